"""Exceptions raised by seqnet.

Every error a user can cause derives from :class:`SeqnetError`; the CLI turns it into one line
on stderr and exit code 2. Messages name the bad value, the valid set and, where useful, a hint.
"""

from __future__ import annotations


class SeqnetError(Exception):
    """Base class of all user-facing seqnet errors."""


class DatasetError(SeqnetError):
    """A dataset directory, traverse or descriptor file is missing, malformed or inconsistent."""


class ConfigError(SeqnetError, ValueError):
    """A parameter (sequence length, radius, method name, ...) is out of its valid range."""


class CheckpointError(SeqnetError):
    """A model checkpoint is missing, corrupted or does not fit the data."""


class ImageError(SeqnetError):
    """An image folder is empty or an image cannot be read."""
