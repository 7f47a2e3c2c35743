"""A numerical floor that holds in float32 as in float64."""

from __future__ import annotations

import jax.numpy as jnp

__all__ = ["tiny"]


def tiny(*arrays) -> float:
    """max(1e-300, the smallest normal number of the arrays' float dtype): the floor under a value that goes
    into a log, a sqrt or a division. 1e-300 alone rounds to 0 in float32 (log 0 = -inf, 0/0 gradients:
    a float32 joint fit's error bars came out NaN); in float64 it stays 1e-300."""
    return max(1e-300, float(jnp.finfo(jnp.result_type(*arrays)).tiny))
