"""The rough-vs-exact R curve study of ``tactile-jax compare-r``: the comparison of ``inference.compare_r``
run on simulated recordings too, and drawn.

``simulator_ratio`` makes a pair's log ratio from a recording of the space-domain
simulator; ``fit_bias`` is ``inference.compare_r.fit_bias`` with ``source="simulator"``
as well; ``write_figures`` draws the error maps (matplotlib imported only when
called). Every name of ``inference.compare_r`` is re-exported here, so this module
is the whole study. SI units, as there.
"""

from __future__ import annotations

import jax
import numpy as np

from ..inference.compare_r import HERTZ_TO_GAUSS as HERTZ_TO_GAUSS
from ..inference.compare_r import BiasRow as BiasRow
from ..inference.compare_r import RatioData as RatioData
from ..inference.compare_r import fit_bias as _fit_bias
from ..inference.compare_r import format_bias_table as format_bias_table
from ..inference.compare_r import rough_error_plane as rough_error_plane
from ..inference.compare_r import rough_error_sensor as rough_error_sensor
from ..inference.compare_r import rough_valid_alpha as rough_valid_alpha
from ..inference.compare_r import synthetic_ratio as synthetic_ratio
from ..inference.compare_r import window_error_plane as window_error_plane
from ..model.sensor import PAPER_SENSOR

__all__ = [
    "HERTZ_TO_GAUSS",
    "BiasRow",
    "RatioData",
    "fit_bias",
    "format_bias_table",
    "rough_error_plane",
    "rough_error_sensor",
    "rough_valid_alpha",
    "simulator_ratio",
    "synthetic_ratio",
    "window_error_plane",
    "write_figures",
]

_D1, _D2 = float(PAPER_SENSOR.d1), float(PAPER_SENSOR.d2)


def simulator_ratio(speed, a, *, window: str = "gaussian", duration: float = 8.0, snr_db: float = 50.0,
                    seed: int = 0, prewhiten: int = 8) -> RatioData:
    """The x pair's log amplitude ratio of a simulated recording (``scene.simulate``, slip along x).

    Welch spectra after AR prewhitening and the usable band of ``spectra.usable_band``,
    as the fit pipeline uses them.
    """
    from ..simulation.scene import Scene, simulate
    from ..spectral.estimate import amplitude_ratio, estimate_spectra, usable_band, whitened_psd

    rec = simulate(Scene(velocity=(speed, 0.0), contact_radius=a, window=window, duration=duration, snr_db=snr_db,
                         seed=seed))
    spec = estimate_spectra(np.asarray(rec.signals, float), rec.fs, method="welch", prewhiten=prewhiten)
    ratio = amplitude_ratio(spec)
    band = np.asarray(usable_band(ratio))[0]
    return RatioData(np.asarray(ratio.omega), np.asarray(ratio.log_ratio[0]), np.asarray(ratio.log_ratio_err[0]),
                     band, float(speed), float(a), spec.kernel, float(spec.bin_factor),
                     np.asarray(whitened_psd(spec)[0]))


def _simulated(speed, a, *, truth: str, seed: int, **kw) -> RatioData:
    """``simulator_ratio`` as ``inference.compare_r.fit_bias``'s data maker: the truth is the simulator's window."""
    return simulator_ratio(speed, a, window=truth, seed=seed, **kw)


def fit_bias(a_values, speeds, *, source="synthetic", **kw) -> list[BiasRow]:
    """``inference.compare_r.fit_bias``; source "simulator" fits ``simulator_ratio``'s recordings (truth:
    the simulator's window, "gaussian" or "hertz"; extra keywords go to ``simulator_ratio``)."""
    return _fit_bias(a_values, speeds, source=_simulated if source == "simulator" else source, **kw)


# --------------------------------------------------------------------------- figures


def write_figures(out_dir, *, tol: float = 0.05, speeds=(0.023, 0.047), fs: float = 1000.0) -> list:
    """PNG maps of the rough-curve error (dimensionless plane, paper sensor) and of Gaussian vs Hertz."""
    from pathlib import Path

    from ..viz.figures import pyplot, save_figure

    plt = pyplot()                                        # MissingExtra naming the plot extra without matplotlib
    from matplotlib.colors import LogNorm

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    norm = LogNorm(1e-4, 10.0)

    # 1. dimensionless plane
    x = np.geomspace(1e-1, 1e3, 300)                     # alpha a
    y = np.geomspace(1e-2, 10.0, 200)                    # d2 / a
    err = np.asarray(rough_error_plane(x[None, :], y[:, None]))
    fig, ax = plt.subplots(figsize=(7, 5))
    m = ax.pcolormesh(x, y, np.clip(err, 1e-4, 10), norm=norm, shading="auto", cmap="viridis")
    ax.contour(x, y, err, levels=[tol], colors="w", linewidths=1.5)
    ax.plot(3 * y, y, "r--", lw=1, label="alpha a = 3 d2 / a (Eq. 26 validity scale)")
    ax.set(xscale="log", yscale="log", xlabel="alpha a", ylabel="d2 / a", xlim=(x[0], x[-1]), ylim=(y[0], y[-1]),
           title=f"|log R_rough - log R_exact| at d1/d2 = {_D1 / _D2:.3f}\nwhite: {tol:g} (rough valid to its right)")
    ax.legend(loc="lower right", fontsize=8)
    fig.colorbar(m, ax=ax)
    paths.append(save_figure(fig, out / "rough_vs_exact_plane.png"))

    # 2. the paper's sensor: alpha and a, with the alpha band of 1-fs/2 Hz at a few speeds
    alpha = np.geomspace(10.0, 1e5, 300)
    a = np.geomspace(0.2e-3, 20e-3, 200)
    err = np.asarray(rough_error_sensor(alpha[None, :], a[:, None]))
    fig, ax = plt.subplots(figsize=(7, 5))
    m = ax.pcolormesh(alpha, 1e3 * a, np.clip(err, 1e-4, 10), norm=norm, shading="auto", cmap="viridis")
    ax.contour(alpha, 1e3 * a, err, levels=[tol], colors="w", linewidths=1.5)
    for i, (v, c) in enumerate(zip(speeds, ("r", "orange", "m"))):
        lo, hi = 2 * np.pi * 2.0 / v, min(2 * np.pi * (fs / 2) / v, alpha[-1])
        ax.axvspan(lo, hi, ymin=0.02 + 0.04 * i, ymax=0.05 + 0.04 * i, color=c, alpha=0.9,
                   label=f"2 Hz - fs/2 at {100 * v:g} cm/s")
        ax.axvline(2 * np.pi * 50.0 / v, color=c, ls=":", lw=1, label=f"50 Hz at {100 * v:g} cm/s")
    for a_mark in (0.85, 2.2):
        ax.axhline(a_mark, color="w", ls="--", lw=0.7)
    ax.set(xscale="log", yscale="log", xlabel="alpha = omega / |v|  (rad/m)", ylabel="a (mm)",
           xlim=(alpha[0], alpha[-1]),
           title=f"paper sensor (d1 = {1e3 * _D1:g}, d2 = {1e3 * _D2:g} mm): |log R_rough - log R_exact|\n"
                 f"white: {tol:g} (rough valid to its right); dashed: a = 0.85, 2.2 mm")
    ax.legend(loc="upper right", fontsize=7)
    fig.colorbar(m, ax=ax)
    paths.append(save_figure(fig, out / "rough_vs_exact_sensor.png"))

    # 3. Gaussian vs Hertz window (equal second moment), dimensionless
    x = np.geomspace(1e-1, 30.0, 160)
    y = np.geomspace(1e-2, 10.0, 80)
    err = np.asarray(jax.jit(window_error_plane)(x[None, :], y[:, None]))
    fig, ax = plt.subplots(figsize=(7, 5))
    m = ax.pcolormesh(x, y, np.clip(np.nan_to_num(err, nan=10.0, posinf=10.0), 1e-4, 10), norm=norm,
                      shading="auto", cmap="viridis")
    ax.contour(x, y, np.nan_to_num(err, nan=10.0, posinf=10.0), levels=[tol], colors="w", linewidths=1.5)
    ax.set(xscale="log", yscale="log", xlabel="alpha a_hertz", ylabel="d2 / a_hertz",
           title="|log R_gauss(a) - log R_hertz(a)| (1-D texture, equal radius)\n" + f"white: {tol:g}")
    fig.colorbar(m, ax=ax)
    paths.append(save_figure(fig, out / "gauss_vs_hertz_plane.png"))
    return paths
