"""Delete-one-segment jackknife of a least-squares fit: the scatter its estimates really have.

The Laplace covariance (J^T J)^-1 of a fit to spectra is only as good as the
noise model behind the residual weights: every bin counted as independent,
each with its Bendat-Piersol error. Adjacent bins are not independent, and how
much they share depends on the scene (benchmarks/README.md, "Error
calibration"). The jackknife asks the recording instead: leave out each Welch
segment (or taper) in turn, push the change it makes in the fitted data
through the fit's Gauss-Newton map at the estimate, and take the spread of the
K parameter shifts (Efron & Stein 1981; Thomson & Chave 1991 for tapers).
Linearised, it costs one Jacobian and K residual evaluations, not K fits.
"""

from __future__ import annotations

from functools import partial
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from .lsq import equilibrated_inverse

__all__ = ["linear_shifts", "covariance", "pooled_scale", "own_scales", "bin_correlation"]


@partial(jax.jit, static_argnums=0)
def linear_shifts(residuals: Callable, theta, data, replaced: dict, free, jac=None):
    """Gauss-Newton parameter shifts for K replacements of ``data``'s fields, and (J^T J)^-1.

    residuals(theta, data) -> (R,) weighted residuals (a NamedTuple ``data``).
    replaced: {field: (K, ...) array}, the K jackknife versions of those fields;
    the weights stay those of the full data. free: (P,) bool.
    jac: (R, P) Jacobian of ``residuals`` at (theta, data) when the caller has it (``LsqResult.jac``
    of the fit at this very data), else computed here by forward mode: that program is most of this
    one's compilation (session 15: 13-17 s of 17 s with the cross-pair chain, 2-core x86-64).
    Returns shifts (K, P), zero for fixed entries, and the unit covariance
    (P, P) (J^T J)^-1 of the free block (zero rows and columns for fixed ones).
    """
    free = jnp.asarray(free)
    r0 = residuals(theta, data)
    jac = (jax.jacfwd(residuals)(theta, data) if jac is None else jac) * free
    d_r = jax.vmap(lambda fields: residuals(theta, data._replace(**fields)) - r0)(replaced)   # (K, R)
    d, _, inv = equilibrated_inverse(jac.T @ jac, free)        # as the Laplace covariance of ``lsq``
    unit = jnp.where(free[:, None] & free[None, :], inv / (d[:, None] * d[None, :]), 0.0)
    return -(d_r @ jac) @ unit, unit


def covariance(shifts, overlap=1.0):
    """Jackknife covariance (K-1)/K sum (d_k - mean)(d_k - mean)^T of shifts (K, P), times ``overlap``.

    overlap: n_segments / dof for overlapping Welch segments (Hann, half
    overlap: 1.05 for 30 segments); the delete-one jackknife treats the segments
    as independent and would otherwise miss their shared samples. 1 for tapers.
    jnp (works on numpy input, under jit and vmap).
    """
    d = jnp.asarray(shifts)
    k = d.shape[0]
    dev = d - d.mean(axis=0)
    return (k - 1) / k * (dev.T @ dev) * overlap


def pooled_scale(var_jk, var_unit, use):
    """One variance scale for the Laplace covariance: the mean over ``use`` of var_jk / var_unit.

    var_jk, var_unit: (P,) jackknife and unit (J^T J)^-1 variances; use: (P,) bool,
    the parameters to pool (zero-variance ones are skipped); NaN when none. A
    single recording's jackknife variance has about K - 1 degrees of freedom per
    parameter; pooling the ratio over the physical parameters steadies it and
    keeps the Laplace correlations. jnp.
    """
    var_unit = jnp.asarray(var_unit)
    use = jnp.asarray(use, bool) & (var_unit > 0)
    ratio = jnp.asarray(var_jk) / jnp.where(use, var_unit, 1.0)
    n = jnp.sum(use)
    return jnp.where(n > 0, jnp.sum(jnp.where(use, ratio, 0.0)) / jnp.maximum(n, 1), jnp.nan)


def own_scales(var_jk, var_unit, own, floor):
    """Variance scales (P,) of the Laplace covariance: the ``own`` parameters each their jackknife ratio.

    var_jk, var_unit: (P,) jackknife and unit (J^T J)^-1 variances; own: (P,) bool,
    the parameters that take their own ratio var_jk / var_unit (zero-variance ones
    are skipped); every other parameter takes that ratio pooled over ``own``
    (``pooled_scale``). No scale falls below ``floor`` (the reduced chi-square: a
    misfit the segments share). Returns (pooled, scales); both NaN when nothing is
    pooled. The Laplace correlations are kept: cov_ij = unit_ij sqrt(s_i s_j). jnp.
    """
    var_unit = jnp.asarray(var_unit)
    own = jnp.asarray(own, bool) & (var_unit > 0)
    pooled = pooled_scale(var_jk, var_unit, own)
    ratio = jnp.where(own, jnp.asarray(var_jk) / jnp.where(own, var_unit, 1.0), pooled)
    ok = jnp.isfinite(pooled) & (pooled > 0)
    return pooled, jnp.where(ok, jnp.maximum(ratio, floor), jnp.nan)


def bin_correlation(values, mask, max_lag: int = 2) -> np.ndarray:
    """Correlation of the errors of a spectral quantity j = 1..max_lag bins apart, from its jackknife.

    values: (K, M) the quantity (for example a pair's log ratio) from the K
    delete-one spectra; mask: (M,) bins to use. Each lag's correlation is the
    jackknife covariance of the bin pairs summed over the band over the root of
    the summed variances (pooled: one number per lag, not per bin). On the
    simulator's recordings it reads the log ratio's neighbour correlation 0.1-0.4
    higher than the spread across realisations does (benchmarks/README.md,
    "Error calibration"), while the parameter variances agree: a diagnostic, not
    an input of the bound.
    """
    v = np.asarray(values, float)
    mask = np.asarray(mask, bool) & np.all(np.isfinite(v), axis=0)
    dev = np.where(mask, v - np.where(mask, v, 0.0).mean(axis=0), 0.0)
    out = np.full(max_lag, np.nan)
    for lag in range(1, max_lag + 1):
        both = mask[:-lag] & mask[lag:]
        if both.sum() < 3:
            continue
        a, b = dev[:, :-lag][:, both], dev[:, lag:][:, both]
        out[lag - 1] = np.sum(a * b) / np.sqrt(np.sum(a * a) * np.sum(b * b))
    return out
