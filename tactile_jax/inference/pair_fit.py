"""Exact-R fit of one probe pair's log amplitude ratio: speed, contact radius, gain.

The fast path of the paper's section 4.3 (Eq. 23 fitted to log|P2/P1|):
correct when the slip is along the pair's sensitive axis or the contact is
large; under oblique slip with a small contact use the joint 2-D model.
Parameters are fitted in log space (positivity by reparametrisation).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..model import hertz as hertz_mod
from ..model.closed_form import radius_from_offset, slope_speed
from .lsq import least_squares
from ..model.r_curve import log_r_exact, log_r_hertz, log_r_rough
from jax.scipy.special import logsumexp

__all__ = ["PairFit", "Leakage", "fit_pair", "pair_leakage", "kernel_log_weights", "centroid_shift", "noise_err",
           "noise_err_from_slope", "CURVES"]

#: R curves a pair can be fitted with: Gaussian exact (Eq. 23), the rough Eq. 26, Hertz (Eq. 12, 1-D texture)
CURVES = ("exact", "rough", "hertz")


class PairFit(NamedTuple):
    """speed (m/s), a (m), gain_ratio (deep/shallow), each with a one-sigma error; fit statistics."""

    speed: float
    speed_err: float
    a: float
    a_err: float
    gain_ratio: float
    gain_ratio_err: float | None
    redchi: float
    n_bins: int
    converged: bool
    cond: float


def _pair_residuals(log_r_fn, theta, args):
    # args: omega, y, err, mask, d1, d2, offsets, log_w and, optionally, the centroid shift (M,) in bins
    omega, y, err, mask, d1, d2, offsets, log_w = args[:8]
    log_v, log_a, log_g = theta[0], theta[1], theta[2]
    # the expected H1 estimate at a bin is the average of R over the spectral window around it,
    # weighted by the (prewhitened) shallow spectrum there: log_w, normalised, is (J,) for a flat
    # one or (M, J) with the spectrum in it (``kernel_log_weights``)
    d_omega = omega[1] - omega[0]
    om = jnp.abs(omega[:, None] + offsets[None, :] * d_omega)
    speed, a = jnp.exp(log_v), jnp.exp(log_a)
    log_r = log_r_fn(om / speed, d1, d2, a)
    model = logsumexp(log_r + log_w, axis=-1)
    if len(args) > 8:
        # the realised part of the window average: R' (per bin) times the shallow power's centroid in the
        # window less the centroid the weights expect (``centroid_shift``), relative to the average R
        half = jnp.stack([jnp.abs(omega - 0.5 * d_omega), omega + 0.5 * d_omega]) / speed
        log_edges = log_r_fn(half, d1, d2, a)
        slope = jnp.exp(log_edges[1] - model) - jnp.exp(log_edges[0] - model)
        model = model + jnp.log1p(jnp.clip(slope * args[8], -0.5, None))
    model = model + log_g
    safe_err = jnp.where(mask, err, 1.0)
    return jnp.where(mask, (jnp.where(mask, y, 0.0) - model) / safe_err, 0.0)


def exact_residuals(theta, args):
    """Residuals of the exact (Gaussian window, Eq. 23) R curve."""
    return _pair_residuals(log_r_exact, theta, args)


def rough_residuals(theta, args):
    """Residuals of the rough R curve (Eq. 26): a straight line whose offset gives a."""
    return _pair_residuals(log_r_rough, theta, args)


def _log_r_hertz_1d(alpha, d1, d2, a):
    # ky = 0: the Hertz projection is exact with one Chebyshev node; 4 panels: 4e-5 in log R for alpha a < 30
    return log_r_hertz(alpha, d1, d2, a, n_y=1, panels=4)


def hertz_residuals(theta, args):
    """Residuals of the Hertz-window R curve (Eq. 12) for a texture varying along the slip."""
    return _pair_residuals(_log_r_hertz_1d, theta, args)


def hertz_table_residuals(theta, args):
    """``hertz_residuals`` from the Hertz table (``model.hertz``) in place of quadrature: ``args`` end with the
    table's coefficients (data, as ``core.Settings.hertz`` holds them). The joint fit's Hertz starts use it:
    one table lookup per node, where the quadrature's 4 panels made two pair fits cost 1.6 s."""
    table = hertz_mod.table_of(args[-1])

    def log_r(alpha, d1, d2, a):
        k = jnp.stack([alpha, alpha])
        # a usable bin has kappa = alpha a far below the table's edge (148): no far field to compile (3 s of 29)
        hn = hertz_mod.hertz_hn(k, jnp.zeros_like(k), jnp.stack([d1, d2]), a, table, depth_index=(0, 1),
                                far_field=False)
        return jnp.log(jnp.abs(hn[1])) - jnp.log(jnp.abs(hn[0]))

    return _pair_residuals(log_r, theta, args[:-1])


def kernel_log_weights(omega, kernel, spectrum=None):
    """(offsets, log weights) of the spectral window each bin's H1 ratio averages R over.

    omega: (M,) bin frequencies, rad/s (uniform). kernel: ``(offsets in bins,
    weights)`` (``CrossSpectra.kernel``). spectrum: (M,) the shallow probe's power
    spectrum as the estimator averaged it (``spectra.whitened_psd``), or None for
    a flat one. The ratio of window averages sum w S R / sum w S is R averaged
    with weights w S: where S is steep on the scale of the window (a slow slip's
    band near DC), a flat S biases the model by up to ~0.03 in log ratio.
    Returns offsets (J,) of the non-zero weights and log weights normalised to sum
    to 1, (J,) without a spectrum, (M, J) with one (S interpolated log-linearly in
    |omega| between bins, the DC bin, notched by detrending, left out).
    """
    offsets, weights = (np.asarray(k, float) for k in kernel)
    keep = weights > 0
    offsets, log_w = offsets[keep], np.log(weights[keep])
    if spectrum is not None:
        omega = np.asarray(omega, float)
        spectrum = np.asarray(spectrum, float)
        ok = (omega > 0) & np.isfinite(spectrum) & (spectrum > 0)
        if ok.sum() >= 2:
            at = np.abs(omega[:, None] + offsets[None, :] * (omega[1] - omega[0]))
            log_w = log_w[None, :] + np.interp(at, omega[ok], np.log(spectrum[ok]))
    return offsets, log_w - np.logaddexp.reduce(log_w, axis=-1, keepdims=True)


class Leakage(NamedTuple):
    """The shallow probe's realised power within each bin's spectral window (one pair; ``pair_leakage``).

    centroid: (M,) bins, ``CrossSpectra.centroid``. spread: (M,) bins^2,
    ``CrossSpectra.spread``. dof: the spectra's K (``CrossSpectra.dof``), the
    one the ratio's errors were computed with.
    """

    centroid: np.ndarray
    spread: np.ndarray
    dof: float


def pair_leakage(spectra, pair: int = 0) -> Leakage | None:
    """``Leakage`` of pair 0 (x) or 1 (y) of one recording's ``CrossSpectra``; None without a centroid."""
    if spectra.centroid is None or spectra.spread is None:
        return None
    return Leakage(np.asarray(spectra.centroid, float)[..., pair, :], np.asarray(spectra.spread, float)[..., pair, :],
                   float(spectra.dof))


def centroid_shift(offsets, log_w, centroid):
    """(M,) the measured power centroid (``CrossSpectra.centroid``, bins) less the one the window weights expect.

    offsets, log_w: ``kernel_log_weights``'s. centroid: (M,) one pair's. The
    weights' own first moment (zero for a flat spectrum and a symmetric window)
    is already in the window average of R; the rest is this recording's texture.
    """
    offsets = np.asarray(offsets, float)
    expected = np.sum(np.exp(np.asarray(log_w, float)) * offsets, axis=-1)
    return np.nan_to_num(np.asarray(centroid, float) - expected)


@jax.jit
def _relative_slope(omega, speed, a, d1, d2):
    """(R(omega + half a bin) - R(omega - half a bin)) / R(omega) of the exact curve."""
    half = 0.5 * (omega[1] - omega[0])
    log_r = log_r_exact(jnp.abs(omega[None, :] + jnp.array([-1.0, 0.0, 1.0])[:, None] * half) / speed, d1, d2, a)
    return jnp.exp(log_r[2] - log_r[1]) - jnp.exp(log_r[0] - log_r[1])


def noise_err(omega, log_ratio_err, mask, speed, a, d1, d2, leakage: Leakage, *, explained=0.85, floor=0.05,
              guard=0.5):
    """(M,) the log ratio's error from noise alone: the Bendat-Piersol error less the slope of R's share.

    The H1 ratio's incoherent deep power includes R'^2 S11 spread (``Leakage``)
    that the centroid term models, so var = err^2 - explained (R'/R)^2 spread / (2 K)
    at (speed, a), R' per bin (of the exact curve, whatever the fitted one);
    ``explained`` < 1 leaves the second-order term in the error (a noise-free
    filter: the centroid removes 85 % of the model error's variance). Guarded
    against its own noise: at least ``floor`` err^2, and at least ``guard`` times
    the median of the used bins within 2 of it (one bin's spread can cancel err^2
    by chance; without the guard 24 seeded 30 dB fits lost 50-70 % in RMSE).
    """
    omega = np.asarray(omega, float)
    slope = np.asarray(_relative_slope(jnp.asarray(omega), speed, a, d1, d2))
    return noise_err_from_slope(log_ratio_err, slope, mask, leakage, explained=explained, floor=floor, guard=guard)


def noise_err_from_slope(log_ratio_err, slope, mask, leakage: Leakage, *, explained=0.85, floor=0.05, guard=0.5):
    """``noise_err`` with R's relative slope across each bin given: (M,) from any model (the joint one's too)."""
    err = np.asarray(log_ratio_err, float)
    slope = np.asarray(slope, float)
    var = np.maximum(err ** 2 - explained * slope ** 2 * np.asarray(leakage.spread, float) / (2.0 * leakage.dof),
                     floor * err ** 2)
    used = np.flatnonzero(np.asarray(mask, bool) & np.isfinite(var))
    out = var.copy()
    for i in used:
        near = used[np.abs(used - i) <= 2]
        out[i] = max(var[i], guard * float(np.median(var[near])))
    return np.sqrt(out)


_RESIDUALS = {"exact": exact_residuals, "rough": rough_residuals, "hertz": hertz_residuals}


def fit_pair(omega, log_ratio, log_ratio_err, mask, d1, d2, *, gain_ratio=1.0, fit_gain=False,
             speed0=None, a0=None, bin_factor=1.0, kernel=((0.0,), (1.0,)), spectrum=None,
             leakage: Leakage | None = None, solver="optimistix", curve: str = "exact") -> PairFit:
    """Fit log R_exact(omega / v; a) + log g to one pair's log AMPLITUDE ratio.

    omega: (M,) rad/s. log_ratio, log_ratio_err: (M,) log|P2/P1| and its
    one-sigma error. mask: (M,) bins to use. d1, d2: depths, m.
    gain_ratio: the known g, or the start value when ``fit_gain``.
    speed0 (m/s), a0 (m): starting values (default: the Eq. 6 slope and Eq. 26 offset).
    bin_factor: the spectra's correlation between bins (inflates the covariance).
    kernel: the spectra's spectral window ``(offsets in bins, weights)``;
        the model averages R over it (resolution bias). Default: none.
    spectrum: (M,) the shallow probe's spectrum as the estimator averaged it
        (``spectra.whitened_psd``): weights the kernel (``kernel_log_weights``).
        None: a flat spectrum.
    leakage: the pair's ``Leakage`` (``pair_leakage(spectra, pair)``): the model adds the
        first-order random resolution error R' (centroid - expected), and the bins are weighted
        by their errors from noise alone (``noise_err``) at the estimate. At 45-60 dB this
        divides the RMSE of |v| and a by 2-5 (benchmarks/README.md). None: left out.
    curve: "exact" (Gaussian window, Eq. 23), "rough" (Eq. 26) or "hertz" (Eq. 12).
    """
    if curve not in _RESIDUALS:
        raise ValueError(f"unknown R curve {curve!r}; expected one of {CURVES}")
    if leakage is not None and not (np.shape(leakage.centroid) == np.shape(leakage.spread) == np.shape(omega)):
        raise ValueError(f"leakage has centroid {np.shape(leakage.centroid)} and spread {np.shape(leakage.spread)} "
                         f"for omega {np.shape(omega)}: pass one recording's pair_leakage(spectra, pair)")
    mask = np.asarray(mask, bool) & np.isfinite(log_ratio) & np.isfinite(log_ratio_err)
    if speed0 is None or a0 is None:
        line = slope_speed(omega, log_ratio, log_ratio_err, mask, d1, d2)
        if speed0 is None:
            speed0 = float(line.speed) if bool(line.ok) else 0.01
        if a0 is None:
            a_off = float(radius_from_offset(float(line.intercept) - np.log(gain_ratio), d1, d2))
            a0 = a_off if np.isfinite(a_off) else 2e-3
    theta0 = jnp.array([np.log(speed0), np.log(a0), np.log(gain_ratio)])
    offsets, log_w = kernel_log_weights(omega, kernel, spectrum)
    args = (jnp.asarray(omega), jnp.asarray(log_ratio), jnp.asarray(log_ratio_err), jnp.asarray(mask),
            float(d1), float(d2), jnp.asarray(offsets), jnp.asarray(log_w))
    free = jnp.array([True, True, bool(fit_gain)])
    res = least_squares(_RESIDUALS[curve], theta0, args, free, solver=solver, bin_factor=float(bin_factor))
    if leakage is not None:
        # refined from the window-average fit: from the slope's start the centroid term let LM run to the
        # a bound (1 of 24 recordings at 45 dB, 1.5 cm/s, 4 mm: chi2 50 there against 12 near the truth);
        # then weighted by the errors of noise alone at the estimate, twice (``noise_err``)
        args = args + (jnp.asarray(centroid_shift(offsets, log_w, leakage.centroid)),)
        for refit in range(3):
            start = jnp.where(jnp.all(jnp.isfinite(res.theta)), res.theta, theta0)
            res = least_squares(_RESIDUALS[curve], start, args, free, solver=solver, bin_factor=float(bin_factor))
            v_hat, a_hat = np.exp(np.asarray(res.theta[:2]))
            if refit == 2 or not (np.isfinite(v_hat) and np.isfinite(a_hat)):
                break
            err = noise_err(omega, log_ratio_err, mask, v_hat, a_hat, d1, d2, leakage)
            args = args[:2] + (jnp.asarray(np.where(mask, err, 1.0)),) + args[3:]
    th = np.asarray(res.theta)
    redchi = float(res.redchi)
    inflate = max(redchi, 1.0) / redchi if redchi > 0 else 1.0      # errors only inflate, as in ``fit``
    sd = np.sqrt(np.clip(np.diag(np.asarray(res.cov)) * inflate, 0, None))
    v, a, g = np.exp(th)
    return PairFit(float(v), float(v * sd[0]), float(a), float(a * sd[1]), float(g),
                   float(g * sd[2]) if fit_gain else None, float(res.redchi), int(res.n_data),
                   bool(res.converged), float(res.cond))
