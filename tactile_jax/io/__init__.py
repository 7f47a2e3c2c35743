"""Files: recordings, spectra, results and scene recipes, read with checks and written atomically."""
