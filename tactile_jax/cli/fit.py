"""``tactile-jax fit``: fit recordings or spectra files, print the report, write one row per record."""

from __future__ import annotations

import dataclasses
import sys

import click

from ..errors import TactileInputError
from ..status import FIT_RAN
from .common import optimise_later, parse_floats, quick_first, user_errors


_POSTERIOR_FILES: set = set()           # posterior files written by this ``fit`` run


@click.command(short_help="Fit recordings or spectra files, with error bars.")
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
@click.option("--sensor", "sensor", type=click.Path(dir_okay=False), default=None,
              help="Sensor file (TOML): probe depths, surface radius, gains and the channel map of audio files; "
                   "an HDF5/NPZ file's metadata must agree with it. Without it an audio file gets the paper's sensor.")
@click.option("--model", "model", default=None,
              help="Scene model: auto (chosen by BIC), slip, window (default), window+gain, window+noise, "
                   "window+gain+noise.")
@click.option("--window", type=click.Choice(["hertz", "gaussian"]), default=None,
              help="Contact window (default: the Hertz disk against the Gaussian, chosen per record).")
@click.option("--texture", type=click.Choice(["isotropic", "directional"]), default=None,
              help="Texture model (default: chosen per record; line textures go to the line model).")
@click.option("--direction", type=click.Choice(["oblique", "along-x", "along-y"]), default=None,
              help="Slip direction (default: a minor speed the data do not need is held at 0, per record).")
@click.option("--ratio-only", is_flag=True,
              help="Leave out the deep probe's conditioned PSD S22.1 (fit the ratio and shallow PSD alone).")
@click.option("--cross-pairs", "cross_pairs", type=click.IntRange(0, 2), default=None,
              help="Fit the y pair conditioned on the x pair, with the x-y cross-spectra: "
                   "0 off, 1 y1 only, 2 both y probes. Default: 2 where the spectra have x-y cross-spectra "
                   "(recordings, and files from 'tactile-jax spectra'), else 0.")
@user_errors
def fit(files, out, mcmc, walkers, steps, seed, plot_dir, record, fit_gain, velocity, noise_floor, method, solver,
        quiet, scene=None, model=None, window=None, texture=None, direction=None, ratio_only=False,
        cross_pairs=None, sensor=None):
    """Fit slip velocity, contact radius and gains to recordings or spectra files; write one row per record.

    FILE is a recording (.h5/.hdf5/.npz with 'signals', or a 4-channel .wav/.flac audio file) or a
    spectra file (with 'omega'). --sensor gives the sensor (depths, radius, channel map).
    Speeds are printed in cm/s and lengths in mm; the results file is in SI units.
    One bad input alone ends with 'error: <file>: <problem>' and exit status 2 (its row is
    still written); among several, its row carries the status and the others go on.
    """
    from pathlib import Path

    from ..inference.options import FitOptions
    from ..io.results import RESULT_SUFFIXES
    from ..io.sensor_file import read_sensor

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
        from .._optional import need

        if mcmc:
            need("arviz", "mcmc", "--mcmc")
        if plot_dir is not None:
            need("matplotlib", "plot", "--plot")
    known = None if velocity is None else tuple(abs(v) for v in parse_floats(velocity, 2, "velocity"))
    options = FitOptions(method=method, velocity=known, fit_gain=fit_gain, noise_floor=noise_floor, solver=solver,
                         window=window, texture=texture, direction=direction and direction.replace("-", " "))
    options = _scene_options(options, scene, model)
    if ratio_only:
        options = dataclasses.replace(options, conditioned=False)
    if cross_pairs is not None:
        options = dataclasses.replace(options, cross_pairs=cross_pairs)
    mcmc_settings = dict(n_walkers=walkers, n_steps=steps, seed=seed, progress=not quiet) if mcmc else None
    spec = None if sensor is None else read_sensor(sensor)             # a bad sensor file ends the run here
    with_sensor = {} if spec is None else {"spec": spec}

    quick_first()
    try:
        _fit_files(files, options, record, with_sensor, out_path, mcmc_settings, plot_dir, quiet)
    finally:
        optimise_later(options.window)


def _fit_files(files, options, record, with_sensor, out_path, mcmc_settings, plot_dir, quiet):
    rows, failures = [], []
    _POSTERIOR_FILES.clear()
    many = len(files) > 1
    for n, path in enumerate(files, 1):
        if many and not quiet:
            click.echo(f"[{n}/{len(files)}] {path}", err=True)
        for row, problem, result in _fit_file(path, options, record, **with_sensor):
            if result is not None:
                if mcmc_settings is not None:
                    _attach_mcmc(result, row, out_path, mcmc_settings)
                if not quiet:
                    from ..viz.report import fit_report

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
        from ..io.results import write_results

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

    from ..inference.select import check_model

    if scene is not None:
        from ..inference.options import recipe_options
        from ..io.recipes import load_recipe

        ctx = click.get_current_context()
        explicit = {name for name in ("method", "velocity", "fit_gain", "noise_floor", "solver", "window", "texture",
                                     "direction") if ctx.get_parameter_source(name) == ParameterSource.COMMANDLINE}
        loaded = load_recipe(scene)
        recipe = recipe_options(loaded.fit, loaded.path)
        options = dataclasses.replace(recipe, **{name: getattr(options, name) for name in explicit})
    if model is not None:
        options = dataclasses.replace(options, model=check_model(model))
    return options


def _fit_file(path, options, record, spec=None):
    """Yield (row, problem or None, FitResult or None) for each record of ``path``; never raises for bad input.

    spec: the ``SensorSpec`` of --sensor, or None."""
    from pathlib import Path

    from .._optional import MissingExtra
    from ..inference.fit import fit_recording, fit_spectra
    from ..io.files import AUDIO_SUFFIXES, is_recording_file, read_recording, read_spectra
    from ..io.recording import SENSOR_FROM_FILE

    src = str(path)
    sensor = None                                   # a spectra file's sensor: the file's metadata or --sensor
    try:
        if Path(src).suffix.lower() in AUDIO_SUFFIXES or is_recording_file(path):
            rec = read_recording(path, sensor=spec)
            if record is not None and record >= rec.n_records:
                raise TactileInputError(f"--record {record} out of range: the file holds {rec.n_records} record(s)",
                                        source=src, code="bad_setting")
            indices = [record] if record is not None else list(range(rec.n_records))
            label = (lambda i: f"{src} [record {i}]") if rec.n_records > 1 else (lambda i: src)
            fits = ((i, lambda i=i: fit_recording(rec, options, record=i)) for i in indices)
        else:
            data = read_spectra(path, sensor=spec)
            sensor = SENSOR_FROM_FILE if spec is None else spec.label
            if record not in (None, 0):
                raise TactileInputError(f"--record {record} out of range: a spectra file holds one record",
                                        source=src, code="bad_setting")
            fits = iter([(0, lambda: fit_spectra(data, options))])
            label = lambda i: src  # noqa: E731
    except TactileInputError as err:
        err = err.with_source(src)
        yield _error_row(src, record or 0, err.code, str(err)), str(err), None
        return
    except MissingExtra as err:                     # a FLAC file without soundfile: the message names both
        yield _error_row(src, record or 0, "unreadable", str(err)), str(err), None
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
        if result.sensor is None:
            result.sensor = sensor
        problem = None if result.status in FIT_RAN else f"{label(i)}: {result.message or result.status}"
        yield result.to_record(), problem, result


def _error_row(src, index, code, message) -> dict:
    from ..inference.result import RESULT_FIELDS

    row = dict.fromkeys(RESULT_FIELDS)
    row.update(file=src, index=int(index), converged=False, status=code, message=message)
    return row


def _attach_mcmc(result, row, out_path, settings):
    """Sample the posterior of an ok fit, attach it to ``result``, update ``row`` and save the draws.

    settings: ``run_emcee`` keywords; with ``progress`` true, emcee's progress bar and a line naming
    the posterior file (with ESS and the largest tau, steps) go to stderr.
    """
    from pathlib import Path

    from ..uncertainty.posterior import run_emcee, save_posterior

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
        if post.precision == "float32":
            diag += f"; float32 log-probability, sd {post.lp_error:.3f} from float64"
        click.echo(f"posterior: {path} ({diag})", err=True)


def _fit_figures(result, plot_dir, quiet):
    from ..viz.figures import plot_fit, plot_posterior_corner

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
