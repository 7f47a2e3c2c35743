"""The paper's closed-form estimators: baselines and initialisers for the joint fit.

- ``dominant_wavenumber``: k0 = log(p1 / p2) / (d2 - d1) from probe amplitudes (Eq. 4, 17).
- ``slope_speed``: |v| from the slope of log|P2/P1| against omega (Eq. 6, 15, 16).
- ``radius_from_offset``: contact radius from the intercept of that line (Eq. 26).

All are pure jnp functions (jit/vmap friendly); a fit that cannot give a
number reports ``ok = False`` and NaN instead of raising.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

__all__ = ["dominant_wavenumber", "SlopeFit", "slope_speed", "radius_from_offset"]


def dominant_wavenumber(p1_amplitude, p2_amplitude, d1, d2):
    """Eq. 4 / 17: k0 = log(p1 / p2) / (d2 - d1), rad/m, from AMPLITUDES (not powers) of a probe pair."""
    return (jnp.log(p1_amplitude) - jnp.log(p2_amplitude)) / (d2 - d1)


class SlopeFit(NamedTuple):
    """Weighted straight-line fit log|P2/P1| = intercept + slope * |omega|.

    speed, speed_err: |v| = -(d2 - d1) / slope and its one-sigma error, m/s.
    slope, slope_err: s/m.  intercept, intercept_err: log amplitude ratio at omega = 0.
    redchi: reduced chi-square; errors are scaled by sqrt(max(redchi, 1) * bin_factor).
    A large redchi says the log ratio is not a straight line (the contact
    window bends it at low omega): the slope is then biased.
    n_bins: bins used. ok: a finite, decaying fit on at least 3 bins.
    """

    speed: jnp.ndarray
    speed_err: jnp.ndarray
    slope: jnp.ndarray
    slope_err: jnp.ndarray
    intercept: jnp.ndarray
    intercept_err: jnp.ndarray
    redchi: jnp.ndarray
    n_bins: jnp.ndarray
    ok: jnp.ndarray


@jax.jit
def slope_speed(omega, log_ratio, log_ratio_err, mask, d1, d2, bin_factor=1.0) -> SlopeFit:
    """Eq. 6: slip speed along a probe pair from the slope of its log AMPLITUDE ratio.

    omega: (M,) rad/s. log_ratio, log_ratio_err: (..., M) log|P2/P1| and its
    one-sigma error (a log POWER ratio has twice the slope: halve it first).
    mask: (..., M) bool, the bins to use. d1, d2: probe depths, m.
    Weighted least squares with an intercept (the Eq. 26 window offset plus
    any log gain ratio); the covariance is scaled by max(redchi, 1) as in lmfit
    and by ``bin_factor``, the spectra's correlation between adjacent bins.
    """
    x = jnp.abs(omega)
    w = jnp.where(mask & jnp.isfinite(log_ratio) & jnp.isfinite(log_ratio_err) & (log_ratio_err > 0),
                  1.0 / jnp.square(jnp.where(log_ratio_err > 0, log_ratio_err, 1.0)), 0.0)
    y = jnp.where(w > 0, log_ratio, 0.0)
    n = jnp.sum(w > 0, axis=-1)
    sw = jnp.sum(w, axis=-1)
    safe_sw = jnp.where(sw > 0, sw, 1.0)
    xm = jnp.sum(w * x, axis=-1) / safe_sw
    ym = jnp.sum(w * y, axis=-1) / safe_sw
    dx = x - xm[..., None]
    sxx = jnp.sum(w * jnp.square(dx), axis=-1)
    safe_sxx = jnp.where(sxx > 0, sxx, 1.0)
    slope = jnp.sum(w * dx * (y - ym[..., None]), axis=-1) / safe_sxx
    intercept = ym - slope * xm
    resid = y - intercept[..., None] - slope[..., None] * x
    chi2 = jnp.sum(w * jnp.square(resid), axis=-1)
    redchi = chi2 / jnp.maximum(n - 2, 1)
    scale = jnp.maximum(redchi, 1.0) * bin_factor
    slope_err = jnp.sqrt(scale / safe_sxx)
    intercept_err = jnp.sqrt(scale * (1.0 / safe_sw + jnp.square(xm) / safe_sxx))
    eps = d2 - d1
    ok = (n >= 3) & (sxx > 0) & (slope < 0) & jnp.isfinite(slope)
    safe_slope = jnp.where(ok, slope, -1.0)
    speed = jnp.where(ok, -eps / safe_slope, jnp.nan)
    speed_err = jnp.where(ok, eps * slope_err / jnp.square(safe_slope), jnp.nan)
    return SlopeFit(speed, speed_err, slope, slope_err, intercept, intercept_err, redchi, n, ok)


def radius_from_offset(offset, d1, d2):
    """Eq. 26: a = sqrt(3 (d2^2 - d1^2) / (2 offset)), metres, from the log-ratio intercept.

    Only defined for a positive offset (a known unit gain ratio); NaN otherwise.
    """
    num = 1.5 * (jnp.square(d2) - jnp.square(d1))
    return jnp.where(offset > 0, jnp.sqrt(num / jnp.where(offset > 0, offset, 1.0)), jnp.nan)
