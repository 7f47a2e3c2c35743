"""The ``tactile-jax`` command line: ``simulate`` and ``demo``.

Flags take SI units (m, m/s, Hz); output for people is in mm and cm/s, labelled.
Bad input ends with one line ``error: <file>: <problem>`` and exit status 2.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import sys

import click
import jax

from ._optional import MissingExtra
from .errors import TactileInputError

# float64 is chosen here, at the entry point (the library never switches it on itself)
jax.config.update("jax_enable_x64", True)
# compiled programs persist across runs (set TACTILE_JAX_CACHE="" to disable)
_CACHE = os.environ.get("TACTILE_JAX_CACHE", os.path.join(os.path.expanduser("~"), ".cache", "tactile_jax", "jax"))
if _CACHE:
    jax.config.update("jax_compilation_cache_dir", _CACHE)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)


def _user_errors(fn):
    """Turn input errors into one line on stderr and exit status 2, never a traceback."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except (TactileInputError, MissingExtra) as err:
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


@main.command(short_help="Simulate a scene into a recording file.")
@click.option("--out", "out", required=True, type=click.Path(dir_okay=False), help="Recording file to write (.h5, .hdf5 or .npz).")
@click.option("--texture", type=click.Choice(["random", "grating", "net", "directional", "modes"]), default="random",
              show_default=True, help="random (foamed polystyrene), grating (1-D, like the paper's pipes), net (wire net),"
              " directional (anisotropic random, 3:1 along x) or modes (300 plane waves, seeded by --seed).")
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
    import math

    import numpy as np

    from .io import write_recording
    from .scene import Scene, simulate as run
    from .texture import DirectionalTexture, Grating, ModeTexture, RandomTexture, WireNet

    if texture == "random":
        tex = RandomTexture()
    elif texture == "grating":
        tex = Grating(pitch=pitch or 1.5e-3, angle=math.radians(angle))
    elif texture == "directional":
        tex = DirectionalTexture()
    elif texture == "modes":
        tex = ModeTexture(seed=seed)
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


@main.command(short_help="Estimate a recording's spectra into a spectra file.")
@click.argument("recording", type=click.Path(dir_okay=False))
@click.option("--out", "out", required=True, type=click.Path(dir_okay=False), help="Spectra file to write (.h5 or .npz).")
@click.option("--method", type=click.Choice(["welch", "multitaper"]), default="welch", show_default=True)
@click.option("--nperseg", type=int, default=None,
              help="Welch segment length, samples (default: as `fit` chooses it, N/8 rounded down to a power of two, "
                   "longer for slow slips).")
@click.option("--prewhiten", type=int, default=8, show_default=True, help="AR order of the prewhitening filter (0: off).")
@click.option("--record", type=int, default=0, show_default=True, help="Record index in a multi-record file.")
@_user_errors
def spectra(recording, out, method, nperseg, prewhiten, record):
    """Estimate a recording's spectra as `fit` does; write a spectra file that fits like the recording.

    The file holds the 4 x 4 spectral matrix (psd, csd, xy), each group of segments' spectra (the
    jackknife's), the estimator (kernel, bin factor, prewhitening filters) and the amplitude ratios.
    """
    import numpy as np

    from .fit import FitOptions, _options_from_file, record_of
    from .io import SpectraData, read_recording, write_spectra
    from .joint.segments import to_spectra

    rec = read_recording(recording)
    if not 0 <= record < rec.n_records:
        raise TactileInputError(f"--record {record} out of range: the file holds {rec.n_records} record(s)",
                                source=recording, code="bad_setting")
    one = rec.record(record)
    options = _options_from_file(FitOptions(method=method, nperseg=nperseg, prewhiten=prewhiten), one)
    try:
        seg = record_of(one.signals, one.fs, one.depths, options, source=recording).seg
    except TactileInputError as err:
        raise err.with_source(recording) from None
    data = SpectraData(**to_spectra(seg), depths=one.depths, curvature_radius=one.curvature_radius,
                       velocity=one.velocity, gain_ratio=one.gain_ratio)
    path = write_spectra(out, data)
    segs = f"nperseg {int(seg.nperseg)}, " if method == "welch" else ""
    click.echo(f"wrote {path}: {data.omega.size} bins up to {data.omega[-1] / (2 * np.pi):g} Hz "
               f"({method}, {segs}K_eff = {float(seg.dof):.1f}, {data.group_count.size} groups, "
               f"prewhiten AR({prewhiten}))")


@main.command(short_help="Simulate the paper's Fig. 5 scene and fit it.")
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
    line, ex = r.slope, r.fit
    click.echo(f"  usable band: {int(line.n_bins)} bins, {r.band_hz[0]:.1f}-{r.band_hz[1]:.1f} Hz of the x pair")
    click.echo("")
    click.echo(f"  {'quantity':<26}{'truth':>10}{'estimate':>22}{'deviation':>18}")

    def row(name, truth, est, err, scale, unit):
        if est is None or err is None:
            click.echo(f"  {name:<26}{scale * truth:>10.4f}{'not determined':>22}")
            return
        dev = est - truth
        rel = f"{100 * dev / truth:>+8.2f} %" if truth else " " * 10
        click.echo(f"  {name:<26}{scale * truth:>10.4f}{scale * est:>12.4f} +/- {scale * err:<6.4f}"
                   f"{rel} {dev / err:>+6.1f} sig  {unit}")

    row("|vx|, Eq. 6 slope", v, float(line.speed), float(line.speed_err), 100, "cm/s")
    row("|vx|, joint fit", v, ex.vx, ex.vx_err, 100, "cm/s")
    row("|vy|, joint fit", abs(r.scene.velocity[1]), ex.vy, ex.vy_err, 100, "cm/s")
    row("a, joint fit", r.scene.contact_radius, ex.a, ex.a_err, 1e3, "mm")
    dof = max(int(line.n_bins) - 2, 1)
    if chi2.sf(float(line.redchi) * dof, dof) < 1e-3:
        click.echo(f"  warning: the log ratio is not a straight line (Eq. 6 reduced chi2 {float(line.redchi):.1f} on "
                   f"{dof} dof): the contact window bends it at low omega, so the slope is biased; "
                   "the joint fit's exact window model (Eq. 23) models it.")
    click.echo(f"  joint fit: status {ex.status}, reduced chi2 {ex.redchi:.2f}; {ex.message or 'no notes'}")
    click.echo(f"  figure: {r.figure}" if r.figure else f"  note: {r.note}")
    click.echo(f"  time: {r.seconds:.1f} s (simulation, spectra, fits, figure; JIT compile included)")


_FIT_RAN = ("ok", "not_converged", "poor_fit")     # statuses of a fit that ran and produced values
_POSTERIOR_FILES: set = set()           # posterior files written by this ``fit`` run


@main.command(short_help="Fit recordings or spectra files, with error bars.")
@click.argument("files", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--out", "out", default=None, type=click.Path(dir_okay=False),
              help="Results file: .json (list of objects), .csv or .parquet (needs pyarrow); one row per record. "
                   "Without it the reports are printed and nothing is written.")
@click.option("--mcmc", is_flag=True, help="Sample the posterior with emcee around each fit (errors beyond Laplace).")
@click.option("--walkers", type=int, default=32, show_default=True, help="emcee walkers (at least 2 x free parameters).")
@click.option("--steps", type=int, default=500, show_default=True, help="emcee steps per walker, burn-in (1/4) included.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the MCMC.")
@click.option("--plot", "plot_dir", type=click.Path(file_okay=False), default=None,
              help="Folder for Fig. 7-style fit figures (and corner plots with --mcmc).")
@click.option("--record", type=int, default=None, help="Fit only this record of a multi-record file (default: all).")
@click.option("--fit-gain", is_flag=True, help="Fit the deep/shallow gain ratios instead of holding them (file or 1).")
@click.option("--velocity", default=None, help="Known slip vx,vy in m/s (e.g. the arm's command): held fixed.")
@click.option("--noise-floor", is_flag=True, help="Fit a white noise floor on the shallow probes.")
@click.option("--method", type=click.Choice(["welch", "multitaper"]), default="welch", show_default=True,
              help="Spectral estimator for recordings.")
@click.option("--solver", type=click.Choice(["optimistix", "jaxopt"]), default="optimistix", show_default=True)
@click.option("--quiet", is_flag=True, help="No fit reports or progress; errors and the summary only.")
@click.option("--scene", "scene", type=click.Path(dir_okay=False), default=None,
              help="Scene recipe (fits/NAME.toml): fit options first from it, explicit flags override.")
@click.option("--model", "model", default=None,
              help="Scene model: auto (chosen by BIC), slip, window (default), window+gain, window+noise, "
                   "window+gain+noise, hertz.")
@click.option("--ratio-only", is_flag=True,
              help="Leave out the deep probe's conditioned PSD S22.1 (fit the ratio and shallow PSD alone).")
@click.option("--cross-pairs", "cross_pairs", type=click.IntRange(0, 2), default=None,
              help="Fit the y pair conditioned on the x pair, with the x-y cross-spectra: "
                   "0 off, 1 y1 only, 2 both y probes. Default: 2 where the spectra have x-y cross-spectra "
                   "(recordings, and files from 'tactile-jax spectra'), else 0.")
@_user_errors
def fit(files, out, mcmc, walkers, steps, seed, plot_dir, record, fit_gain, velocity, noise_floor, method, solver,
        quiet, scene=None, model=None, ratio_only=False, cross_pairs=None):
    """Fit slip velocity, contact radius and gains to recordings or spectra files; write one row per record.

    FILE is a recording (.h5/.hdf5/.npz with 'signals') or a spectra file (with 'omega').
    Speeds are printed in cm/s and lengths in mm; the results file is in SI units.
    One bad input alone ends with 'error: <file>: <problem>' and exit status 2 (its row is
    still written); among several, its row carries the status and the others go on.
    """
    from pathlib import Path

    from .fit import FitOptions
    from .results import RESULT_SUFFIXES

    out_path = None if out is None else Path(out)
    if out_path is not None and out_path.suffix.lower() not in RESULT_SUFFIXES:
        raise TactileInputError(f"--out must end in {', '.join(RESULT_SUFFIXES)}, got {out!r}", code="bad_setting")
    if out_path is not None and out_path.suffix.lower() == ".parquet":
        try:
            import pyarrow  # noqa: F401
        except ImportError:
            raise TactileInputError("--out .parquet needs pyarrow: pip install pyarrow (or use .json / .csv)",
                                    code="bad_setting") from None
    if record is not None and record < 0:
        raise TactileInputError(f"--record must be >= 0, got {record}", code="bad_setting")
    if mcmc and (walkers < 2 or steps < 2):
        raise TactileInputError("--walkers and --steps must be at least 2", code="bad_setting")
    if mcmc or plot_dir is not None:                      # optional extras, checked before any fit runs
        from ._optional import need

        if mcmc:
            need("arviz", "mcmc", "--mcmc")
        if plot_dir is not None:
            need("matplotlib", "plot", "--plot")
    known = None if velocity is None else tuple(abs(v) for v in _floats(velocity, 2, "velocity"))
    options = FitOptions(method=method, velocity=known, fit_gain=fit_gain, noise_floor=noise_floor, solver=solver)
    options = _scene_options(options, scene, model)
    if ratio_only:
        options = dataclasses.replace(options, conditioned=False)
    if cross_pairs is not None:
        options = dataclasses.replace(options, cross_pairs=cross_pairs)
    mcmc_settings = dict(n_walkers=walkers, n_steps=steps, seed=seed, progress=not quiet) if mcmc else None

    rows, failures = [], []
    _POSTERIOR_FILES.clear()
    many = len(files) > 1
    for n, path in enumerate(files, 1):
        if many and not quiet:
            click.echo(f"[{n}/{len(files)}] {path}", err=True)
        for row, problem, result in _fit_file(path, options, record):
            if result is not None:
                if mcmc_settings is not None:
                    _attach_mcmc(result, row, out_path, mcmc_settings)
                if not quiet:
                    from .report import fit_report

                    click.echo(fit_report(result, truth=result.truth or None))
                    click.echo("")
                if plot_dir is not None:
                    _fit_figures(result, plot_dir, quiet)
            rows.append(row)
            if problem is not None:
                failures.append(problem)
                if many:
                    click.echo(f"  failed ({row['status']}): {problem}", err=True)

    if out_path is not None:
        from .results import write_results

        written = write_results(out_path, rows)
        if not quiet and (many or not failures):
            click.echo(f"wrote {written}: {len(rows)} row{'s' if len(rows) != 1 else ''}", err=True)
    if not many and failures:
        for problem in failures:
            click.echo(f"error: {problem}", err=True)
        sys.exit(2)
    if many:
        click.echo(f"{len(rows) - len(failures)} fitted, {len(failures)} failed", err=True)
        if len(failures) == len(rows):
            click.echo(f"error: none of the {len(rows)} records was fitted", err=True)
            sys.exit(2)


def _scene_options(options, scene, model):
    """Recipe (--scene) first, then the flags given on the command line, then --model."""
    from click.core import ParameterSource

    from .model_select import check_model

    if scene is not None:
        from .recipes import load_recipe

        ctx = click.get_current_context()
        explicit = {name for name in ("method", "velocity", "fit_gain", "noise_floor", "solver")
                    if ctx.get_parameter_source(name) == ParameterSource.COMMANDLINE}
        recipe = load_recipe(scene).options
        options = dataclasses.replace(recipe, **{name: getattr(options, name) for name in explicit})
    if model is not None:
        options = dataclasses.replace(options, model=check_model(model))
    return options


def _fit_file(path, options, record):
    """Yield (row, problem or None, FitResult or None) for each record of ``path``; never raises for bad input."""
    from .fit import fit_recording, fit_spectra
    from .io import is_recording_file, read_recording, read_spectra

    src = str(path)
    try:
        if is_recording_file(path):
            rec = read_recording(path)
            if record is not None and record >= rec.n_records:
                raise TactileInputError(f"--record {record} out of range: the file holds {rec.n_records} record(s)",
                                        source=src, code="bad_setting")
            indices = [record] if record is not None else list(range(rec.n_records))
            label = (lambda i: f"{src} [record {i}]") if rec.n_records > 1 else (lambda i: src)
            fits = ((i, lambda i=i: fit_recording(rec, options, record=i)) for i in indices)
        else:
            data = read_spectra(path)
            if record not in (None, 0):
                raise TactileInputError(f"--record {record} out of range: a spectra file holds one record",
                                        source=src, code="bad_setting")
            fits = iter([(0, lambda: fit_spectra(data, options))])
            label = lambda i: src  # noqa: E731
    except TactileInputError as err:
        err = err.with_source(src)
        yield _error_row(src, record or 0, err.code, str(err)), str(err), None
        return
    for i, run in fits:
        try:
            result = run()
        except TactileInputError as err:
            err = err.with_source(src)
            yield _error_row(src, i, err.code, str(err)), str(err), None
            continue
        except Exception as err:  # noqa: BLE001 - one record's failure must not end a batch
            text = " ".join(f"{type(err).__name__}: {err}".split())
            yield _error_row(src, i, "fit_error", f"{src}: {text}"), f"{src}: {text}", None
            continue
        result.file, result.index = src, i
        problem = None if result.status in _FIT_RAN else f"{label(i)}: {result.message or result.status}"
        yield result.to_record(), problem, result


def _error_row(src, index, code, message) -> dict:
    from .fit import RESULT_FIELDS

    row = dict.fromkeys(RESULT_FIELDS)
    row.update(file=src, index=int(index), converged=False, status=code, message=message)
    return row


def _attach_mcmc(result, row, out_path, settings):
    """Sample the posterior of an ok fit, attach it to ``result``, update ``row`` and save the draws.

    settings: ``run_emcee`` keywords; with ``progress`` true, emcee's progress bar and a line naming
    the posterior file (with ESS and the largest tau, steps) go to stderr.
    """
    from pathlib import Path

    from .posterior import run_emcee, save_posterior

    if result.problem is None or result.status != "ok":
        why = "the fit has no joint-model problem" if result.problem is None else f"fit status {result.status}"
        row["mcmc_warnings"] = f"not run: {why}"
        return
    try:
        post = run_emcee(result.problem, **settings)
    except ValueError as err:
        row["mcmc_warnings"] = f"not run: {err}"
        click.echo(f"warning: {result.file} [{result.index}]: MCMC not run: {err}", err=True)
        return
    result.posterior = post
    row.update(result.to_record())
    stem = Path(str(result.file)).stem
    path = out_path.parent / f"{out_path.stem}_{stem}_{result.index}_posterior.h5"
    n = 2
    while str(path) in _POSTERIOR_FILES:                  # two inputs with one stem: keep both
        path = out_path.parent / f"{out_path.stem}_{stem}_{result.index}_posterior_{n}.h5"
        n += 1
    _POSTERIOR_FILES.add(str(path))
    attrs = {"source_file": str(result.file), "index": int(result.index),
             "fit": {k: row.get(k) for k in ("vx", "vx_err", "vy", "vy_err", "a", "a_err")}}
    if result.truth:
        attrs["truth"] = result.truth
    row["posterior_file"] = str(save_posterior(path, post, attrs=attrs))
    if settings.get("progress"):
        import math

        known = math.isfinite(post.ess) and math.isfinite(post.max_tau)
        diag = f"ESS {post.ess:.0f}, tau {post.max_tau:.1f} steps" if known else "tau not estimable: run a longer chain"
        click.echo(f"posterior: {path} ({diag})", err=True)


def _fit_figures(result, plot_dir, quiet):
    from .plotting import plot_fit, plot_posterior_corner

    try:
        paths = plot_fit(result, plot_dir)
        if result.posterior is not None:
            paths += plot_posterior_corner(result, plot_dir, truth=result.truth or None)
    except Exception as err:  # noqa: BLE001 - a figure never ends a batch
        click.echo(f"warning: {result.file} [{result.index}]: figure not written: {err}", err=True)
        return
    if not quiet:
        for p in paths:
            click.echo(f"figure: {p}", err=True)


from .batch_cli import batch as _batch  # noqa: E402
main.add_command(_batch)


@main.command("compare-r", short_help="Rough Eq. 26 against the exact R curve.")
@click.option("--out", "out_dir", default="compare_r", show_default=True, type=click.Path(file_okay=False),
              help="Folder for the PNG figures and the bias table (CSV).")
@click.option("--tol", type=float, default=0.05, show_default=True, help="Tolerance on |log R_rough - log R_exact|.")
@click.option("--seeds", type=int, default=3, show_default=True, help="Seeds per cell of the fit-bias table.")
@click.option("--simulate/--no-simulate", default=True, show_default=True,
              help="Also fit simulated recordings (space-domain simulator) at a = 0.85, 2.2 mm, 4.7 cm/s.")
@click.option("--hertz/--no-hertz", default=True, show_default=True,
              help="Also compare the Gaussian window with the Hertz window (slower: the Hertz curve is a quadrature).")
@_user_errors
def compare_r(out_dir, tol, seeds, simulate, hertz):
    """Rough (Eq. 26) vs exact (Eq. 23) R curve, and Gaussian vs Hertz window: maps, fit bias, time per fit."""
    import csv
    import time
    from pathlib import Path

    import numpy as np

    from . import compare_r as cr

    if not tol > 0 or seeds < 1:
        raise TactileInputError("--tol must be positive and --seeds at least 1", code="bad_setting")
    t0 = time.perf_counter()
    out = Path(out_dir)
    paths = cr.write_figures(out, tol=tol)
    d1, d2 = cr._D1, cr._D2
    click.echo(f"rough curve within {tol:g} of the exact one (paper sensor, d1 = {1e3 * d1:g} mm, d2 = {1e3 * d2:g} mm):")
    click.echo(f"  {'a mm':>6}  {'alpha >= rad/m':>15}  {'f >= Hz at 2.3 cm/s':>20}  {'at 4.7 cm/s':>12}")
    for a in (0.5e-3, 0.85e-3, 1.5e-3, 2.2e-3, 3e-3, 5e-3, 10e-3):
        x = float(cr.rough_valid_alpha([d2 / a], tol)[0]) / a
        click.echo(f"  {1e3 * a:>6.2f}  {x:>15.4g}  {x * 0.023 / (2 * np.pi):>20.1f}  {x * 0.047 / (2 * np.pi):>12.1f}")
    s = tuple(range(seeds))
    click.echo("")
    click.echo("rough-valid: Eq. 26 fitted only where it is within 0.05 of Eq. 23 at the true a and speed "
               "(an oracle band: its best case); a fit > 50 mm: the fitted offset wants no window")
    click.echo("fit bias, synthetic exact-curve ratios (50 dB per bin, K = 28, 1 kHz, 512-sample segments), "
               f"medians over {seeds} seeds:")
    rows = cr.fit_bias([0.85e-3, 1.5e-3, 2.2e-3, 3e-3, 5e-3], [0.023, 0.047, 0.094], seeds=s,
                       curves=("exact", "rough", "rough-valid"))
    click.echo(cr.format_bias_table(rows))
    all_rows = [("synthetic", r) for r in rows]
    if simulate:
        click.echo("")
        click.echo(f"fit bias, simulated recordings (Gaussian window, slip along x, 8 s at 1 kHz, 50 dB), {seeds} seeds:")
        rows = cr.fit_bias([0.85e-3, 2.2e-3], [0.047], seeds=s, source="simulator", truth="gaussian",
                           curves=("exact", "rough", "rough-valid"))
        click.echo(cr.format_bias_table(rows))
        all_rows += [("simulator", r) for r in rows]
    if hertz:
        click.echo("")
        click.echo("Gaussian vs Hertz window: synthetic Hertz-curve ratios (1-D texture) fitted with each curve:")
        rows = cr.fit_bias([0.85e-3, 2.2e-3], [0.047], seeds=s, truth="hertz", curves=("exact", "hertz"))
        click.echo(cr.format_bias_table(rows))
        all_rows += [("synthetic", r) for r in rows]
        if simulate:
            click.echo("simulated recordings with the Hertz window (random 2-D texture):")
            rows = cr.fit_bias([0.85e-3, 2.2e-3], [0.047], seeds=s, source="simulator", truth="hertz",
                               curves=("exact", "hertz"))
            click.echo(cr.format_bias_table(rows))
            all_rows += [("simulator", r) for r in rows]
    table = out / "fit_bias.csv"
    with open(table, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(("source",) + cr.BiasRow._fields)
        for src, r in all_rows:
            w.writerow((src,) + tuple(r))
    for p in paths + [table]:
        click.echo(f"wrote {p}")
    click.echo(f"time: {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":  # pragma: no cover
    main()
