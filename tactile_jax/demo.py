"""The built-in example: the paper's Fig. 5 scene, simulated and measured (the ``demo`` command)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ._optional import MissingExtra
from .closed_form import SlopeFit, slope_speed
from .fit import FitOptions, FitResult, fit_recording
from .r_curve import log_r_exact
from .scene import Scene, simulate
from .spectra import amplitude_ratio, estimate_spectra, usable_band
from .texture import RandomTexture

__all__ = ["DemoResult", "paper_fig5_scene", "run_demo", "DEFAULT_PREWHITEN"]

#: AR order of the prewhitening filter used by the demo (see ``prewhiten``)
DEFAULT_PREWHITEN = 8


class DemoResult(NamedTuple):
    """Truth next to the estimates for the demo scene (SI units) and where the figure went.

    figure: the figure's path, or None when none was written. note: why not, for people
    (e.g. the ``pip install`` line of the ``plot`` extra); empty otherwise. seconds: wall time (s).
    """

    scene: Scene
    slope: SlopeFit
    fit: FitResult
    band_hz: tuple[float, float]
    figure: Path | None
    seconds: float
    note: str = ""


def paper_fig5_scene(seed: int = 0, duration: float = 16.0) -> Scene:
    """Paper Fig. 5: random (foamed-polystyrene-like) texture slid along x at 2.3 cm/s.

    The paper does not state the contact; we take a = 3 mm (its Fig. 4
    contact), Gaussian window, 1 kHz, 50 dB SNR on the paper's sensor.
    """
    return Scene(texture=RandomTexture(), velocity=(0.023, 0.0), contact_radius=3e-3, window="gaussian",
                 fs=1000.0, duration=duration, snr_db=50.0, seed=seed)


def run_demo(out_dir="tactile_jax_demo", *, seed: int = 0, duration: float = 16.0, method: str = "welch",
             plot: bool = True) -> DemoResult:
    """Simulate the Fig. 5 scene; estimate |vx| by the Eq. 6 slope of the x pair and (vx, vy, a) by the
    joint fit of both pairs (``fit.fit_recording``, the exact window model); save a figure (``plot``;
    without matplotlib, ``figure`` is None and ``note`` names the ``plot`` extra)."""
    t0 = time.perf_counter()
    scene = paper_fig5_scene(seed, duration)
    rec = simulate(scene)
    d1, d2 = rec.depths
    spec = estimate_spectra(rec.signals, rec.fs, method=method, prewhiten=DEFAULT_PREWHITEN)
    ratio = amplitude_ratio(spec)
    band = usable_band(ratio)
    args = (ratio.omega, ratio.log_ratio[0], ratio.log_ratio_err[0], band[0], d1, d2)
    line = slope_speed(*args, bin_factor=spec.bin_factor)
    fit = fit_recording(rec, FitOptions(method=method, prewhiten=DEFAULT_PREWHITEN))
    omega = np.asarray(ratio.omega)
    used = np.asarray(band[0])
    band_hz = (float(omega[used].min() / 2 / np.pi), float(omega[used].max() / 2 / np.pi)) if used.any() else (np.nan, np.nan)
    figure, note = None, ""
    if plot:
        from .plotting import plot_ratio_figure

        true_speed = abs(scene.velocity[0])
        om = np.linspace(1e-3, omega[used].max() * 1.1 if used.any() else omega.max(), 300)
        a_fit = fit.a if fit.a is not None else scene.contact_radius
        curves = {
            f"joint fit: |vx| = {100 * fit.vx:.3f} cm/s, a = {1e3 * a_fit:.2f} mm (exact R, Eq. 23)":
                np.asarray(log_r_exact(om / fit.vx, d1, d2, a_fit)),
            "Eq. 15 line at the true speed": -om * (d2 - d1) / true_speed,
        }
        try:
            figure = plot_ratio_figure(
                Path(out_dir) / "fig5_demo.png", freq=np.asarray(spec.freq), psd_shallow=np.asarray(spec.psd[0]),
                psd_deep=np.asarray(spec.psd[1]), omega=omega, log_ratio=np.asarray(ratio.log_ratio[0]),
                log_ratio_err=np.asarray(ratio.log_ratio_err[0]), band=used, line=(float(line.intercept), float(line.slope)),
                line_label=f"Eq. 6 line: |vx| = {100 * float(line.speed):.3f} cm/s", curves={"om": om, **curves},
                title=(f"Fig. 5 scene: random texture at {100 * true_speed:.1f} cm/s along x, "
                       f"a = {1e3 * scene.contact_radius:.1f} mm (simulated)"))
        except MissingExtra as err:
            note = f"figure not written: {err}"
    return DemoResult(scene, line, fit, band_hz, figure, time.perf_counter() - t0, note)
