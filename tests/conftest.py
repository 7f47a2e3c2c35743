"""Tests run in float64 (chosen here, as the library leaves it to the entry points)."""

import jax

jax.config.update("jax_enable_x64", True)
