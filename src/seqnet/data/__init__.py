"""seqnet.data."""
