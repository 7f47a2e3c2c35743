"""The per-recording loop a user without tactile_jax would write: scipy.signal + scipy.optimize.curve_fit.

Same model as ``tactile-jax batch --model pair``: for each probe pair, the H1
log amplitude ratio log(|S12| / S11) from Welch spectra (scipy.signal.welch /
csd, Hann, 50 % overlap, the same segment length), bins kept where the
coherence exceeds the 1 % zero-coherence level and 0.5 and the Bendat &
Piersol error is below 0.5, then ``curve_fit`` of the exact R curve
(docs/model.md, Eq. 23 in log space) for log|v|, log a, weighted by that error,
started from the Eq. 6 straight line. No prewhitening, no spectral-window
model (a user would not write them). Used by ``throughput.py`` as the
reference; run alone it fits one recording file:

    python benchmarks/scipy_reference.py scene.h5
"""

from __future__ import annotations

import sys

import numpy as np
from scipy import optimize, signal, special

LOG2 = np.log(2.0)


def _log_erfc(z):
    """log erfc(z), stable for large |z|: log erfcx(z) - z^2 for z > 0."""
    z = np.asarray(z, float)
    pos = z > 0
    out = np.empty_like(z)
    out[pos] = np.log(special.erfcx(z[pos])) - z[pos] ** 2
    out[~pos] = np.log(special.erfc(z[~pos]))
    return out


def log_g(alpha, d, a):
    """log G(alpha; d, a) of the Gaussian window, normalised (G -> exp(-|alpha| d) for a -> inf)."""
    alpha = np.abs(alpha)
    s = np.sqrt(3.0) / a
    t1 = -alpha * d + _log_erfc((s * s * d - alpha) / (s * np.sqrt(2)))
    t2 = alpha * d + _log_erfc((s * s * d + alpha) / (s * np.sqrt(2)))
    return s * s * d * d / 2 + np.logaddexp(t1, t2) - LOG2


def log_r(omega, log_v, log_a, d1, d2):
    alpha = omega / np.exp(log_v)
    a = np.exp(log_a)
    return log_g(alpha, d2, a) - log_g(alpha, d1, a)


def fit_record(x, fs, d1, d2, nperseg):
    """(|vx|, |vy|, a) with one-sigma errors, NaN where a pair cannot be fitted; x: (4, N)."""
    kw = dict(fs=fs, nperseg=nperseg, noverlap=nperseg // 2, window="hann")
    f, pxx = signal.welch(x, **kw)
    omega = 2 * np.pi * f
    k = (x.shape[-1] - nperseg) // (nperseg // 2) + 1
    level = 1 - (0.01 / f.size) ** (1 / (k - 1))
    out = []
    for p in (0, 2):
        _, s12 = signal.csd(x[p], x[p + 1], **kw)
        s11, s22 = pxx[p], pxx[p + 1]
        g2 = np.abs(s12) ** 2 / (s11 * s22)
        y = np.log(np.abs(s12) / s11)
        err = np.sqrt(np.clip(1 - g2, 0, None) / (2 * k * np.maximum(g2, 1e-300)))
        sel = (g2 > max(level, 0.5)) & (err <= 0.5) & (omega > 0) & np.isfinite(y)
        if sel.sum() < 5:
            out.append((np.nan, np.nan, np.nan, np.nan))
            continue
        om, yy, ee = omega[sel], y[sel], err[sel]
        slope, icpt = np.polyfit(om, yy, 1, w=1 / ee)
        v0 = -(d2 - d1) / slope if slope < 0 else 0.01
        a0 = np.sqrt(1.5 * (d2 ** 2 - d1 ** 2) / icpt) if icpt > 0 else 2e-3
        try:
            popt, pcov = optimize.curve_fit(lambda o, lv, la: log_r(o, lv, la, d1, d2), om, yy,
                                            p0=[np.log(v0), np.log(np.clip(a0, 2e-5, 0.05))], sigma=ee,
                                            absolute_sigma=False, maxfev=2000)
            redchi = np.sum(((yy - log_r(om, *popt, d1, d2)) / ee) ** 2) / max(sel.sum() - 2, 1)
            sd = np.sqrt(np.diag(pcov) * max(redchi, 1.0) / redchi)
            v, a = np.exp(popt)
            out.append((v, v * sd[0], a, a * sd[1]))
        except (RuntimeError, ValueError):
            out.append((np.nan, np.nan, np.nan, np.nan))
    (vx, vx_err, ax, ax_err), (vy, vy_err, ay, ay_err) = out
    a, a_err = (ax, ax_err) if not (ay_err / ay < ax_err / ax) else (ay, ay_err)
    return vx, vx_err, vy, vy_err, a, a_err


def welch_floor(batch, fs, nperseg):
    """Only the Welch auto- and cross-spectra of a (B, 4, N) batch, vectorised numpy (the floor)."""
    kw = dict(fs=fs, nperseg=nperseg, noverlap=nperseg // 2, window="hann", axis=-1)
    _, pxx = signal.welch(batch, **kw)
    _, pxy = signal.csd(batch[:, 0::2], batch[:, 1::2], **kw)
    return pxx, pxy


if __name__ == "__main__":  # pragma: no cover
    sys.path.insert(0, ".")
    from tactile_jax.io.files import read_recording

    rec = read_recording(sys.argv[1])
    sig = rec.signals if rec.signals.ndim == 3 else rec.signals[None]
    nper = 1 << ((sig.shape[-1] // 8).bit_length() - 1)
    for i, x in enumerate(sig):
        print(i, fit_record(np.asarray(x, float), rec.fs, *rec.depths, nper))
