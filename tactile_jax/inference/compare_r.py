"""When is the rough R curve (Eq. 26) good enough? Rough vs exact, Gaussian vs Hertz.

Two questions, each answered twice (curves, then fits):

- ``rough_error_plane`` / ``rough_error_sensor``: |log R_rough - log R_exact|
  over the dimensionless plane (alpha a, d2 / a) at the paper's d1 / d2, and
  over (alpha, a) for the paper's sensor; ``rough_valid_alpha`` the smallest
  alpha a beyond which the rough curve stays within a tolerance.
- ``window_error_plane``: the same for the Gaussian exact curve against the
  Hertz window (1-D texture along the slip), at equal radius and at equal
  second moment of the projected window (a_gauss = sqrt(3/5) a_hertz).
- ``fit_bias``: what the approximation does to a fit. Log ratios made with a
  truth curve (``"exact"`` or ``"hertz"``) plus spectral-estimate noise
  (``synthetic_ratio``), or by any data maker passed as ``source``, are fitted
  per pair (``pair_fit.fit_pair``) with each candidate curve; the rows give
  median relative biases of a and of the speed over seeds and the median wall
  time of one fit (compiled).

Everything is SI: alpha in rad/m, omega in rad/s, lengths in m, speeds in m/s.
This module is the comparison alone: the study around it (ratios of simulated
recordings, ``simulator_ratio``; the figures, ``write_figures``) is
``studies.compare_r``, which re-exports everything here.
"""

from __future__ import annotations

import dataclasses
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .pair_fit import PairFit as PairFitNaN
from .pair_fit import fit_pair
from ..model.r_curve import log_g, log_r_exact, log_r_hertz, log_r_rough
from ..model.sensor import PAPER_SENSOR

__all__ = [
    "HERTZ_TO_GAUSS",
    "BiasRow",
    "fit_bias",
    "format_bias_table",
    "rough_error_plane",
    "rough_error_sensor",
    "rough_valid_alpha",
    "RatioData",
    "synthetic_ratio",
    "window_error_plane",
]

#: Gaussian radius with the second moment of a Hertz window of radius 1 (a^2/3 vs a^2/5 along one axis)
HERTZ_TO_GAUSS = float(np.sqrt(3.0 / 5.0))

_D1, _D2 = float(PAPER_SENSOR.d1), float(PAPER_SENSOR.d2)


def rough_error_plane(alpha_a, d2_over_a, d1_over_d2: float = _D1 / _D2):
    """|log R_rough - log R_exact| at alpha a (dimensionless) and d2 / a; broadcasts.

    The error depends on alpha, a, d1, d2 only through alpha a, d2 / a and d1 / d2
    (default: the paper's 0.265 / 0.925).
    """
    alpha_a, d2 = jnp.broadcast_arrays(jnp.asarray(alpha_a, float), jnp.asarray(d2_over_a, float))
    d1 = d2 * d1_over_d2
    return jnp.abs(log_r_rough(alpha_a, d1, d2, 1.0) - log_r_exact(alpha_a, d1, d2, 1.0))


def rough_error_sensor(alpha, a, depths=(_D1, _D2)):
    """|log R_rough - log R_exact| for a sensor: alpha (rad/m), a (m), depths (m); broadcasts."""
    d1, d2 = depths
    return jnp.abs(log_r_rough(alpha, d1, d2, a) - log_r_exact(alpha, d1, d2, a))


_rough_error_plane_jit = jax.jit(rough_error_plane)


def rough_valid_alpha(d2_over_a, tol: float = 0.05, d1_over_d2: float = _D1 / _D2, *, max_alpha_a: float = 1e4,
                      n: int = 4000):
    """Smallest alpha a beyond which the rough curve is within ``tol`` of the exact one, per d2 / a.

    d2_over_a: (m,) values. Returns (m,) alpha a (dimensionless; inf when not
    reached below ``max_alpha_a``). Searched on a log grid of ``n`` points.
    """
    d2_over_a = np.atleast_1d(np.asarray(d2_over_a, float))
    grid = np.geomspace(1e-3, max_alpha_a, n)
    err = np.asarray(_rough_error_plane_jit(grid[None, :], d2_over_a[:, None], d1_over_d2))
    bad = err > tol
    out = np.full(d2_over_a.shape, np.inf)
    for i, row in enumerate(bad):
        if not row.any():
            out[i] = grid[0]
        elif not row[-1]:
            out[i] = grid[np.flatnonzero(row)[-1] + 1]
    return out


def _log_r_hertz_1d(alpha, d1, d2, a):
    return log_r_hertz(alpha, d1, d2, a, n_y=1, panels=4)       # ky = 0: one node is exact; 4e-5 for alpha a < 30


def window_error_plane(alpha_a, d2_over_a, d1_over_d2: float = _D1 / _D2, *, matched: bool = False):
    """|log R_gauss - log R_hertz| at alpha a_hertz and d2 / a_hertz (1-D texture along the slip).

    matched: compare with the Gaussian of equal projected second moment
    (a_gauss = sqrt(3/5) a_hertz), else (default) of equal radius, which is the
    closer of the two over most of the plane. The Hertz ratio has isolated
    spikes at the zeros of its line response beyond alpha a ~ 10.
    """
    alpha_a, d2 = jnp.broadcast_arrays(jnp.asarray(alpha_a, float), jnp.asarray(d2_over_a, float))
    d1 = d2 * d1_over_d2
    a_g = HERTZ_TO_GAUSS if matched else 1.0
    return jnp.abs(log_r_exact(alpha_a, d1, d2, a_g) - _log_r_hertz_1d(alpha_a, d1, d2, 1.0))


# --------------------------------------------------------------------------- fit bias


class BiasRow(NamedTuple):
    """One cell of the fit-bias table (medians over seeds).

    truth: curve or simulator window that made the data. curve: the curve fitted.
    a, speed: true contact radius (m) and speed (m/s). a_bias, speed_bias: median
    relative bias (fit / truth - 1). a_pull: median (fit - truth) / error.
    seconds: median wall time of one fit (compiled). n_ok: converged fits of n (medians
    use every finite fit). a_fit: median fitted a (m). redchi: median reduced chi-square.
    n_bins: median number of bins fitted.
    """

    truth: str
    curve: str
    a: float
    speed: float
    a_bias: float
    speed_bias: float
    a_pull: float
    speed_pull: float
    seconds: float
    n_ok: int
    n: int
    n_bins: float
    a_fit: float
    redchi: float


@dataclasses.dataclass(frozen=True)
class RatioData:
    """One pair's measured log amplitude ratio: omega (M,) rad/s, log_ratio, err (M,), mask (M,) bool;
    kernel (the spectral window), bin_factor, the truth (speed m/s, a m) and spectrum (M,), the
    prewhitened shallow spectrum that weights the window (None: flat; ``pair_fit.kernel_log_weights``)."""

    omega: np.ndarray
    log_ratio: np.ndarray
    err: np.ndarray
    mask: np.ndarray
    speed: float
    a: float
    kernel: tuple = ((0.0,), (1.0,))
    bin_factor: float = 1.0
    spectrum: np.ndarray | None = None


def synthetic_ratio(speed, a, *, truth: str = "exact", depths=(_D1, _D2), fs: float = 1000.0, nperseg: int = 512,
                    n_avg: float = 28.0, snr_db: float = 50.0, max_err: float = 0.5, seed: int = 0) -> RatioData:
    """Log ratio made with a truth curve plus the noise of a spectral estimate.

    Bins omega = 2 pi fs j / nperseg. The shallow and deep probes' per-bin SNR
    is 10^(snr_db/10) times G(alpha; d, a)^2 (Gaussian window of radius a, or
    of the matched radius sqrt(3/5) a for a Hertz truth); the coherence gives
    the Bendat-Piersol error sqrt((1 - g^2) / (2 K g^2)) with K = ``n_avg``; bins
    with error above ``max_err`` are dropped, as ``spectra.usable_band`` does.
    truth: "exact" (Gaussian window, Eq. 23) or "hertz" (Eq. 12, 1-D texture).
    """
    d1, d2 = depths
    omega = 2 * np.pi * fs * np.arange(1, nperseg // 2) / nperseg
    alpha = omega / speed
    a_snr = a * HERTZ_TO_GAUSS if truth == "hertz" else a
    snr0 = 10.0 ** (snr_db / 10.0)
    snr1 = snr0 * np.exp(2 * np.asarray(log_g(alpha, d1, a_snr)))
    snr2 = snr0 * np.exp(2 * np.asarray(log_g(alpha, d2, a_snr)))
    coh = 1.0 / ((1.0 + 1.0 / snr1) * (1.0 + 1.0 / snr2))
    err = np.sqrt((1.0 - coh) / (2.0 * n_avg * coh))
    if truth == "exact":
        log_r = np.asarray(log_r_exact(alpha, d1, d2, a))
    elif truth == "hertz":
        log_r = np.asarray(_log_r_hertz_1d(alpha, d1, d2, a))
    else:
        raise ValueError(f"unknown truth curve {truth!r}; expected 'exact' or 'hertz'")
    rng = np.random.default_rng(seed)
    y = log_r + err * rng.standard_normal(omega.size)
    mask = (err <= max_err) & np.isfinite(y)
    return RatioData(omega, np.where(mask, y, 0.0), np.where(mask, err, 1.0), mask, float(speed), float(a))


def _valid_band(data: RatioData, tol: float = 0.05):
    """The bins where the rough curve is within ``tol`` of the exact one at the TRUE a and speed (an oracle)."""
    alpha_min = float(rough_valid_alpha([_D2 / data.a], tol)[0]) / data.a
    return dataclasses.replace(data, mask=data.mask & (data.omega / data.speed >= alpha_min))


def _one_fit(data: RatioData, curve: str):
    d1, d2 = _D1, _D2
    if curve == "rough-valid":
        data, curve = _valid_band(data), "rough"
        if data.mask.sum() < 4:
            nan = float("nan")
            return PairFitNaN(nan, nan, nan, nan, nan, None, nan, int(data.mask.sum()), False, nan), 0.0
    kw = dict(kernel=data.kernel, bin_factor=data.bin_factor, spectrum=data.spectrum)
    t = time.perf_counter()
    if curve == "hertz":
        # the Hertz curve's LM needs a start near the basin: the Gaussian fit's (its time counts)
        g = fit_pair(data.omega, data.log_ratio, data.err, data.mask, d1, d2, curve="exact", **kw)
        if np.isfinite(g.speed) and np.isfinite(g.a):
            kw.update(speed0=g.speed, a0=g.a)
    f = fit_pair(data.omega, data.log_ratio, data.err, data.mask, d1, d2, curve=curve, **kw)
    return f, time.perf_counter() - t


def fit_bias(a_values, speeds, *, curves=("exact", "rough"), truth: str = "exact", seeds=(0, 1, 2),
             source="synthetic", **kw) -> list[BiasRow]:
    """Fit data made with ``truth`` by each of ``curves``; one ``BiasRow`` per (a, speed, curve).

    curves: "exact", "rough", "hertz" (``pair_fit`` curves) or "rough-valid": the rough
    curve on the bins where it is within 0.05 of the exact one at the true a
    and speed only (an oracle band: the best case for Eq. 26).
    a_values (m), speeds (m/s). source: "synthetic" (``synthetic_ratio``,
    truth "exact" or "hertz") or a data maker, called as
    ``source(speed, a, truth=truth, seed=seed, **kw)`` and returning ``RatioData``
    (``studies.compare_r.fit_bias`` takes "simulator" too: ``simulator_ratio``,
    truth "gaussian" or "hertz" window). Extra keywords go to the data maker.
    The first fit of each curve (compilation) is not timed.
    """
    if isinstance(source, str):
        if source != "synthetic":
            raise ValueError(f"unknown source {source!r}; expected 'synthetic' or a data maker "
                             "('simulator': studies.compare_r.fit_bias)")
        make = synthetic_ratio
    else:
        make = source
    warmed = set()
    rows = []
    for a in a_values:
        for v in speeds:
            datasets = [make(v, a, truth=truth, seed=s, **kw) for s in seeds]
            for curve in curves:
                if curve not in warmed:
                    _one_fit(datasets[0], "rough" if curve == "rough-valid" else curve)
                    warmed.add(curve)
                out = [_one_fit(d, curve) for d in datasets]
                # medians over every finite fit: a rough fit whose offset wants a -> inf does not converge
                # (log a walks off), and that is the result to show, not to drop; n_ok counts converged ones
                ok = [f for f, _ in out if np.isfinite(f.a) and np.isfinite(f.speed)]
                if ok:
                    a_b = np.median([f.a / a - 1 for f in ok])
                    v_b = np.median([f.speed / v - 1 for f in ok])
                    a_p = np.median([(f.a - a) / f.a_err if f.a_err > 0 else np.nan for f in ok])
                    v_p = np.median([(f.speed - v) / f.speed_err if f.speed_err > 0 else np.nan for f in ok])
                else:
                    a_b = v_b = a_p = v_p = np.nan
                rows.append(BiasRow(truth, curve, float(a), float(v), float(a_b), float(v_b), float(a_p), float(v_p),
                                    float(np.median([t for _, t in out])), sum(f.converged for f in ok), len(out),
                                    float(np.median([f.n_bins for f, _ in out])),
                                    float(np.median([f.a for f in ok])) if ok else np.nan,
                                    float(np.median([f.redchi for f in ok])) if ok else np.nan))
    return rows


def format_bias_table(rows: list[BiasRow]) -> str:
    """The fit-bias table for people (mm, cm/s, %, ms)."""
    head = (f"{'truth':<9}{'fitted':<12}{'a mm':>7}{'v cm/s':>8}{'bins':>6}{'a fit mm':>10}{'a bias %':>10}"
            f"{'a pull':>8}{'v bias %':>10}{'v pull':>8}{'redchi':>9}{'ms/fit':>9}{'ok':>6}")
    lines = [head, "-" * len(head)]
    for r in rows:
        a_fit = f"{1e3 * r.a_fit:>10.3f}" if r.a_fit < 0.05 else f"{'> 50':>10}"     # a at the bound: no window
        a_bias = f"{100 * r.a_bias:>+10.1f}" if abs(r.a_bias) < 10 else f"{'>+999':>10}"
        lines.append(f"{r.truth:<9}{r.curve:<12}{1e3 * r.a:>7.2f}{1e2 * r.speed:>8.2f}{r.n_bins:>6.0f}{a_fit}{a_bias}"
                     f"{r.a_pull:>+8.1f}{100 * r.speed_bias:>+10.2f}{r.speed_pull:>+8.1f}{r.redchi:>9.3g}"
                     f"{1e3 * r.seconds:>9.1f}{r.n_ok:>4}/{r.n}")
    return "\n".join(lines)
