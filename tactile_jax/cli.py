"""The ``tactile-jax`` command line: ``simulate`` and ``demo``.

Flags take SI units (m, m/s, Hz); output for people is in mm and cm/s, labelled.
Bad input ends with one line ``error: <file>: <problem>`` and exit status 2.
"""

from __future__ import annotations

import functools
import sys

import click
import jax

from .errors import TactileInputError

# float64 is chosen here, at the entry point (the library never switches it on itself)
jax.config.update("jax_enable_x64", True)


def _user_errors(fn):
    """Turn input errors into one line on stderr and exit status 2, never a traceback."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except TactileInputError as err:
            click.echo(f"error: {err}", err=True)
            sys.exit(2)
        except OSError as err:
            click.echo(f"error: {getattr(err, 'filename', None) or ''}: {err.strerror or err}", err=True)
            sys.exit(2)

    return wrapper


def _floats(text: str, n: int, name: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise TactileInputError(f"--{name} must be {n} comma-separated numbers, got {text!r}", code="bad_setting") from None
    if len(values) != n:
        raise TactileInputError(f"--{name} must be {n} comma-separated numbers, got {text!r}", code="bad_setting")
    return values


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="tactile_jax")
def main():
    """Slip velocity, contact radius and texture spectra from a vertical-sampling tactile sensor."""


@main.command()
@click.option("--out", "out", required=True, type=click.Path(dir_okay=False), help="Recording file to write (.h5, .hdf5 or .npz).")
@click.option("--texture", type=click.Choice(["random", "grating", "net"]), default="random", show_default=True,
              help="random (foamed polystyrene), grating (1-D, like the paper's pipes) or net (wire net).")
@click.option("--pitch", type=float, default=None, help="Grating or net pitch, m (defaults 1.5e-3 and 0.5e-3).")
@click.option("--angle", type=float, default=0.0, show_default=True, help="Grating wavevector angle from the x axis, degrees.")
@click.option("--velocity", default="0.023,0.0", show_default=True, help="Slip vx,vy in m/s.")
@click.option("--contact-radius", type=float, default=None, help="Contact radius a, m (default 3e-3 unless --contact-depth).")
@click.option("--contact-depth", type=float, default=None, help="Contact depth, m; a = sqrt(R d) with R = 30 mm.")
@click.option("--window", type=click.Choice(["gaussian", "hertz"]), default="gaussian", show_default=True)
@click.option("--fs", type=float, default=1000.0, show_default=True, help="Sample rate, Hz.")
@click.option("--duration", type=float, default=16.0, show_default=True, help="Seconds.")
@click.option("--snr-db", type=float, default=50.0, show_default=True, help="Signal-to-noise ratio in dB (see Scene).")
@click.option("--noiseless", is_flag=True, help="No additive noise.")
@click.option("--gains", default="1,1,1,1", show_default=True, help="Per-probe gains x1,x2,y1,y2.")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--records", type=int, default=1, show_default=True, help="Records to write (n, 4, N), seeds seed..seed+n-1.")
@_user_errors
def simulate(out, texture, pitch, angle, velocity, contact_radius, contact_depth, window, fs, duration, snr_db,
             noiseless, gains, seed, records):
    """Simulate a scene and write it as a recording file with its truth."""
    import dataclasses
    import math

    import numpy as np

    from .io import write_recording
    from .scene import Scene, simulate as run
    from .texture import Grating, RandomTexture, WireNet

    if texture == "random":
        tex = RandomTexture()
    elif texture == "grating":
        tex = Grating(pitch=pitch or 1.5e-3, angle=math.radians(angle))
    else:
        tex = WireNet(pitch=pitch or 0.5e-3)
    if contact_radius is None and contact_depth is None:
        contact_radius = 3e-3
    if records < 1:
        raise TactileInputError(f"--records must be at least 1, got {records}", code="bad_setting")
    scene = Scene(texture=tex, velocity=_floats(velocity, 2, "velocity"), contact_radius=contact_radius,
                  contact_depth=contact_depth, window=window, fs=fs, duration=duration,
                  snr_db=None if noiseless else snr_db, gains=_floats(gains, 4, "gains"), seed=seed)
    recs = [run(dataclasses.replace(scene, seed=seed + i)) for i in range(records)]
    rec = recs[0]
    if records > 1:
        rec = dataclasses.replace(rec, signals=np.stack([r.signals for r in recs]),
                                  truth={**rec.truth, "seeds": [seed + i for i in range(records)]})
    path = write_recording(out, rec)
    t = rec.truth
    click.echo(f"wrote {path}: {records} x 4 x {rec.n_samples} samples at {rec.fs:g} Hz; "
               f"vx = {100 * t['vx']:.3f} cm/s, vy = {100 * t['vy']:.3f} cm/s, a = {1e3 * t['a']:.3f} mm ({t['window']})")


@main.command()
@click.argument("recording", type=click.Path(dir_okay=False))
@click.option("--out", "out", required=True, type=click.Path(dir_okay=False), help="Spectra file to write (.h5 or .npz).")
@click.option("--method", type=click.Choice(["welch", "multitaper"]), default="welch", show_default=True)
@click.option("--nperseg", type=int, default=None, help="Welch segment length, samples (default: N/8 rounded down to a power of two).")
@click.option("--prewhiten", type=int, default=8, show_default=True, help="AR order of the prewhitening filter (0: off).")
@click.option("--record", type=int, default=0, show_default=True, help="Record index in a multi-record file.")
@_user_errors
def spectra(recording, out, method, nperseg, prewhiten, record):
    """Estimate auto/cross spectra and amplitude ratios of a recording; write a spectra file."""
    import numpy as np

    from .io import SpectraData, read_recording, write_spectra
    from .spectra import amplitude_ratio, estimate_spectra

    rec = read_recording(recording)
    if not 0 <= record < rec.n_records:
        raise TactileInputError(f"--record {record} out of range: the file holds {rec.n_records} record(s)",
                                source=recording, code="bad_setting")
    one = rec.record(record)
    kw = {"nperseg": nperseg} if (nperseg and method == "welch") else {}
    try:
        spec = estimate_spectra(np.asarray(one.signals, float), one.fs, method=method, prewhiten=prewhiten or None, **kw)
    except TactileInputError as err:
        raise err.with_source(recording) from None
    ratio = amplitude_ratio(spec)
    data = SpectraData(omega=np.asarray(spec.omega), psd=np.asarray(spec.psd), csd=np.asarray(spec.csd),
                       n_segments=float(spec.dof), ratio=np.exp(np.asarray(ratio.log_ratio))[:, 1:],
                       ratio_err=np.asarray(ratio.log_ratio_err)[:, 1:], depths=one.depths,
                       curvature_radius=one.curvature_radius, velocity=one.velocity, gain_ratio=one.gain_ratio)
    # DC carries no ratio: the ratio arrays start at the first bin, so drop DC from every array
    data = data._replace(omega=data.omega[1:], psd=data.psd[:, 1:], csd=data.csd[:, 1:])
    path = write_spectra(out, data)
    click.echo(f"wrote {path}: {data.omega.size} bins up to {data.omega[-1] / (2 * np.pi):g} Hz "
               f"({method}, K_eff = {spec.dof:.1f}, prewhiten AR({prewhiten}))")


@main.command()
@click.option("--out-dir", default="tactile_jax_demo", show_default=True, type=click.Path(file_okay=False),
              help="Folder for the figure.")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--duration", type=float, default=16.0, show_default=True, help="Seconds of simulated recording.")
@click.option("--method", type=click.Choice(["welch", "multitaper"]), default="welch", show_default=True)
@_user_errors
def demo(out_dir, seed, duration, method):
    """Simulate the paper's Fig. 5 scene and estimate the slip speed with an error bar."""
    from scipy.stats import chi2

    from .demo import DEFAULT_PREWHITEN, run_demo

    click.echo("Fig. 5 scene (simulated): random texture sliding along x at 2.3 cm/s, a = 3 mm, Gaussian window,")
    click.echo(f"  {duration:g} s at 1 kHz, SNR 50 dB; {method} spectra after AR({DEFAULT_PREWHITEN}) prewhitening")
    r = run_demo(out_dir, seed=seed, duration=duration, method=method)
    v = abs(r.scene.velocity[0])
    line, ex = r.slope, r.exact
    click.echo(f"  usable band: {int(line.n_bins)} bins, {r.band_hz[0]:.1f}-{r.band_hz[1]:.1f} Hz of the x pair")
    click.echo("")
    click.echo(f"  {'quantity':<26}{'truth':>10}{'estimate':>22}{'deviation':>18}")

    def row(name, truth, est, err, scale, unit):
        dev = est - truth
        click.echo(f"  {name:<26}{scale * truth:>10.4f}{scale * est:>12.4f} +/- {scale * err:<6.4f}"
                   f"{100 * dev / truth:>+8.2f} % {dev / err:>+6.1f} sig  {unit}")

    row("|vx|, Eq. 6 slope", v, float(line.speed), float(line.speed_err), 100, "cm/s")
    row("|vx|, exact R fit", v, ex.speed, ex.speed_err, 100, "cm/s")
    row("a, exact R fit", r.scene.contact_radius, ex.a, ex.a_err, 1e3, "mm")
    dof = max(int(line.n_bins) - 2, 1)
    if chi2.sf(float(line.redchi) * dof, dof) < 1e-3:
        click.echo(f"  warning: the log ratio is not a straight line (Eq. 6 reduced chi2 {float(line.redchi):.1f} on "
                   f"{dof} dof): the contact window bends it at low omega, so the slope is biased; "
                   "the exact R curve (Eq. 23) models it.")
    click.echo(f"  exact R fit: reduced chi2 {ex.redchi:.2f}, converged {ex.converged}")
    click.echo(f"  figure: {r.figure}")
    click.echo(f"  time: {r.seconds:.1f} s (simulation, spectra, fits, figure; JIT compile included)")


if __name__ == "__main__":  # pragma: no cover
    main()
