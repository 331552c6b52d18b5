"""Evaluation: method names, descriptors of an evaluation, checks, the evaluation loop, results, metrics."""
