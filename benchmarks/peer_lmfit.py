"""A scipy / lmfit peer of the exact-R pair fit, for benchmarks/speed_vs_error.py.

An independent implementation of the same estimator with the tools a
scientist would reach for: ``scipy.signal.welch`` / ``csd`` (Hann, the same
segment length as tactile_jax's default, no prewhitening), the H1 log
amplitude ratio |S12| / S11 with the Bendat & Piersol error
sqrt((1 - g2) / (2 K g2)), the same band rule (coherence above the
deep-probe SNR level and the 1 % Bonferroni zero-coherence level, error of
the log <= 0.5), the exact R curve (paper Eq. 23, Gaussian window) in numpy
with ``scipy.special.erfcx``, fitted by ``lmfit`` (MINPACK leastsq) in log
v, log a; and lmfit's emcee wrapper for the posterior. SI units throughout.

    python benchmarks/peer_lmfit.py            # self-check on one simulated scene
"""

from __future__ import annotations

import time
from typing import NamedTuple

import lmfit
import numpy as np
from scipy import signal, special

_SQRT_6 = np.sqrt(6.0)
_SQRT_3_2 = np.sqrt(1.5)


def log_g(alpha, depth, a):
    """log G(alpha; d, a) of the Gaussian window (docs/model.md), numpy; alpha rad/m, d and a in m."""
    alpha = np.abs(alpha)
    u = alpha * a / _SQRT_6
    c = _SQRT_3_2 * depth / a
    z, zp = c - u, c + u
    neg = z < 0
    zs = np.where(neg, 0.0, z)
    zn = np.where(neg, z, 0.0)
    with np.errstate(over="ignore", under="ignore"):
        pos = -np.square(alpha * a) / 6.0 + np.log(0.5 * (special.erfcx(zs) + special.erfcx(zp)))
        negv = (-alpha * depth + 1.5 * depth ** 2 / a ** 2
                + np.log(0.5 * (special.erfc(zn) + np.exp(-np.square(zn)) * special.erfcx(zp))))
    return np.where(neg, negv, pos)


def log_r_exact(alpha, d1, d2, a):
    """log R = log G(d2) - log G(d1), the exact R curve (Eq. 23), numpy."""
    return log_g(alpha, d2, a) - log_g(alpha, d1, a)


class PeerSpectra(NamedTuple):
    omega: np.ndarray         # (M,) rad/s
    log_ratio: np.ndarray     # (2, M) log|S12| / S11
    log_ratio_err: np.ndarray  # (2, M)
    band: np.ndarray          # (2, M) bool
    dof: float


def spectra(signals, fs, nperseg):
    """Welch H1 log amplitude ratios of both pairs with scipy.signal; signals (4, N)."""
    x = np.asarray(signals, float)
    f, s11 = signal.welch(x[[0, 2]], fs, nperseg=nperseg)
    _, s22 = signal.welch(x[[1, 3]], fs, nperseg=nperseg)
    _, s12 = signal.csd(x[[0, 2]], x[[1, 3]], fs, nperseg=nperseg)
    k = 2 * (x.shape[-1] // nperseg) - 1           # 50 % overlap Hann segments
    dof = k * 0.95                                  # Welch's correction for 50 % Hann overlap (approx.)
    with np.errstate(divide="ignore", invalid="ignore"):
        g2 = np.abs(s12) ** 2 / (s11 * s22)
        lr = np.log(np.abs(s12)) - np.log(s11)
        err = np.sqrt(np.clip(1 - g2, 0, None) / (2 * dof * g2))
    m = f.size
    sig = 1 - (0.01 / m) ** (1 / (dof - 1))
    band = (g2 > 0.5) & (g2 > sig) & (err <= 0.5) & (f > 0) & np.isfinite(lr) & np.isfinite(err)
    return PeerSpectra(2 * np.pi * f, lr, err, band, dof)


def _residual(params, omega, y, err, d1, d2):
    v = np.exp(params["log_v"].value)
    a = np.exp(params["log_a"].value)
    return (y - log_r_exact(omega / v, d1, d2, a)) / err


def _start(omega, y, err, d1, d2):
    """Eq. 6 weighted line for the start (speed) and Eq. 26 offset (radius)."""
    w = 1 / err ** 2
    slope, icpt = np.polyfit(omega, y, 1, w=np.sqrt(w))
    v0 = (d2 - d1) / -slope if slope < 0 else 0.01
    a0 = np.sqrt(1.5 * (d2 ** 2 - d1 ** 2) / icpt) if icpt > 0 else 2e-3
    return float(np.clip(v0, 1e-4, 1.0)), float(np.clip(a0, 2e-5, 0.05))


class PeerFit(NamedTuple):
    speed: float
    speed_err: float
    a: float
    a_err: float
    success: bool
    redchi: float
    nfev: int
    minimizer: object
    result: object


def fit_pair(omega, log_ratio, log_ratio_err, mask, d1, d2) -> PeerFit:
    """lmfit leastsq of the exact R curve to one pair's log amplitude ratio (unit gain ratio)."""
    om, y, err = omega[mask], log_ratio[mask], log_ratio_err[mask]
    v0, a0 = _start(om, y, err, d1, d2)
    params = lmfit.Parameters()
    params.add("log_v", value=np.log(v0))
    params.add("log_a", value=np.log(a0), min=np.log(1e-5), max=np.log(0.1))
    mini = lmfit.Minimizer(_residual, params, fcn_args=(om, y, err, d1, d2))
    res = mini.minimize(method="leastsq")
    v, a = np.exp(res.params["log_v"].value), np.exp(res.params["log_a"].value)
    sv = res.params["log_v"].stderr
    sa = res.params["log_a"].stderr
    return PeerFit(float(v), float(v * sv) if sv else np.nan, float(a), float(a * sa) if sa else np.nan,
                   bool(res.success), float(res.redchi), int(res.nfev), mini, res)


def emcee_mean(peer: PeerFit, *, steps=300, burn=100, nwalkers=20, seed=0):
    """Posterior means of |v| and a by lmfit's emcee wrapper started at the leastsq fit."""
    res = peer.minimizer.emcee(params=peer.result.params, steps=steps, burn=burn, nwalkers=nwalkers,
                               is_weighted=True, progress=False, seed=seed)
    chain = peer.minimizer.sampler.get_chain(discard=burn, flat=True)       # (draws, nvarys); no pandas needed
    names = list(res.var_names)
    return (float(np.mean(np.exp(chain[:, names.index("log_v")]))),
            float(np.mean(np.exp(chain[:, names.index("log_a")]))))


def run(signals, fs, d1, d2, nperseg, pair: int = 0):
    """The whole peer pipeline on one recording's pair: (PeerFit, seconds for spectra, seconds for the fit)."""
    t0 = time.perf_counter()
    sp = spectra(signals, fs, nperseg)
    t1 = time.perf_counter()
    fit = fit_pair(sp.omega, sp.log_ratio[pair], sp.log_ratio_err[pair], sp.band[pair], d1, d2)
    return fit, t1 - t0, time.perf_counter() - t1


if __name__ == "__main__":
    import jax

    jax.config.update("jax_enable_x64", True)
    from tactile_jax.cli.demo import paper_fig5_scene
    from tactile_jax.model.r_curve import log_r_exact as jax_log_r
    from tactile_jax.simulation.scene import simulate
    from tactile_jax.spectral.estimate import default_nperseg

    alpha = np.geomspace(1.0, 1e6, 50)
    for a in (1e-4, 3e-3, 5e-2):
        diff = np.max(np.abs(log_r_exact(alpha, 0.265e-3, 0.925e-3, a) - np.asarray(jax_log_r(alpha, 0.265e-3, 0.925e-3, a))))
        print(f"numpy vs tactile_jax log R, a = {a * 1e3:g} mm: max |diff| {diff:.1e}")
    rec = simulate(paper_fig5_scene(seed=0, duration=8.0))
    fit, ts, tf = run(rec.signals, rec.fs, *rec.depths, default_nperseg(rec.signals.shape[-1]))
    print(f"|vx| {100 * fit.speed:.3f} +/- {100 * fit.speed_err:.3f} cm/s (2.3), a {1e3 * fit.a:.3f} +/- "
          f"{1e3 * fit.a_err:.3f} mm (3.0); spectra {1e3 * ts:.1f} ms, fit {1e3 * tf:.1f} ms, nfev {fit.nfev}")
    print("emcee mean (|v|, a):", emcee_mean(fit, steps=200, burn=50))
