"""seqnet.train."""
