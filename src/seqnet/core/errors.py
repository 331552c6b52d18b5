"""Exceptions raised by seqnet.

Every error a user can cause derives from :class:`SeqnetError`; the CLI turns it into one line
on stderr and exit code 2 (``exit_code``; 1 for :class:`ResourceError`, a failure of the
environment rather than of the input). Messages name the bad value, the valid set and, where
useful, a hint.
"""

from __future__ import annotations


class SeqnetError(Exception):
    """Base class of all user-facing seqnet errors."""

    exit_code = 2


class DatasetError(SeqnetError):
    """A dataset directory, traverse or descriptor file is missing, malformed or inconsistent."""


class CountError(DatasetError):
    """Two counts of one traverse's files that must agree do not (names against descriptors): ``counts`` holds
    them, ``(names, rows)``, for a caller that can tell why (both sides' files given the other way round)."""

    def __init__(self, message: str, counts: tuple[int, int]) -> None:
        super().__init__(message)
        self.counts = counts


class ConfigError(SeqnetError, ValueError):
    """A parameter (sequence length, radius, method name, ...) is out of its valid range."""


class WindowsTooLongError(ConfigError):
    """The sequence windows (L, L_m) are longer than the traverse or split they slide over."""


class CheckpointError(SeqnetError):
    """A model checkpoint is missing, corrupted or does not fit the data."""


class ImageError(SeqnetError):
    """An image folder is empty or an image cannot be read."""


class OutputError(SeqnetError):
    """An output path cannot be used: it holds files this run did not create, or is of the wrong kind."""


class ResourceError(SeqnetError):
    """The environment stopped the work (disk full, read-only file system, no permission, locked).

    The CLI reports it as one line with exit code 1 (bad input exits with 2).
    """

    exit_code = 1


class LockedError(ResourceError):
    """Another live process holds the lock of a run or dataset directory."""
