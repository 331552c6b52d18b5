"""``python -m seqnet ...``: the command line (also what ``torchrun -m seqnet train ...`` runs)."""

from .cli import entry_point

if __name__ == "__main__":
    entry_point()
