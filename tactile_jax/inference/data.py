"""What the joint model is fitted to: the measured spectra on the fit's window of bins, as fixed-shape arrays.

``Measured`` holds what a record's spectra say (and what the jackknife
replaces by each delete-one-group estimate); ``JointData`` adds the fixed
weights, the model's grid, the estimator's spectral window and the priors.
All fields are arrays of fixed shape: the window has ``N_FIT`` bins, masks say
which are used.

The residual blocks (``residuals``):

- the shallow log PSDs of both pairs, weight sqrt(K);
- each pair's H1 log amplitude ratio log|S12| / S11, weighted by its Bendat-Piersol
  error from the neighbours' coherence;
- each pair's conditioned deep PSD S22.1 = S22 - |S12|^2 / S11 (Bendat & Piersol), weight
  sqrt(K - 1), less its expected log offset psi(K - 1) - psi(K);
- the y pair conditioned on the x pair (``cross_pair``): y1 on (x1, x2) in place of y1's
  PSD, y2 on (x1, x2, y1) in place of the y ratio and S22.1.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._numerics import tiny
from ..model import cross_pair

__all__ = ["N_LUMP_SD", "N_LUMP", "N_DATA_ROWS", "N_FIT", "N_MARGIN", "Measured", "JointData", "measure",
           "grid_offsets", "half_offsets"]

#: the sds of the texture's random effects (``JointData.lump_sd``), and the effects at each bin: the log power
#: each pair hears and the angular factor's four coefficients (``forward.texture_tangents``)
N_LUMP_SD = 3
N_LUMP = 6
#: bins in the fit's window
N_FIT = 48
#: the data rows of the joint residuals (``residuals.blocks``): per bin, each pair's shallow PSD, ratio and
#: conditioned deep PSD, the chain's whitened coefficients (2 and 3 complex) and its two residual PSDs
N_DATA_ROWS = (3 * 2 + 2 * 2 + 2 * 3 + 2) * N_FIT
#: integer-grid points of the model beyond each end of the window (the kernel's reach, 6 bins, and one
#: more for the cubic interpolation to half bins)
N_MARGIN = 7


def grid_offsets(n_fit: int = N_FIT) -> np.ndarray:
    """Integer offsets (bins, from the window's first bin) of the model's density grid: (n_fit + 2 N_MARGIN,)."""
    return np.arange(-N_MARGIN, n_fit + N_MARGIN)


def half_offsets(n_fit: int = N_FIT) -> np.ndarray:
    """Half-bin offsets (bins, from the window's first bin) of the spectral window's reach around the fit's
    bins, (2 (n_fit - 1) + 4 (N_MARGIN - 1) + 1,): where the kernel averages the densities."""
    reach = N_MARGIN - 1
    return np.arange(-2 * reach, 2 * (n_fit - 1 + reach) + 1) / 2.0


class Measured(NamedTuple):
    """One record's spectra on the window (L bins): the data side of every residual block.

    log_s11: (2, L) shallow log PSDs. log_h: (2, L) log|S12| / S11. log_c22: (2, L) log S22.1.
    beta1: (L, 2), beta2: (L, 3) complex chain coefficients; log_c: (2, L) their residual PSDs.
    chain_ok: (2, L) where the chain's blocks are defined.
    """

    log_s11: jax.Array
    log_h: jax.Array
    log_c22: jax.Array
    beta1: jax.Array
    beta2: jax.Array
    log_c: jax.Array
    chain_ok: jax.Array


class JointData(NamedTuple):
    """Everything the joint model's residuals need besides the parameters (arrays; see the module).

    meas: ``Measured``. omega: (L,) bin frequencies, rad/s. grid_abs: |omega| where the model's densities
    are computed: the integer grid (``grid_offsets``, F) under the Gaussian window, whose smooth densities
    are interpolated to half bins, or the half-bin grid itself (``half_offsets``, H) under the Hertz
    window. log_kernel: (J,) log spectral-window weights at
    ``segments.KERNEL_OFFSETS`` (-2e4: none). white_half, white_bin: (2, H), (2, L) log |A|^2 of each
    pair's prewhitening filter on the half-bin grid and at the bins; xy_white_half, xy_white_bin:
    (H,), (L,) complex conj(A_x) A_y. depths: (2,) m. log_k_knots: (n,) log rad/m.
    h_err: (2, L) one-sigma errors of log_h. w1, w2: (L, 2, 2), (L, 3, 3) complex chain weights.
    mask_s11, mask_h, mask_c22, mask_xy: (2, L) bins of each block. s11_weight, c22_weight,
    c22_offset: scalars; xy_c_weight, xy_c_offset: (2,). log_noise: (2, 2) measured log white-noise
    PSDs [[x1, x2], [y1, y2]]. prior_center, prior_inv_sd: (P,) Gaussian priors on the
    parameters (inverse sd 0: none). smooth_inv_sd: inverse sd of the knots' second differences.
    lump_sd: (``N_LUMP_SD``,) the sds of a lumpy texture's random effects at each bin (``residuals``): its log
    power, common to both pairs and each pair's own, and its angular factor; zeros: a smooth texture.
    lump_rows: (R_d, ``N_LUMP``) the data rows' derivatives by those effects (``residuals.lump_rows``, at the
    fit the random effects' refit starts from; zeros: none).
    """

    meas: Measured
    omega: jax.Array
    grid_abs: jax.Array
    log_kernel: jax.Array
    white_half: jax.Array
    white_bin: jax.Array
    xy_white_half: jax.Array
    xy_white_bin: jax.Array
    depths: jax.Array
    log_k_knots: jax.Array
    h_err: jax.Array
    w1: jax.Array
    w2: jax.Array
    mask_s11: jax.Array
    mask_h: jax.Array
    mask_c22: jax.Array
    mask_xy: jax.Array
    s11_weight: jax.Array
    c22_weight: jax.Array
    c22_offset: jax.Array
    xy_c_weight: jax.Array
    xy_c_offset: jax.Array
    log_noise: jax.Array
    prior_center: jax.Array
    prior_inv_sd: jax.Array
    smooth_inv_sd: jax.Array
    lump_sd: jax.Array
    lump_rows: jax.Array


def _log(x):
    return jnp.log(jnp.clip(x, tiny(x), None))


def measure(psd, csd, xy, dof):
    """``Measured`` and the chain's weights (w1, w2) from spectra on the window: psd (4, L), csd (2, L),
    xy (4, L) complex; dof the segments' effective number."""
    s11 = psd[0::2]
    mag = jnp.abs(csd)
    ok = (s11 > 0) & (psd[1::2] > 0)
    c22 = psd[1::2] - jnp.square(mag) / jnp.where(s11 > 0, s11, 1.0)
    chain = cross_pair.chain_estimate(psd, csd, xy, dof)
    meas = Measured(_log(s11), jnp.where(ok, _log(mag) - _log(s11), 0.0), _log(c22), chain.beta1, chain.beta2,
                    chain.log_c, chain.ok)
    return meas, chain.w1, chain.w2
