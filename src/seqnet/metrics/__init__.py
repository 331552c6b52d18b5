"""Recall@K and precision-recall."""
