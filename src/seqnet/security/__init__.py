"""The guarded boundary: every file seqnet reads or writes goes through this package (docs/security.md)."""
