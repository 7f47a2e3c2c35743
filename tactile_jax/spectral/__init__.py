"""Spectral estimation: Welch and multitaper spectra, prewhitening, the fit's fixed grid, the usable band."""
