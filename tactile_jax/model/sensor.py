"""Sensor geometry (probe depths, surface curvature) and Hertz contact depth."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

__all__ = ["Sensor", "PAPER_SENSOR", "contact_depth", "contact_radius"]


class Sensor(NamedTuple):
    """Probe depths below the surface and surface curvature radius.

    d1, d2: shallow and deep probe depths, metres (d1 < d2).
    curvature_radius: radius of the spherical sensor surface, metres.
    """

    d1: float = 0.265e-3
    d2: float = 0.925e-3
    curvature_radius: float = 30e-3

    @property
    def eps(self) -> float:
        """Probe separation d2 - d1, metres."""
        return self.d2 - self.d1


#: The sensor of Shinoda & Ando (section 5): d1 = 0.265 mm, d2 = 0.925 mm, R = 30 mm.
PAPER_SENSOR = Sensor()


def contact_depth(a, curvature_radius):
    """Hertz contact depth d = a^2 / R (metres) for contact radius ``a`` (m)."""
    return jnp.square(a) / curvature_radius


def contact_radius(depth, curvature_radius):
    """Hertz contact radius a = sqrt(R d) (metres) for contact depth ``depth`` (m)."""
    return jnp.sqrt(curvature_radius * depth)
