"""seqnet.describe."""
