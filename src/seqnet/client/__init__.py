"""A client of ``seqnet serve`` on the standard library only (no server dependency): :class:`Client`."""

from .client import Client, ClientError, Session, encode_frame

__all__ = ["Client", "ClientError", "Session", "encode_frame"]
