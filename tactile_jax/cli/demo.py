"""``tactile-jax demo``, the built-in example: the paper's Fig. 5 scene, simulated and measured."""

from __future__ import annotations

import time
from pathlib import Path
from typing import NamedTuple

import click
import numpy as np

from .._optional import MissingExtra
from ..model.closed_form import SlopeFit, slope_speed
from ..inference.options import FitOptions
from ..inference.result import FitResult
from ..inference.fit import fit_recording
from ..model.r_curve import log_r_exact
from ..simulation.scene import Scene, simulate
from ..spectral.estimate import amplitude_ratio, estimate_spectra, usable_band
from ..simulation.texture import RandomTexture

from .common import optimise_later, quick_first, user_errors

__all__ = ["DemoResult", "paper_fig5_scene", "run_demo", "DEFAULT_PREWHITEN", "demo"]

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
        from ..viz.figures import plot_ratio_figure

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


@click.command(short_help="Simulate the paper's Fig. 5 scene and fit it.")
@click.option("--out-dir", default="tactile_jax_demo", show_default=True, type=click.Path(file_okay=False),
              help="Folder for the figure.")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--duration", type=float, default=16.0, show_default=True, help="Seconds of simulated recording.")
@click.option("--method", type=click.Choice(["welch", "multitaper"]), default="welch", show_default=True)
@user_errors
def demo(out_dir, seed, duration, method):
    """Simulate the paper's Fig. 5 scene and estimate the slip speed with an error bar."""
    from scipy.stats import chi2

    click.echo("Fig. 5 scene (simulated): random texture sliding along x at 2.3 cm/s, a = 3 mm, Gaussian window,")
    click.echo(f"  {duration:g} s at 1 kHz, SNR 50 dB; {method} spectra after AR({DEFAULT_PREWHITEN}) prewhitening")
    quick_first()
    try:
        r = run_demo(out_dir, seed=seed, duration=duration, method=method)
    finally:
        optimise_later(None)
    v = abs(r.scene.velocity[0])
    line, ex = r.slope, r.fit
    click.echo(f"  usable band: {int(line.n_bins)} bins, {r.band_hz[0]:.1f}-{r.band_hz[1]:.1f} Hz of the x pair")
    click.echo("")
    click.echo(f"  {'quantity':<26}{'truth':>10}{'estimate':>22}{'deviation':>18}")

    def row(name, truth, est, err, scale, unit, upper=None):
        if upper is not None and est is not None and err is None:       # held at 0 by the slip direction
            click.echo(f"  {name:<26}{scale * truth:>10.4f}{'0 (held), < ' + f'{scale * upper:.4f}':>22}"
                       f"{'95 % bound':>18}  {unit}")
            return
        if est is None or err is None:
            click.echo(f"  {name:<26}{scale * truth:>10.4f}{'not determined':>22}")
            return
        dev = est - truth
        rel = f"{100 * dev / truth:>+8.2f} %" if truth else " " * 10
        click.echo(f"  {name:<26}{scale * truth:>10.4f}{scale * est:>12.4f} +/- {scale * err:<6.4f}"
                   f"{rel} {dev / err:>+6.1f} sig  {unit}")

    row("|vx|, Eq. 6 slope", v, float(line.speed), float(line.speed_err), 100, "cm/s")
    row("|vx|, joint fit", v, ex.vx, ex.vx_err, 100, "cm/s")
    row("|vy|, joint fit", abs(r.scene.velocity[1]), ex.vy, ex.vy_err, 100, "cm/s", ex.vy_upper)
    row("a, joint fit", r.scene.contact_radius, ex.a, ex.a_err, 1e3, "mm")
    dof = max(int(line.n_bins) - 2, 1)
    if chi2.sf(float(line.redchi) * dof, dof) < 1e-3:
        click.echo(f"  warning: the log ratio is not a straight line (Eq. 6 reduced chi2 {float(line.redchi):.1f} on "
                   f"{dof} dof): the contact window bends it at low omega, so the slope is biased; "
                   "the joint fit's exact window model (Eq. 23) models it.")
    click.echo(f"  joint fit: status {ex.status}, reduced chi2 {ex.redchi:.2f}; {ex.message or 'no notes'}")
    click.echo(f"  figure: {r.figure}" if r.figure else f"  note: {r.note}")
    click.echo(f"  time: {r.seconds:.1f} s (simulation, spectra, fits, figure; JIT compile included)")
