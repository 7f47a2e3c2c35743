"""The y pair conditioned on the x pair: what the cross-pair spectra add to a joint fit.

Under slow slip both pairs hear the texture modes of small |k| (|kx| and |ky|
below about 1/a), and in the lowest bins the shallow probes x1 and y1 are
coherent (0.96-1.00 on the simulator). Fitting each pair's spectra as if the
pairs were independent counts those modes twice and leaves out how the two
pairs share them, which depends on (vx, vy, a).

The four channels' likelihood factors exactly as p(x1, x2) p(y1 | x1, x2)
p(y2 | x1, x2, y1). The joint fit (``inference.residuals``) fits the x pair and, per bin, a
regression of each y channel on the channels before it (Bendat & Piersol's
conditioned spectra, ch. 7):

    beta = S_uu^-1 S_u,t,    S_t.u = S_tt - S_u,t^H beta,

u the regressors, t the target, S_ab = E[conj(A) B]. For Gaussian data (complex
Wishart with K degrees of freedom), given the regressors' record the estimate
of beta is complex normal about beta with covariance S_t.u (K S_uu-hat)^-1, and
the residual power S_t.u-hat ~ S_t.u chi^2_2(K - n) / 2K (n regressors) is
independent of it. So the residuals are

    z = sqrt(2 (K - n) / S_t.u-hat) L^H (beta-hat - beta)   (real and imaginary parts, unit variance),
    (log S_t.u-hat - log S_t.u - offset) sqrt(K - n),

with L the Cholesky factor of the MEASURED S_uu (fixed by the regressors) and the
measured S_t.u (independent of beta-hat): weights that do not follow the
estimate's own noise, unlike a coherence-based error. Where the pairs share
nothing, beta is 0 and S_t.u the channel's own PSD: the block reduces to the
y pair's PSD that it replaces.

This module holds the measured side (jnp, any leading axes); the model side is
``inference.forward``'s.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

__all__ = ["ChainEstimate", "chain_matrix", "chain_estimate", "chain_offsets", "regression"]

#: the chain's blocks: (target channel, regressor channels) in (x1, x2, y1, y2) indices
BLOCKS = ((2, (0, 1)), (3, (0, 1, 2)))


class ChainEstimate(NamedTuple):
    """The measured chain at each bin (leading axes ..., bins M).

    beta1: (..., M, 2) complex, y1 on (x1, x2). beta2: (..., M, 3) complex, y2 on (x1, x2, y1).
    w1, w2: (..., M, 2, 2), (..., M, 3, 3) complex, sqrt(2 (K - n) / S_t.u) L^H with S_uu = L L^H.
    log_c: (..., 2, M) log of the residual PSDs S_y1.x and S_y2.(x, y1), units^2/Hz.
    ok: (..., 2, M) where the block's estimate is finite and positive.
    """

    beta1: jnp.ndarray
    beta2: jnp.ndarray
    w1: jnp.ndarray
    w2: jnp.ndarray
    log_c: jnp.ndarray
    ok: jnp.ndarray


def chain_matrix(psd, csd, xy):
    """(..., M, 4, 4) the Hermitian spectral matrix E[conj(X_c) X_d] of (x1, x2, y1, y2) from a
    ``CrossSpectra``'s ``psd`` (..., 4, M), ``csd`` (..., 2, M) and ``xy`` (..., 4, M)."""
    psd, csd, xy = (jnp.moveaxis(jnp.asarray(v), -2, -1) for v in (psd, csd, xy))    # (..., M, c)
    z = jnp.zeros(psd.shape[:-1], xy.dtype)
    upper = [[psd[..., 0], csd[..., 0], xy[..., 0], xy[..., 1]],
             [z, psd[..., 1], xy[..., 2], xy[..., 3]],
             [z, z, psd[..., 2], csd[..., 1]],
             [z, z, z, psd[..., 3]]]
    u = jnp.stack([jnp.stack(row, -1) for row in upper], -2).astype(xy.dtype)
    return u + jnp.conj(jnp.swapaxes(jnp.triu(u, 1), -1, -2))    # u is zero below its diagonal


def _solve_small(a, b):
    """a^-1 b for (..., n, n) a and (..., n) b with small static n, by Gauss-Jordan elimination unrolled
    (no pivoting: a is Hermitian positive definite here). Written out rather than ``jnp.linalg.solve``:
    batched LAPACK calls inside the vmapped, looped fit of ``inference.core`` stalled XLA's CPU runtime
    (8 records x 3 starts never finished), and unrolled elimination of a 2 x 2 or 3 x 3 is cheaper."""
    n = a.shape[-1]
    a = [[a[..., i, j] for j in range(n)] for i in range(n)]
    b = [b[..., i] for i in range(n)]
    for k in range(n):
        inv = 1.0 / a[k][k]
        a[k] = [v * inv for v in a[k]]
        b[k] = b[k] * inv
        for i in range(n):
            if i != k:
                f = a[i][k]
                a[i] = [v - f * w for v, w in zip(a[i], a[k])]
                b[i] = b[i] - f * b[k]
    return jnp.stack(b, axis=-1)


def regression(s_uu, s_ut, s_tt):
    """beta = S_uu^-1 S_u,t (..., n) and the residual PSD S_t.u = S_tt - S_u,t^H beta (...), real: the
    chain's step for the measured matrices here and the model's (``inference.forward``)."""
    beta = _solve_small(s_uu, s_ut)
    return beta, jnp.real(s_tt - jnp.sum(jnp.conj(s_ut) * beta, axis=-1))


def _block(m, target, regressors, dof):
    r = np.asarray(regressors)
    s_uu = m[..., r[:, None], r[None, :]]
    s_ut = m[..., r, target]
    ok = jnp.all(jnp.isfinite(s_uu), axis=(-1, -2)) & jnp.all(jnp.real(jnp.diagonal(s_uu, axis1=-2, axis2=-1)) > 0,
                                                              axis=-1)
    s_uu = jnp.where(ok[..., None, None], s_uu, jnp.eye(r.size))
    s_ut = jnp.where(ok[..., None], s_ut, 0.0)
    chol = jnp.linalg.cholesky(s_uu)
    beta, c = regression(s_uu, s_ut, m[..., target, target])
    ok = ok & jnp.isfinite(c) & (c > 0) & jnp.all(jnp.isfinite(chol), axis=(-1, -2))
    c_safe = jnp.where(ok, c, 1.0)
    w = jnp.sqrt(2.0 * (dof - r.size) / c_safe)[..., None, None] * jnp.conj(jnp.swapaxes(chol, -1, -2))
    w = jnp.where(ok[..., None, None], w, 0.0)
    return beta, w, jnp.log(c_safe), ok


def chain_estimate(psd, csd, xy, dof: float) -> ChainEstimate:
    """The measured chain (``ChainEstimate``) from spectra (see ``chain_matrix``); ``dof`` the spectra's K."""
    m = chain_matrix(psd, csd, xy)
    b1, w1, c1, ok1 = _block(m, *BLOCKS[0], dof)
    b2, w2, c2, ok2 = _block(m, *BLOCKS[1], dof)
    return ChainEstimate(b1, b2, w1, w2, jnp.stack([c1, c2], -2), jnp.stack([ok1, ok2], -2))


def chain_offsets(dof: float) -> tuple[np.ndarray, np.ndarray]:
    """(2,) weights sqrt(K - n) and (2,) offsets psi(K - n) - psi(K) of the residual PSDs' logs.

    The offset is the mean of log S_t.u-hat less that of a channel's PSD, whose own
    psi(K) - log K the model's fitted level absorbs (as ``fit.conditioned_fields``'s).
    """
    import scipy.special  # here, not at import: importing it takes about 0.25 s

    n = np.array([len(r) for _, r in BLOCKS], float)
    k = np.maximum(float(dof) - n, 1.0)
    return np.sqrt(k), scipy.special.digamma(k) - scipy.special.digamma(float(dof))
