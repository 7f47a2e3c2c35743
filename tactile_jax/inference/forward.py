"""The joint model's spectra as the estimator sees them, at the fit's bins.

Parameters (a flat vector, ``PARAMS`` order): log|vx|, log|vy| (m/s), log a
(m), log gx, log gy (deep/shallow amplitude gain ratios of the pairs), log ay
(power level of the y pair's shallow probe relative to x1), log noise (a
fitted shallow white-noise floor, units^2/Hz), the directional texture's
angular factor (p, q, p4, q4) (``model.lines.log_angular``; zeros: isotropic) and log
Phi at the texture's knots (``model.spline``).

The densities of the ten entries of the spectral matrix (``lines``) are
computed on the half-bin grid of the spectral window's reach under the Hertz
window, and under the Gaussian window (smooth densities, half the cost) on
the integer-bin grid, interpolated to half bins (cubic in log density: the
resolution rule keeps the log ratio's fall below 0.15 per bin); then
averaged by the estimator's spectral window with the prewhitening filter's
weight |A|^2 (for x-y entries the complex conj(A_x) A_y):
each bin's expectation is what Welch or multitaper averaging of these
densities gives, so the resolution bias of steep spectra is modelled, not an
error. Gains, levels and the white-noise floors (measured, or the fitted
shallow one) complete the 4 x 4 matrix of (x1, x2, y1, y2) at each bin.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._numerics import tiny
from ..model import cross_pair
from .data import N_LUMP, JointData
from ..model.lines import ENTRIES, log_matrix

__all__ = ["PARAMS", "ANISO", "N_PHYS", "INDEX", "param_names", "ModelSpectra", "spectra_at_bins", "texture_tangents",
           "half_bin_index", "LUMP_SHIFT", "N_LUMP", "lump_basis"]

#: names of the leading parameters; ``log_phi_j`` follow for the texture knots
PARAMS = ("log_vx", "log_vy", "log_a", "log_gx", "log_gy", "log_ay", "log_noise", "aniso_p", "aniso_q", "aniso_p4",
          "aniso_q4")
#: the directional texture's angular coefficients (``model.lines.log_angular``)
ANISO = ("aniso_p", "aniso_q", "aniso_p4", "aniso_q4")
N_PHYS = len(PARAMS)
#: each named parameter's position in theta
INDEX = {name: i for i, name in enumerate(PARAMS)}


def param_names(n_knots: int) -> tuple[str, ...]:
    return PARAMS + tuple(f"log_phi_{j}" for j in range(n_knots))


class ModelSpectra(NamedTuple):
    """The model at the bins (L): log S11, log S12, log S22 (2, L) of each pair, noise floors included on
    the autos; log_h (2, L) = log S12 - log S11; log_c22 (2, L) the conditioned deep PSD as estimated;
    beta1 (L, 2), beta2 (L, 3), log_c (2, L): the chain of the y pair on the x pair."""

    log_s11: jax.Array
    log_h: jax.Array
    log_c22: jax.Array
    beta1: jax.Array
    beta2: jax.Array
    log_c: jax.Array


def half_bin_index(n_fit: int, n_kernel: int) -> np.ndarray:
    """(L, J) positions on the half-bin grid of each bin's kernel offsets (``segments.KERNEL_OFFSETS``)."""
    return 2 * np.arange(n_fit)[:, None] + np.arange(n_kernel)[None, :]


def _to_half_bins(f):
    """(..., F) log densities on the integer grid -> (..., 2 F - 5) on half bins from its second point to its
    last but one (cubic interpolation between points)."""
    even = f[..., 1:-1]
    odd = (-f[..., :-3] + 9.0 * f[..., 1:-2] + 9.0 * f[..., 2:-1] - f[..., 3:]) / 16.0
    inter = jnp.stack([even[..., :-1], odd], axis=-1).reshape(f.shape[:-1] + (-1,))
    return jnp.concatenate([inter, even[..., -1:]], axis=-1)


#: the auto entries of ``ENTRIES`` (positive densities) and, for each entry, its two autos
_AUTO = tuple(k for k, (i, j) in enumerate(ENTRIES) if i == j)
_AUTO_OF = {i: ENTRIES.index((i, i)) for i in range(4)}


def _half_bins(log_abs, sign):
    """The ten entries on half bins: autos cubic in log density, cross entries cubic in their coherency
    S_ij / sqrt(S_ii S_jj) (bounded and smooth even where S_ij changes sign). Returns log|S| and sign (10, H)."""
    auto = {k: _to_half_bins(log_abs[k]) for k in _AUTO}
    logs, signs = [], []
    for k, (i, j) in enumerate(ENTRIES):
        if k in auto:
            logs.append(auto[k])
            signs.append(jnp.ones_like(auto[k]))
            continue
        scale = 0.5 * (log_abs[_AUTO_OF[i]] + log_abs[_AUTO_OF[j]])
        rho = _to_half_bins(sign[k] * jnp.exp(log_abs[k] - scale))
        half_scale = 0.5 * (auto[_AUTO_OF[i]] + auto[_AUTO_OF[j]])
        logs.append(jnp.log(jnp.maximum(jnp.abs(rho), tiny(rho))) + half_scale)
        signs.append(jnp.where(rho < 0, -1.0, 1.0).astype(rho.dtype))
    return jnp.stack(logs), jnp.stack(signs)


def _windows(x, n_fit: int, n_kernel: int):
    """(..., H) on the half-bin grid -> (..., L, J): each bin's kernel offsets (``half_bin_index``), as J
    strided slices (a gather's tangents, one per parameter in the Jacobian, are copied and transposed)."""
    return jnp.stack([x[..., j:j + 2 * n_fit - 1:2] for j in range(n_kernel)], axis=-1)


def _window_average(half, sign, weight, log_kernel, n_fit):
    """(C, L) each bin's kernel average of sign exp(half) times ``weight`` (C, H) (real or complex) over its
    kernel offsets: (log of its magnitude scale, the average relative to it)."""
    n_kernel = log_kernel.shape[0]
    terms = log_kernel + _windows(half, n_fit, n_kernel)
    top = jnp.max(terms, axis=-1)
    return top, jnp.sum(jnp.exp(terms - top[..., None]) * _windows(sign * weight, n_fit, n_kernel), axis=-1)


#: (2, 10) how a log texture power the x pair hears (row 0) and the y pair hears (row 1) enters the log density of
#: each entry of ``ENTRIES``: a pair's own entries fully, the x-y entries (the modes both pairs hear) by half
LUMP_SHIFT = np.array([[1.0 if (i < 2 and j < 2) else 0.5 if (i < 2) != (j < 2) else 0.0 for i, j in ENTRIES],
                       [1.0 if (i >= 2 and j >= 2) else 0.5 if (i < 2) != (j < 2) else 0.0 for i, j in ENTRIES]])


def spectra_at_bins(theta, data: JointData, hertz=None, shift=None, p_tangents=True) -> ModelSpectra:
    """``ModelSpectra`` of the parameters ``theta`` (P,) for ``data``, under the Gaussian contact window, or
    under the Hertz window where ``hertz`` holds its table's coefficients (``model.hertz``). shift: (2,) log
    texture power added to what the x and the y pair hear (``LUMP_SHIFT``; None: 0). p_tangents: (traced
    bool) whether the tangents in vx, vy and a are wanted (``lines.log_matrix``; False: they are 0)."""
    i = INDEX
    phys = jnp.exp(jnp.stack([theta[i["log_vx"]], theta[i["log_vy"]], theta[i["log_a"]]]))
    aniso = jnp.stack([theta[i[name]] for name in ANISO])
    dens, sign = log_matrix(phys, theta[N_PHYS:], aniso, data.grid_abs, data.depths, data.log_k_knots,
                            None if hertz is None else 1, hertz, p_tangents)                    # (10, F)
    # gains and levels: x2 has gx, y1 the level ay (power), y2 both (amplitudes: half the power's log)
    level, gx, gy = theta[i["log_ay"]], theta[i["log_gx"]], theta[i["log_gy"]]
    amp = jnp.stack([0.0, gx, 0.5 * level, 0.5 * level + gy])
    dens = dens + jnp.stack([amp[i] + amp[j] for i, j in ENTRIES])[:, None]
    if shift is not None:
        dens = dens + (shift @ LUMP_SHIFT.astype(dens.dtype))[:, None]
    # the Hertz window's densities are computed on the half bins themselves: its spectrum's nulls (the disk's
    # edge) make the y pair's densities dip between integer bins at slips along x, which no interpolation of
    # them follows (interpolated, the fit reads vy 0.05-0.12 cm/s for a truth of 0, beyond its error, at
    # reduced chi-squares of 1.2-2.0; on the half bins 0.9-1.2 and vy within its error: benchmarks/windows.py)
    half, half_sign = (dens, sign) if hertz is not None else _half_bins(dens, sign)   # (10, H)
    n_fit = data.omega.shape[0]
    white = jnp.exp(jnp.repeat(data.white_half, 3, axis=0))                          # |A|^2 per pair entry
    top, avg = _window_average(half[:6], half_sign[:6], white, data.log_kernel, n_fit)
    auto = top + jnp.log(jnp.maximum(jnp.abs(avg), tiny(top))) - jnp.repeat(data.white_bin, 3, axis=0)
    pair = auto.reshape(2, 3, n_fit)                                                 # [pair][11, 12, 22]
    s12 = jnp.where(avg[1::3] < 0, -1.0, 1.0)                                        # (2, L) the sign of S12
    noise = jnp.maximum(jnp.stack([jnp.full(2, theta[i["log_noise"]]), jnp.full(2, -700.0)], -1),
                        data.log_noise)                                                  # (2, 2)
    b11 = jnp.logaddexp(pair[:, 0], noise[:, :1])
    b12 = pair[:, 1]
    b22 = jnp.logaddexp(pair[:, 2], noise[:, 1:])
    # x-y entries: complex weights conj(A_x) A_y on the signed grid
    top, avg = _window_average(half[6:], half_sign[6:], data.xy_white_half, data.log_kernel, n_fit)   # (4, L)
    ref = b11[0]
    cxy = avg / data.xy_white_bin * jnp.exp(top - ref)                               # (4, L), / S_x1x1
    eps = 8.0 * jnp.finfo(b22.dtype).eps
    coherent = jnp.clip(jnp.exp(2.0 * b12 - b11 - b22), 0.0, 1.0 - eps)
    log_c22 = b22 + jnp.log1p(-coherent)
    # the 4 x 4 matrix relative to S_x1x1, and the y pair's chain on the x pair
    e = lambda v: jnp.exp(v - ref).astype(cxy.dtype)                                  # noqa: E731
    c = jnp.conj
    x12, y12 = e(b12[0]) * s12[0], e(b12[1]) * s12[1]
    rows = [[e(b11[0]), x12, cxy[0], cxy[1]],
            [x12, e(b22[0]), cxy[2], cxy[3]],
            [c(cxy[0]), c(cxy[2]), e(b11[1]), y12],
            [c(cxy[1]), c(cxy[3]), y12, e(b22[1])]]
    m = jnp.moveaxis(jnp.stack([jnp.stack(r) for r in rows]), -1, 0)                  # (L, 4, 4)
    ok = data.mask_xy.any(axis=0)[:, None, None]
    m = jnp.where(ok, m, jnp.eye(4, dtype=m.dtype))                                   # unused bins: finite
    out = []
    for target, n in ((2, 2), (3, 3)):
        beta, res = cross_pair.regression(m[:, :n, :n], m[:, :n, target], m[:, target, target])
        res = jnp.maximum(res, 64.0 * jnp.finfo(res.dtype).eps * jnp.real(m[:, target, target]))
        out.append((beta, jnp.log(res) + ref))
    return ModelSpectra(b11, b12 - b11, log_c22, out[0][0], out[1][0], jnp.stack([out[0][1], out[1][1]]))


def lump_basis(n_params: int) -> np.ndarray:
    """(P, ``N_LUMP``) the texture's random effects as directions in the parameters: the x pair's log power (every
    knot up, the y level down: the spline's basis sums to one), the y pair's (its level ``log_ay``) and the
    angular factor's coefficients. The model's derivatives by the effects (``texture_tangents``) are its Jacobian
    times this."""
    basis = np.zeros((n_params, N_LUMP))
    basis[N_PHYS:, 0] = 1.0
    basis[INDEX["log_ay"], 0] = -1.0
    basis[INDEX["log_ay"], 1] = 1.0
    for k, name in enumerate(ANISO):
        basis[INDEX[name], 2 + k] = 1.0
    return basis


def texture_tangents(theta, data: JointData, hertz=None) -> ModelSpectra:
    """Each field of ``spectra_at_bins`` differentiated (leading axis ``N_LUMP``) by the log texture
    power the x pair and the y pair hear (``LUMP_SHIFT``) and by the texture's angular factor (``ANISO``: how
    its power is spread along each line k . v = omega), by forward differentiation (the line integrals are
    computed once). A bin's log PSD moves with the texture's share of its power: below 1 where the noise
    floor is heard."""
    ia = np.array([INDEX[name] for name in ANISO])
    x0 = jnp.zeros(N_LUMP, theta.dtype)
    _, lin = jax.linearize(lambda x: spectra_at_bins(theta.at[ia].add(x[2:]), data, hertz, x[:2]), x0)
    return jax.vmap(lin)(jnp.eye(N_LUMP, dtype=theta.dtype))
