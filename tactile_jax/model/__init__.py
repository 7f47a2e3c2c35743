"""The physics, as pure jnp functions: depth decay, contact windows, the R curve, line probes, the spectral matrix."""
