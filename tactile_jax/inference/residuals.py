"""Weighted residuals of the joint model (``data``'s blocks), data and model kept apart.

``blocks(model, meas, data)`` is linear in the measured side, so the
jackknife replaces ``meas`` by each delete-one estimate with the model held
at the fit and the weights at the full record's.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .data import JointData, Measured
from .forward import N_PHYS, ModelSpectra, spectra_at_bins

__all__ = ["blocks", "row_bins", "row_series", "residuals", "residuals_and_model", "n_prior"]


def _masked(mask, meas, model, weight):
    return jnp.where(mask, (jnp.where(mask, meas, 0.0) - jnp.where(mask, model, 0.0)) * weight, 0.0).ravel()


def blocks(model: ModelSpectra, meas: Measured, data: JointData):
    """The data residuals, flat: shallow log PSDs (2 L), log ratios (2 L), conditioned deep PSDs (2 L),
    the chain's whitened coefficients (4 L + 6 L) and its log residual PSDs (2 L)."""
    err = jnp.where(data.mask_h, data.h_err, 1.0)
    out = [_masked(data.mask_s11, meas.log_s11, model.log_s11, data.s11_weight),
           _masked(data.mask_h, meas.log_h, model.log_h, 1.0 / err),
           _masked(data.mask_c22, meas.log_c22, model.log_c22 + data.c22_offset, data.c22_weight)]
    for b, (beta_m, w, beta) in enumerate(((meas.beta1, data.w1, model.beta1), (meas.beta2, data.w2, model.beta2))):
        m = data.mask_xy[b][:, None]
        z = jnp.einsum("lij,lj->li", w, jnp.where(m, beta_m - beta, 0.0))
        out.append(jnp.where(m, jnp.concatenate([z.real, z.imag], -1), 0.0).ravel())
    ok = data.mask_xy & meas.chain_ok
    out.append(_masked(ok, meas.log_c, model.log_c + data.xy_c_offset[:, None], data.xy_c_weight[:, None]))
    return jnp.concatenate(out)


def row_series(data: JointData) -> np.ndarray:
    """(S, L) the row of ``blocks`` of each series across the window's bins (static: from the shapes alone). A
    series is one pair's block (shallow PSD, ratio, conditioned deep PSD, chain residual PSD) or one column
    of a chain's whitened coefficients: every row of ``blocks`` is in exactly one."""
    n_bins = data.omega.shape[-1]
    b = np.arange(n_bins)
    rows = [k * n_bins + b for k in range(6)]
    base = 6 * n_bins
    for n in (2 * data.meas.beta1.shape[-1], 2 * data.meas.beta2.shape[-1]):
        rows += [base + b * n + j for j in range(n)]
        base += n_bins * n
    rows += [base + k * n_bins + b for k in range(2)]
    return np.stack(rows)


def row_bins(data: JointData) -> np.ndarray:
    """The window bin (0 .. L-1) of each row of ``blocks`` (static: from the shapes alone)."""
    idx = row_series(data)
    bins = np.empty(idx.size, dtype=int)
    bins[idx] = np.arange(idx.shape[1])
    return bins


def n_prior(n_params: int) -> int:
    """How many trailing entries of ``residuals`` are priors."""
    return n_params + (n_params - N_PHYS) - 2


def priors(theta, data: JointData):
    prior = (theta - data.prior_center) * data.prior_inv_sd
    log_phi = theta[N_PHYS:]
    smooth = (log_phi[:-2] - 2.0 * log_phi[1:-1] + log_phi[2:]) * data.smooth_inv_sd
    return jnp.concatenate([prior, smooth])


def residuals_and_model(theta, args):
    """All weighted residuals (``blocks`` then the ``n_prior`` priors) and the model's spectra.

    args: (``JointData``, the Hertz table's coefficients or None for the Gaussian window)."""
    data, hertz = args
    model = spectra_at_bins(theta, data, hertz)
    return jnp.concatenate([blocks(model, data.meas, data), priors(theta, data)]), model


def residuals(theta, args):
    """All weighted residuals: ``blocks`` then the priors (``n_prior`` of them); args as ``residuals_and_model``."""
    return residuals_and_model(theta, args)[0]
