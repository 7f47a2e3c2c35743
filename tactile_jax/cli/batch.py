"""``tactile-jax batch``: fit every record of a dataset in compiled chunks, resumably (see ``batch``)."""

from __future__ import annotations

import click

from .common import parse_floats, user_errors


@click.command("batch", short_help="Fit every record of a dataset, resumably.")
@click.argument("inputs", nargs=-1, required=True, type=click.Path())
@click.option("--out", "out", required=True, type=click.Path(dir_okay=False),
              help="Results file: .json, .csv or .parquet (needs pyarrow); rerunning with it resumes.")
@click.option("--processes", type=int, default=None,
              help="Spawned processes the chunks run on (default: one per CPU core; 1: this process).")
@click.option("--workers", type=int, default=None, help="Run on a local Dask cluster of N spawned processes.")
@click.option("--scheduler", default=None, help="Address of a running Dask scheduler (tcp://host:8786).")
@click.option("--chunk-size", type=int, default=None,
              help="Records per compiled call (memory grows with it, not with the batch) [default: 32 on a CPU, "
                   "1024 on an accelerator].")
@click.option("--velocity", default=None, help="Known slip vx,vy in m/s for every record: held fixed.")
@click.option("--fit-gain", is_flag=True, help="Fit the deep/shallow gain ratios instead of holding them.")
@click.option("--nperseg", type=int, default=None, help="Welch segment length (default: largest 2^k <= N/8, longer for slow slips, per record).")
@click.option("--window", type=click.Choice(["hertz", "gaussian"]), default=None,
              help="Contact window (default: the Hertz disk against the Gaussian, chosen per record).")
@click.option("--texture", type=click.Choice(["isotropic", "directional"]), default=None,
              help="Texture model (default: chosen per record; line textures go to the line model).")
@click.option("--direction", type=click.Choice(["oblique", "along-x", "along-y"]), default=None,
              help="Slip direction (default: a minor speed the data do not need is held at 0, per record).")
@click.option("--sensor", "sensor", type=click.Path(dir_okay=False), default=None,
              help="Sensor file (TOML): probe depths, surface radius, gains and the channel map of audio files; "
                   "an HDF5/NPZ file's metadata must agree with it. Without it an audio file gets the paper's sensor.")
@click.option("--no-resume", is_flag=True, help="Start afresh instead of skipping rows already in --out.")
@click.option("--quiet", is_flag=True, help="No progress line; the summary only.")
@user_errors
def batch(inputs, out, processes, workers, scheduler, chunk_size, velocity, fit_gain, nperseg, window, texture, direction,
          no_resume, quiet, sensor=None):
    """Fit slip velocity and contact radius to every record under INPUTS (files or folders).

    Recordings are .h5/.hdf5/.npz files and 4-channel .wav/.flac audio files; --sensor gives the
    sensor (depths, radius, channel map) of every one.

    One row per record (data-contract fields, the source file and the record index).
    Bad recordings get a row with their status; the command exits 0 once the batch is done
    and says how many rows failed. Output is rewritten atomically after every chunk.
    """
    from ..batch.run import run_batch
    from ..errors import TactileInputError
    from ..inference.options import FitOptions

    if workers is not None and scheduler is not None:
        raise TactileInputError("give --workers or --scheduler, not both", code="bad_setting")
    known = None if velocity is None else tuple(abs(v) for v in parse_floats(velocity, 2, "velocity"))
    options = FitOptions(velocity=known, fit_gain=fit_gain, nperseg=nperseg, window=window, texture=texture,
                         direction=direction and direction.replace("-", " "))
    summary = run_batch(list(inputs), out, options=options, chunk_size=chunk_size, workers=workers,
                        scheduler=scheduler, progress=not quiet, resume=not no_resume, processes=processes,
                        sensor=sensor)
    t = summary.timings
    rate = summary.n_fitted / t["total"] if t["total"] > 0 else 0.0
    click.echo(f"wrote {summary.out}: {summary.n_rows} rows ({summary.n_fitted} fitted now, {summary.n_skipped} "
               f"already done), {summary.n_failed} failed; model {summary.model}; {t['total']:.1f} s "
               f"({rate:.1f} recordings/s; spectra {t['spectra']:.1f} s, fit {t['fit']:.1f} s)", err=True)
