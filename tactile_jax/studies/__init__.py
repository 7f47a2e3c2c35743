"""Studies: the analysis run on simulated data and drawn (``tactile-jax compare-r``); above the analysis,
which imports nothing of them."""
