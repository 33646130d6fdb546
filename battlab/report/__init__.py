"""Static HTML reports (one page, PNG figures beside it, no scripts, no network) for diagnosis and campaigns."""

from battlab.report.html import Figure, KeyValues, Paragraph, Section, Table, render, write

__all__ = ["Figure", "KeyValues", "Paragraph", "Section", "Table", "render", "write"]
