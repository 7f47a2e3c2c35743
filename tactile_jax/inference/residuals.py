"""Weighted residuals of the joint model (``data``'s blocks), data and model kept apart.

``blocks(model, meas, data)`` is linear in the measured side, so the
jackknife replaces ``meas`` by each delete-one estimate with the model held
at the fit and the weights at the full record's.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .._numerics import any_in_batch
from .data import N_LUMP, JointData, Measured
from .forward import N_PHYS, ModelSpectra, spectra_at_bins

__all__ = ["blocks", "row_bins", "row_series", "residuals", "residuals_and_model", "n_prior", "n_lump_rows",
           "lump_scale", "lump_dof", "lump_rows", "n_data_rows", "profile", "N_LUMP_SERIES"]

#: rows of the texture's random effects per bin (``_profiled``): one per effect
N_LUMP_SERIES = N_LUMP


def _masked(mask, meas, model, weight):
    return jnp.where(mask, (jnp.where(mask, meas, 0.0) - jnp.where(mask, model, 0.0)) * weight, 0.0).ravel()


def _data_rows(model: ModelSpectra, meas: Measured, data: JointData, offsets: bool = True):
    """The data residuals, flat (``blocks``' first 18 L rows); without ``offsets`` the estimators' log offsets
    are left out (for a model's derivatives, with ``meas`` zero)."""
    err = jnp.where(data.mask_h, data.h_err, 1.0)
    c22_offset = data.c22_offset if offsets else 0.0
    c_offset = data.xy_c_offset[:, None] if offsets else 0.0
    out = [_masked(data.mask_s11, meas.log_s11, model.log_s11, data.s11_weight),
           _masked(data.mask_h, meas.log_h, model.log_h, 1.0 / err),
           _masked(data.mask_c22, meas.log_c22, model.log_c22 + c22_offset, data.c22_weight)]
    for b, (beta_m, w, beta) in enumerate(((meas.beta1, data.w1, model.beta1), (meas.beta2, data.w2, model.beta2))):
        m = data.mask_xy[b][:, None]
        z = jnp.einsum("lij,lj->li", w, jnp.where(m, beta_m - beta, 0.0))
        out.append(jnp.where(m, jnp.concatenate([z.real, z.imag], -1), 0.0).ravel())
    ok = data.mask_xy & meas.chain_ok
    out.append(_masked(ok, meas.log_c, model.log_c + c_offset, data.xy_c_weight[:, None]))
    return jnp.concatenate(out)


def lump_rows(tangents: ModelSpectra, data: JointData):
    """(R_d, K) the data rows' derivatives by the texture's random effects, from the model's
    (``forward.texture_tangents``: each field with a leading axis of K)."""
    zero = jax.tree.map(jnp.zeros_like, data.meas)._replace(chain_ok=data.meas.chain_ok)
    n = jax.tree.leaves(tangents)[0].shape[0]
    return jnp.stack([-_data_rows(jax.tree.map(lambda x: x[k], tangents), zero, data, offsets=False)
                      for k in range(n)], -1)


def _lump_terms(r, jl, data: JointData):
    """Each bin's normal equations for the texture's random effects there: A (L, K, K) and b (L, K), from the
    data rows ``r`` (R_d,) and their derivatives by the effects ``jl`` (R_d, K)."""
    idx = jnp.asarray(row_series(data)[:-N_LUMP_SERIES])
    js, rs = jl[idx], r[idx]                                                        # (S, L, K), (S, L)
    return jnp.einsum("slk,slm->lkm", js, js), jnp.einsum("slk,sl->lk", js, rs)


def _prior_factor(sd):
    """M (K, K) with M M^T the random effects' prior covariance: the two pairs' log powers sd[0]^2 in common plus
    sd[1]^2 each (lower Cholesky factor), the angular factor's coefficients sd[2]^2 each, independent."""
    var = jnp.square(sd[0]) + jnp.square(sd[1])
    l11 = jnp.sqrt(var)
    l21 = jnp.where(var > 0, jnp.square(sd[0]) / jnp.where(var > 0, l11, 1.0), 0.0)
    l22 = jnp.sqrt(jnp.clip(var - jnp.square(l21), 0.0, None))
    m = jnp.zeros((N_LUMP, N_LUMP), sd.dtype).at[0, 0].set(l11).at[1, 0].set(l21).at[1, 1].set(l22)
    return m.at[np.arange(2, N_LUMP), np.arange(2, N_LUMP)].set(sd[2])


def _cholesky_solve(s, b):
    """s (L, K, K) symmetric positive definite (here I + M^T A M: eigenvalues at least 1) \\ b (L, K, ...),
    unrolled over the small fixed K (a batched LAPACK call under vmap deadlocks jaxlib's CPU backend)."""
    k = s.shape[-1]
    c = [[None] * k for _ in range(k)]
    for j in range(k):
        d = s[:, j, j] - sum(c[j][m] * c[j][m] for m in range(j))
        c[j][j] = jnp.sqrt(jnp.maximum(d, 1e-300))
        for i in range(j + 1, k):
            c[i][j] = (s[:, i, j] - sum(c[i][m] * c[j][m] for m in range(j))) / c[j][j]
    expand = (slice(None),) + (None,) * (b.ndim - 2)
    y = []
    for i in range(k):
        y.append((b[:, i] - sum(c[i][m][expand] * y[m] for m in range(i))) / c[i][i][expand])
    x = [None] * k
    for i in reversed(range(k)):
        x[i] = (y[i] - sum(c[m][i][expand] * x[m] for m in range(i + 1, k))) / c[i][i][expand]
    return jnp.stack(x, 1)


def _profiled(r, data: JointData):
    """The data rows with each bin's texture random effects (``forward.texture_tangents``: the log power each
    pair hears, the angular factor's coefficients) marginalised with the prior covariance C = M M^T
    (``_prior_factor(data.lump_sd)``; the rows' derivatives by them ``data.lump_rows``), the ``N_LUMP_SERIES`` L
    rows that complete its quadratic form, and the effects' degrees of freedom.

    With J_l the bin's rows' derivatives by its effects, A = J_l^T J_l and b = J_l^T r, the quadratic form of
    the marginal likelihood, r^T (I + J C J^T)^-1 r, is min over delta of |r - J delta|^2 + delta^T C^-1 delta,
    reached at delta = M w, w = (I + M^T A M)^-1 M^T b, its prior term |w|^2. The degrees of freedom the effects
    take are tr(I - (I + M^T A M)^-1) per bin. Every term is finite as the sds go to 0 (rows unchanged, extra
    rows 0). Linear in r for fixed theta."""
    jl = data.lump_rows
    a, b = _lump_terms(r, jl, data)
    m = _prior_factor(data.lump_sd)
    s = jnp.eye(N_LUMP, dtype=r.dtype) + jnp.einsum("ji,ljk,kn->lin", m, a, m)
    rhs = jnp.concatenate([(b @ m)[:, :, None], jnp.broadcast_to(jnp.eye(N_LUMP, dtype=r.dtype),
                                                                  (b.shape[0], N_LUMP, N_LUMP))], -1)
    sol = _cholesky_solve(s, rhs)
    w = sol[:, :, 0]                                                                 # (L, K)
    edf = jnp.sum(N_LUMP - jnp.trace(sol[:, :, 1:], axis1=1, axis2=2))
    delta = w @ m.T
    bins = jnp.asarray(row_bins(data)[:r.shape[0]])
    return r - jnp.sum(jl * delta[bins], -1), w.T.ravel(), edf


def profile(r, data: JointData):
    """All residuals (``residuals``' layout, the random effects' rows zero: ``data.lump_sd`` was zero where they
    were computed) with the texture's random effects of ``data`` marginalised (``_profiled``); r (R,) or their
    Jacobian (R, P), column by column: the map is linear. The effects' rows' derivatives ``data.lump_rows`` are
    held, as in a fit with them."""
    n, k = n_data_rows(data), n_lump_rows(data)

    def one(x):
        kept, w, _ = _profiled(x[:n], data)
        return jnp.concatenate([kept, w, x[n + k:]])

    return one(r) if r.ndim == 1 else jax.vmap(one, in_axes=1, out_axes=1)(r)


def blocks(model: ModelSpectra, meas: Measured, data: JointData):
    """The data residuals, flat: shallow log PSDs (2 L), log ratios (2 L), conditioned deep PSDs (2 L),
    the chain's whitened coefficients (4 L + 6 L) and its log residual PSDs (2 L); then ``N_LUMP_SERIES`` L rows
    of the texture's random effects at each bin (``_profiled``; zeros where ``data.lump_sd`` is)."""
    r = _data_rows(model, meas, data)
    # the random effects only where some record of a chunk has them (with none, ``_profiled`` is the identity)
    return jax.lax.cond(any_in_batch(jnp.any(data.lump_sd > 0)), lambda: jnp.concatenate(_profiled(r, data)[:2]),
                        lambda: jnp.concatenate([r, jnp.zeros(N_LUMP_SERIES * data.omega.shape[-1], r.dtype)]))


def n_data_rows(data: JointData) -> int:
    """How many of ``blocks``' rows are data (the first ones)."""
    return row_series(data)[:-N_LUMP_SERIES].size


def lump_dof(data: JointData):
    """The degrees of freedom the texture's random effects take (0 where ``data.lump_sd`` is)."""
    zero = jnp.zeros((), data.omega.dtype)
    return jax.lax.cond(any_in_batch(jnp.any(data.lump_sd > 0)),
                        lambda: _profiled(jnp.zeros(n_data_rows(data), data.omega.dtype), data)[2], lambda: zero)


def lump_scale(r, jl, data: JointData, min_weight: float = 1.0):
    """The sds (3,) of a texture's random effects at each bin (``_prior_factor``): its log power about the model's
    smooth spectrum (common to both pairs, each pair's own), and the angular factor's coefficients (the
    whole sd of the log power), by moments: from the data rows ``r`` (R_d,) of a fit with no random effect and
    their derivatives by the effects ``jl`` (``lump_rows``), each bin's least-squares pair powers have
    covariance C + A^-1; a pair's power is measured in bins where its rows weigh at least ``min_weight``."""
    a, b = _lump_terms(r, jl[:, :2], data)
    a_diag = jnp.stack([a[:, 0, 0], a[:, 1, 1]], -1)
    use = a_diag >= min_weight                                                       # (L, 2)
    both = use[:, 0] & use[:, 1]
    det = jnp.where(both, a[:, 0, 0] * a[:, 1, 1] - a[:, 0, 1] * a[:, 1, 0], 1.0)
    inv = jnp.stack([jnp.stack([a[:, 1, 1], -a[:, 0, 1]], -1), jnp.stack([-a[:, 1, 0], a[:, 0, 0]], -1)], -2) \
        / det[:, None, None]
    one = jnp.where(use, 1.0 / jnp.where(use, a_diag, 1.0), 0.0)          # a pair's alone, where the other has none
    delta = jnp.where(both[:, None], jnp.einsum("lkm,lm->lk", inv, b), b * one)
    var = jnp.where(both[:, None], jnp.stack([inv[:, 0, 0], inv[:, 1, 1]], -1), one)
    total = jnp.sum(jnp.where(use, jnp.square(delta) - var, 0.0)) / jnp.maximum(jnp.sum(use), 1)
    common = jnp.sum(jnp.where(both, delta[:, 0] * delta[:, 1] - inv[:, 0, 1], 0.0)) / jnp.maximum(jnp.sum(both), 1)
    common = jnp.clip(common, 0.0, None)
    total = jnp.clip(total, common, None)
    # the angular factor's coefficients: the log power's whole sd along each line
    return jnp.sqrt(jnp.stack([common, total - common, total]))


def row_series(data: JointData) -> np.ndarray:
    """(S, L) the row of ``blocks`` of each series across the window's bins (static: from the shapes alone). A
    series is one pair's block (shallow PSD, ratio, conditioned deep PSD, chain residual PSD), one column
    of a chain's whitened coefficients, or (the last ``N_LUMP_SERIES``) one of the texture random effect's
    rows: every row of ``blocks`` is in exactly one."""
    n_bins = data.omega.shape[-1]
    b = np.arange(n_bins)
    rows = [k * n_bins + b for k in range(6)]
    base = 6 * n_bins
    for n in (2 * data.meas.beta1.shape[-1], 2 * data.meas.beta2.shape[-1]):
        rows += [base + b * n + j for j in range(n)]
        base += n_bins * n
    rows += [base + k * n_bins + b for k in range(2)]
    base += 2 * n_bins
    rows += [base + k * n_bins + b for k in range(N_LUMP_SERIES)]
    return np.stack(rows)


def row_bins(data: JointData) -> np.ndarray:
    """The window bin (0 .. L-1) of each row of ``blocks`` (static: from the shapes alone)."""
    idx = row_series(data)
    bins = np.empty(idx.size, dtype=int)
    bins[idx] = np.arange(idx.shape[1])
    return bins


def n_lump_rows(data: JointData) -> int:
    """How many of ``blocks``' rows complete the texture random effect's quadratic form (counted in chi-square,
    not as data)."""
    return N_LUMP_SERIES * data.omega.shape[-1]


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

    args: (``JointData``, the Hertz table's coefficients or None for the Gaussian window), and optionally
    whether the Jacobian's columns of vx, vy and a are wanted (``forward.spectra_at_bins``'s p_tangents)."""
    data, hertz, *wanted = args
    model = spectra_at_bins(theta, data, hertz, p_tangents=wanted[0] if wanted else True)
    return jnp.concatenate([blocks(model, data.meas, data), priors(theta, data)]), model


def residuals(theta, args):
    """All weighted residuals: ``blocks`` then the priors (``n_prior`` of them); args as ``residuals_and_model``."""
    return residuals_and_model(theta, args)[0]
