"""Exact-R fit of one probe pair's log amplitude ratio: speed, contact radius, gain.

The fast path of the paper's section 4.3 (Eq. 23 fitted to log|P2/P1|):
correct when the slip is along the pair's sensitive axis or the contact is
large; under oblique slip with a small contact use the joint 2-D model.
Parameters are fitted in log space (positivity by reparametrisation).
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from .closed_form import radius_from_offset, slope_speed
from .lsq import least_squares
from .r_curve import log_r_exact, log_r_hertz, log_r_rough
from jax.scipy.special import logsumexp

__all__ = ["PairFit", "fit_pair", "kernel_log_weights", "CURVES"]

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
    omega, y, err, mask, d1, d2, offsets, log_w = args
    log_v, log_a, log_g = theta[0], theta[1], theta[2]
    # the expected H1 estimate at a bin is the average of R over the spectral window around it,
    # weighted by the (prewhitened) shallow spectrum there: log_w, normalised, is (J,) for a flat
    # one or (M, J) with the spectrum in it (``kernel_log_weights``)
    d_omega = omega[1] - omega[0]
    om = jnp.abs(omega[:, None] + offsets[None, :] * d_omega)
    log_r = log_r_fn(om / jnp.exp(log_v), d1, d2, jnp.exp(log_a))
    model = logsumexp(log_r + log_w, axis=-1) + log_g
    safe_err = jnp.where(mask, err, 1.0)
    return jnp.where(mask, (jnp.where(mask, y, 0.0) - model) / safe_err, 0.0)


def _residuals(theta, args):
    """Residuals of the exact (Gaussian window, Eq. 23) R curve."""
    return _pair_residuals(log_r_exact, theta, args)


def _residuals_rough(theta, args):
    """Residuals of the rough R curve (Eq. 26): a straight line whose offset gives a."""
    return _pair_residuals(log_r_rough, theta, args)


def _log_r_hertz_1d(alpha, d1, d2, a):
    # ky = 0: the Hertz projection is exact with one Chebyshev node; 4 panels: 4e-5 in log R for alpha a < 30
    return log_r_hertz(alpha, d1, d2, a, n_y=1, panels=4)


def _residuals_hertz(theta, args):
    """Residuals of the Hertz-window R curve (Eq. 12) for a texture varying along the slip."""
    return _pair_residuals(_log_r_hertz_1d, theta, args)


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


_RESIDUALS = {"exact": _residuals, "rough": _residuals_rough, "hertz": _residuals_hertz}


def fit_pair(omega, log_ratio, log_ratio_err, mask, d1, d2, *, gain_ratio=1.0, fit_gain=False,
             speed0=None, a0=None, bin_factor=1.0, kernel=((0.0,), (1.0,)), spectrum=None, solver="optimistix",
             curve: str = "exact") -> PairFit:
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
    curve: "exact" (Gaussian window, Eq. 23), "rough" (Eq. 26) or "hertz" (Eq. 12).
    """
    if curve not in _RESIDUALS:
        raise ValueError(f"unknown R curve {curve!r}; expected one of {CURVES}")
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
    res = least_squares(_RESIDUALS[curve], theta0, args, jnp.array([True, True, bool(fit_gain)]), solver=solver,
                        bin_factor=float(bin_factor))
    th = np.asarray(res.theta)
    redchi = float(res.redchi)
    inflate = max(redchi, 1.0) / redchi if redchi > 0 else 1.0      # errors only inflate, as in ``fit``
    sd = np.sqrt(np.clip(np.diag(np.asarray(res.cov)) * inflate, 0, None))
    v, a, g = np.exp(th)
    return PairFit(float(v), float(v * sd[0]), float(a), float(a * sd[1]), float(g),
                   float(g * sd[2]) if fit_gain else None, float(res.redchi), int(res.n_data),
                   bool(res.converged), float(res.cond))
