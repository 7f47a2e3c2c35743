"""Figures and the text fit report (matplotlib is imported only where a figure is drawn)."""
