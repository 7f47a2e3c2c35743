"""Reprocessing a dataset: every record of every file through the fit's compiled program, resumably."""
