"""Figures as PNG files (matplotlib, Agg backend: no display needed)."""
