"""Depth decay of a surface mode in the elastic half-space (paper Eq. 2)."""

from __future__ import annotations

import jax.numpy as jnp

__all__ = ["log_depth_decay", "depth_decay", "poisson_kernel"]


def log_depth_decay(k, depth):
    """log of exp(-|k| depth): k in rad/m, depth in m (positive, below the surface)."""
    return -jnp.abs(k) * depth


def depth_decay(k, depth):
    """Amplitude factor exp(-|k| depth) of a mode of spatial frequency ``k`` (rad/m) at ``depth`` (m)."""
    return jnp.exp(log_depth_decay(k, depth))


def poisson_kernel(x, depth):
    """Line-probe kernel in space, K_d(x) = d / (pi (x^2 + d^2)), in 1/m.

    The y-integral of the half-space Poisson kernel; its Fourier transform
    is exp(-|k| d). ``x`` (m) is the distance across the probe line.
    """
    return depth / (jnp.pi * (jnp.square(x) + jnp.square(depth)))
