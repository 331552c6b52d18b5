"""Nearest-neighbour search: the one blocked driver, exact k-NN and ANN indexes."""
