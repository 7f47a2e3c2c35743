"""Cramer-Rao bounds on slip speed and contact radius from the per-bin noise of the spectra.

For weighted residuals r_i = (y_i - m_i(theta)) / sigma_i with independent
Gaussian noise of sd sigma_i, the Fisher information is F = J^T J with
J = dr / dtheta (``jax.jacfwd`` of the model at the truth), and any unbiased
estimator has cov(theta) >= F^-1 (the free block; fixed parameters are known).
Adjacent spectral bins are correlated: for a model that is smooth across bins
the information of M correlated bins is that of M / ``bin_factor``
independent ones (``CrossSpectra.bin_factor``), so F is divided by it. The
white-noise ``bin_factor`` (Hann: 1.94) overstates the correlation of the log
ratio's errors, -0.23..+0.25 between neighbours across realisations
(benchmarks/README.md, "Error calibration"): ``pair_crb`` also takes measured
correlations, F = J^T C^-1 J with C banded (``jackknife.bin_correlation``
estimates them from one recording, but 0.1-0.4 too high).
Parameters are fitted in log space; sd(v) = v sd(log v) is exact for the
bound (its Jacobian is v). Two models:

- ``pair_crb``: one probe pair's log AMPLITUDE ratio, log R_exact(omega / v; a)
  + log g averaged over the spectral window (``pair_fit``'s model), noise
  ``log_ratio_err`` per bin: the bound that the exact least-squares fit
  (``pair_fit.fit_pair``) can reach.
- ``joint_crb``: the 2-D joint model (``joint_model``) with its shallow log
  PSDs (sd 1 / ``s11_weight``), log ratios (sd ``h_err``) and, where the data
  carry them, conditioned deep log PSDs (sd 1 / ``c22_weight``); the texture
  spectrum and other free parameters are nuisances whose uncertainty the
  bound includes. Priors are left out unless ``include_priors``.
- ``whittle_crb``: the ideal spectral estimator's bound: K averaged complex
  Gaussian Fourier vectors per bin (the complex-Wishart, Whittle, likelihood),
  F = K sum_bins tr(S^-1 dS S^-1 dS), of the 4 x 4 matrix of both pairs
  (``spectral_matrix``), or of the two pairs' 2 x 2 blocks alone
  (``cross=False``: what per-pair statistics hold, as if the pairs were
  independent). No spectral window, no leakage: a bound on what any
  estimator from these bins could reach, against which ``joint_crb`` (the
  fit's own statistics and measured errors) is compared in
  benchmarks/information.py.

Everything is pure jnp; enable float64 at the entry point for meaningful bounds.
"""

from __future__ import annotations

from functools import partial
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from . import joint_model as jm
from .spectral_matrix import spectral_matrix
from .pair_fit import _residuals as _pair_residuals
from .pair_fit import centroid_shift, kernel_log_weights, noise_err

__all__ = ["fisher_information", "bound_covariance", "banded_correlation", "Bound", "pair_crb", "joint_crb",
           "whittle_crb", "wishart_fisher"]


@partial(jax.jit, static_argnames=("residuals", "n_prior"))
def fisher_information(residuals: Callable, theta, args, free, *, n_prior: int = 0, bin_factor=1.0, corr=None):
    """Fisher information J^T J / bin_factor (or J^T corr^-1 J) of the data residuals at ``theta``: (P, P).

    residuals: ``residuals(theta, args) -> (n,)`` weighted residuals (zero where
    masked), the last ``n_prior`` of them priors (left out). free: (P,) bool;
    fixed parameters get zero rows and columns. corr: optional (n, n)
    correlation matrix of the data residuals' noise.
    """
    theta = jnp.asarray(theta)
    jac = jax.jacfwd(residuals)(theta, args)
    jac = jac[: jac.shape[0] - n_prior] * jnp.asarray(free, bool)[None, :]
    if corr is not None:
        return jac.T @ jnp.linalg.solve(corr, jac)
    return jac.T @ jac / bin_factor


@jax.jit
def bound_covariance(fisher, free):
    """The Cramer-Rao covariance: inverse of the free block of ``fisher`` (zeros elsewhere).

    Inverted after scaling to unit diagonal (the information on log v and on
    log-texture knots can differ by many decades); a direction with no
    information gives an infinite variance, not a silently finite one.
    """
    free = jnp.asarray(free, bool)
    p = fisher.shape[0]
    diag = jnp.diag(fisher)
    seen = free & (diag > 0)
    d = jnp.where(seen, jnp.sqrt(jnp.where(diag > 0, diag, 1.0)), 1.0)
    scaled = fisher / (d[:, None] * d[None, :])
    scaled = jnp.where(seen[:, None] & seen[None, :], scaled, jnp.eye(p))
    cov = jnp.linalg.inv(scaled) / (d[:, None] * d[None, :])
    cov = jnp.where(seen[:, None] & seen[None, :], cov, 0.0)
    blind = free & ~seen
    inf_var = jnp.where(blind, jnp.inf, 0.0)
    return cov + jnp.diag(inf_var)


class Bound(NamedTuple):
    """Cramer-Rao one-sigma bounds (SI units) and the covariance they come from.

    speed_sd: (|vx|,) for a pair or (|vx|, |vy|) for the joint model, m/s.
    a_sd: contact radius, m. log_cov: (P, P) bound on the covariance of the
    internal (log) parameters. fisher: (P, P) Fisher information.
    """

    speed_sd: jax.Array
    a_sd: jax.Array
    log_cov: jax.Array
    fisher: jax.Array


def banded_correlation(rho, positions) -> np.ndarray:
    """Correlation matrix (n, n) of the bins at integer ``positions`` (n,) with correlations ``rho``
    at lags 1, 2, ... bins (0 beyond): a gap in the band leaves its neighbours' lags as they are.

    Made positive definite if the measured ``rho`` are not (eigenvalues floored at 0.05).
    """
    rho = np.concatenate([[1.0], np.asarray(rho, float)])
    pos = np.asarray(positions, int)
    lag = np.abs(pos[:, None] - pos[None, :])
    c = np.where(lag < rho.size, rho[np.minimum(lag, rho.size - 1)], 0.0)
    w, v = np.linalg.eigh(c)
    if w[0] < 0.05:
        c = (v * np.maximum(w, 0.05)) @ v.T
        d = np.sqrt(np.diag(c))
        c = c / np.outer(d, d)
    return c


def pair_crb(omega, log_ratio_err, mask, d1, d2, speed, a, *, gain_ratio=1.0, fit_gain=False,
             kernel=((0.0,), (1.0,)), spectrum=None, leakage=None, bin_factor=1.0, bin_corr=None,
             noise_alone: bool = False) -> Bound:
    """Cramer-Rao bound on |v| and a from one pair's log AMPLITUDE ratio (the exact R model).

    omega: (M,) rad/s. log_ratio_err: (M,) one-sigma noise of log|P2/P1| per
    bin. mask: (M,) bins used. d1, d2: depths, m. speed: true |v| along the
    pair, m/s. a: true contact radius, m. gain_ratio: deep/shallow gain (known
    unless ``fit_gain``, which adds it as a nuisance). kernel: the spectra's
    spectral window ``(offsets in bins, weights)``, and spectrum, the shallow
    spectrum that weights it, as in ``fit_pair``. leakage: the pair's ``pair_fit.Leakage``: the
    model gains the centroid term and the noise is the errors of noise alone at the truth
    (``pair_fit.noise_err``), the bound of ``fit_pair(leakage=...)``.
    bin_factor: correlation of adjacent bins (``CrossSpectra.bin_factor``).
    bin_corr: instead, the correlations of the log ratio's errors at lags 1, 2, ...
    bins: F = J^T C^-1 J over the used bins. The estimator's own (``CrossSpectra.bin_corr``,
    Hann Welch 0.444, 0.028) is that of the noise once the centroid term is modelled: 200
    realisations at 30 dB measured 0.408, 0.027 (benchmarks/README.md, "Session 9").
    noise_alone: ``log_ratio_err`` already are errors of noise alone (for example averaged over
    realisations): with ``leakage`` they are used as given, not passed through ``noise_err``.
    """
    if leakage is not None and not noise_alone:
        log_ratio_err = np.where(mask, noise_err(omega, np.where(mask, log_ratio_err, 1.0), mask, speed, a, d1, d2,
                                                 leakage), log_ratio_err)
    err = jnp.asarray(log_ratio_err)
    mask = jnp.asarray(mask, bool) & jnp.isfinite(err) & (err > 0)
    offsets, log_w = kernel_log_weights(omega, kernel, spectrum)
    omega = jnp.asarray(omega)
    args = (omega, jnp.zeros_like(omega), jnp.where(mask, err, 1.0), mask, d1, d2,
            jnp.asarray(offsets), jnp.asarray(log_w))
    if leakage is not None:
        args = args + (jnp.asarray(centroid_shift(offsets, log_w, leakage.centroid)),)
    theta = jnp.log(jnp.asarray([speed, a, gain_ratio], dtype=omega.dtype))
    free = jnp.array([True, True, bool(fit_gain)])
    if bin_corr is None:
        fisher = fisher_information(_pair_residuals, theta, args, free, bin_factor=bin_factor)
    else:
        # correlated among the used bins only: the unused ones (zero rows of J) stay apart, so that
        # F = J_used^T C_used^-1 J_used and not the inverse of a matrix that spans unobserved bins
        used = np.flatnonzero(np.asarray(mask))
        corr = np.eye(omega.shape[0])
        corr[np.ix_(used, used)] = banded_correlation(bin_corr, used)
        fisher = fisher_information(_pair_residuals, theta, args, free, corr=jnp.asarray(corr))
    cov = bound_covariance(fisher, free)
    sd = jnp.sqrt(jnp.diag(cov))
    return Bound(speed * sd[:1], a * sd[1], cov, fisher)


def joint_crb(theta, data: jm.ModelData, free, *, bin_factor=1.0, include_priors: bool = False) -> Bound:
    """Cramer-Rao bound on |vx|, |vy| and a under the joint 2-D model (``joint_model``).

    theta: (P,) internal parameters at the truth (log speeds in m/s, log a in m;
    the texture knots, a nuisance, for example at their fitted values).
    data: the ``ModelData`` of a fit (its masks and per-bin errors give the
    noise; its measured values are not used). free: (P,) bool, which
    parameters are unknown. bin_factor: correlation of adjacent bins, applied
    to the log-ratio residuals (``h_err`` counts bins as independent;
    ``s11_weight`` = sqrt(K / bin_factor) already includes it).
    include_priors: add the model's prior residuals to the information (a
    Bayesian bound); by default only the data count.
    """
    theta = jnp.asarray(theta)
    free = jnp.asarray(free, bool)
    # one Jacobian of all residuals, sliced into blocks: the log-PSD residuals' weight sqrt(K / bin_factor)
    # already counts correlated bins; the ratios', the conditioned PSDs' and the cross-pair chain's do not
    jac = _joint_jacobian(theta, data) * free[None, :]
    n = data.omega.shape[0]
    n_data = (6 * n if data.log_c22 is not None else 4 * n) + (12 * n if data.xy_beta1 is not None else 0)
    fisher = jac[:2 * n].T @ jac[:2 * n] + jac[2 * n:n_data].T @ jac[2 * n:n_data] / bin_factor
    if include_priors:
        prior = jac[jac.shape[0] - jm.n_prior_residuals(theta.shape[0]):]
        fisher = fisher + prior.T @ prior
    cov = bound_covariance(fisher, free)
    sd = jnp.sqrt(jnp.diag(cov))
    return Bound(jnp.exp(theta[:2]) * sd[:2], jnp.exp(theta[2]) * sd[2], cov, fisher)


def whittle_crb(theta, data: jm.ModelData, free, *, cross: bool = True, include_priors: bool = False,
                dof=None, bin_factor=1.0, n_s: int = 6001) -> Bound:
    """Cramer-Rao bound on |vx|, |vy| and a from the bins' full spectral matrix (the ideal estimator).

    theta, free: as ``joint_crb`` (the noise level, parameter 6, is taken as
    known). data: a joint fit's ``ModelData`` with the conditioned-PSD fields
    (``FitOptions.conditioned``; ``log_noise_c22`` gives each channel's white
    noise); its bins with any data (any mask of either pair) are used.
    cross: the 4 x 4 matrix of both pairs; False keeps the pairs' 2 x 2 blocks
    (cross-pair entries zeroed), the information of per-pair statistics
    counted as if the pairs were independent. dof: averages per bin K
    (default: from ``data.c22_weight`` = sqrt(K - 1)). bin_factor: correlation of
    adjacent bins (``CrossSpectra.bin_factor``), as in ``joint_crb``; F is divided by
    it. With the default 1 the bins count as independent, which for Welch's
    half-overlapped Hann segments (K ~ 2 T / segment length, bin_factor 1.94)
    credits each bin with about twice the T x bandwidth complex degrees of freedom
    the record holds. include_priors: as ``joint_crb``.
    """
    if data.log_c22 is None or data.log_noise_c22 is None:
        raise ValueError("whittle_crb needs the conditioned-PSD fields of the fit's ModelData "
                         "(FitOptions(conditioned=True))")
    theta = jnp.asarray(theta)
    used = np.asarray(data.mask_s11 | data.mask_h | data.mask_c22).any(axis=0)
    omega = jnp.asarray(np.asarray(data.omega)[used])
    k = float(data.c22_weight) ** 2 + 1.0 if dof is None else float(dof)
    free = jnp.asarray(free, bool).at[6].set(False)
    blocks = jnp.ones((4, 4)) if cross else jnp.asarray(_PAIR_BLOCKS)
    fisher = _whittle_fisher(theta, omega, data.depths, data.log_k_knots, jnp.ravel(data.log_noise_c22),
                             free, k / float(bin_factor), blocks, n_s)
    if include_priors:
        prior = _joint_jacobian(theta, data)[-jm.n_prior_residuals(theta.shape[0]):] * free[None, :]
        fisher = fisher + prior.T @ prior
    cov = bound_covariance(fisher, free)
    sd = jnp.sqrt(jnp.diag(cov))
    return Bound(jnp.exp(theta[:2]) * sd[:2], jnp.exp(theta[2]) * sd[2], cov, fisher)


def wishart_fisher(matrix: Callable, theta, free, dof):
    """Fisher information (P, P) of ``dof`` averaged complex Gaussian vectors per bin whose spectral
    matrix is ``matrix(theta)`` (F, p, p): K sum_bins tr(S^-1 dS_i S^-1 dS_j); fixed parameters get zeros.
    jnp (trace it inside a jit)."""
    s = matrix(theta)
    ds = jax.jacfwd(matrix)(theta) * jnp.asarray(free, s.dtype)[None, None, None, :]     # (F, p, p, P)
    a = jnp.einsum("fab,fbcp->facp", jnp.linalg.inv(s), ds)
    return dof * jnp.einsum("fabp,fbaq->pq", a, a)


@partial(jax.jit, static_argnames=("n_s",))
def _whittle_fisher(theta, omega, depths, log_k_knots, log_noise, free, dof, blocks, n_s):
    def matrix(t):      # blocks: (4, 4) ones, or the pairs' blocks (cross-pair entries zeroed)
        return spectral_matrix(t, omega, depths, log_k_knots, log_noise, n_s=n_s) * blocks
    return wishart_fisher(matrix, theta, free, dof)


_PAIR_BLOCKS = np.kron(np.eye(2), np.ones((2, 2)))     # the x and y pairs' 2 x 2 blocks


_joint_jacobian = jax.jit(jax.jacfwd(jm.residuals))
