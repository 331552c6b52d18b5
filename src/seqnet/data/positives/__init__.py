"""Explicit ground truth: for every query frame, the reference frames that show the same place.

Public VPR benchmarks often give their ground truth as lists (query i matches references
``[10i-1, 10i, 10i+1]``; ``-1`` or an empty list = no match) instead of positions and a radius.
:class:`Positives` holds such lists as one CSR structure (``indptr [Nq+1]``, ``indices [nnz]``);
when a dataset has them, Recall@K, training mining and every method use them instead of the radius.

Readers (:func:`read_positives`, :mod:`.files`): a JSON list of lists; a CSV of ``query,reference`` pairs
(without a header in that order; a header names the two columns, in either order, else it is refused); a
``.npy`` of a NumPy object array of index arrays (as pickled by many benchmarks), read by a restricted
unpickler that can rebuild NumPy arrays and nothing else, so a hostile file cannot run code. The structure:
:mod:`.csr`.
"""

from __future__ import annotations

from .csr import Positives
from .files import as_positives, query_bound, read_positives

__all__ = ["Positives", "as_positives", "query_bound", "read_positives"]
