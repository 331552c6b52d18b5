"""seqnet.methods."""
