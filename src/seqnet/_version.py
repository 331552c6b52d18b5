"""The package version (kept apart from ``seqnet/__init__`` so modules can import it without a cycle)."""

__version__ = "0.2.0"
