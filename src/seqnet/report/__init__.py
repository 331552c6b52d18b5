"""Outputs people look at: Markdown tables, PNG figures, the self-contained HTML report."""
