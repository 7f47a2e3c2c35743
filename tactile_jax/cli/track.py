"""``tactile-jax track``: slip velocity and contact radius over a sliding window of a long recording."""

from __future__ import annotations

import click

from .common import parse_floats, user_errors


@click.command("track", short_help="Follow a slip over time: estimates over a sliding window.")
@click.argument("path", type=click.Path())
@click.option("--out", "out", default=None, type=click.Path(dir_okay=False),
              help="Rows file, one row per update: .csv, .json or .parquet (needs pyarrow).")
@click.option("--window", "window", type=float, default=2.0, show_default=True, help="Window length, s.")
@click.option("--hop", type=float, default=0.1, show_default=True, help="Time between updates, s.")
@click.option("--record", type=int, default=0, show_default=True, help="Record of a file holding several.")
@click.option("--sensor", "sensor", type=click.Path(dir_okay=False), default=None,
              help="Sensor file (TOML): probe depths, surface radius, gains and the channel map of audio files.")
@click.option("--velocity", default=None, help="Known slip vx,vy in m/s: held fixed.")
@click.option("--contact-window", "contact_window", type=click.Choice(["hertz", "gaussian"]), default=None,
              help="Contact window (default: chosen by the data at each full analysis).")
@click.option("--nperseg", type=int, default=None,
              help="Welch segment, samples (default: the longest power of two leaving 6 segments per window).")
@click.option("--plot", "plot", default=None, type=click.Path(dir_okay=False),
              help="Draw vx, vy and a against time with their error bands and the status (.png, .pdf, .svg).")
@click.option("--quiet", is_flag=True, help="No progress line; the summary only.")
@user_errors
def track(path, out, window, hop, record, sensor, velocity, contact_window, nperseg, plot, quiet):
    """Estimate vx, vy and a every HOP seconds over the last WINDOW seconds of the recording at PATH.

    The first window in which the probes hear a moving texture gets the full analysis of ``fit``;
    later windows go on from the last estimate. A still contact is reported as ``no_slip`` (no
    speed), a window in which a slip starts as ``slip_start``, one across a change of the slip as
    ``slip_change``.
    """
    import numpy as np

    from ..inference.options import FitOptions
    from ..io.files import read_recording
    from ..io.results import write_results
    from ..status import Status
    from ..track.tracker import track_recording

    rec = read_recording(path, sensor=sensor)
    known = None if velocity is None else tuple(abs(v) for v in parse_floats(velocity, 2, "velocity"))
    options = FitOptions(velocity=known, window=contact_window)
    bars = []

    def progress(done, total):          # opened once the settings have passed their checks
        if not bars:
            from tqdm import tqdm

            bars.append(tqdm(total=total, unit="sample", unit_scale=True, desc="track", leave=False))
        bars[0].update(done - bars[0].n)

    try:
        rows = track_recording(rec, window=window, hop=hop, options=options, nperseg=nperseg, record=record,
                               progress=None if quiet else progress)
    finally:
        for bar in bars:
            bar.close()
    if out:
        write_results(out, rows)
    counts = {}
    for row in rows:
        counts[row["status"]] = counts.get(row["status"], 0) + 1
    ok = [r for r in rows if r["status"] == Status.OK.value]
    compute = np.array([r["compute_s"] for r in rows if r["update"] == "step"])
    lines = [f"{path}: {len(rows)} updates over {rec.n_samples / rec.fs:.1f} s (window {window:g} s, hop {hop:g} s); "
             + ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))]
    if ok:
        for name, scale, unit in (("vx", 100.0, "cm/s"), ("vy", 100.0, "cm/s"), ("a", 1e3, "mm")):
            values = np.array([r[name] for r in ok if r[name] is not None], float) * scale
            if values.size:
                lines.append(f"  {name}: {np.min(values):.3f} to {np.max(values):.3f} {unit} over the ok updates "
                             f"(median {np.median(values):.3f})")
    if compute.size:
        lines.append(f"  compute per update: median {1e3 * np.median(compute):.1f} ms, 95th percentile "
                     f"{1e3 * np.percentile(compute, 95):.1f} ms ({compute.size} updates from the last estimate)")
    if rows and rows[0].get("sensor") == "paper (default)":
        lines.append("  the paper's sensor assumed (no sensor file)")
    if out:
        lines.append(f"wrote {out}")
    if plot:
        from ..viz.track import track_figure

        track_figure(rows, path=plot, title=str(path))
        lines.append(f"wrote {plot}")
    click.echo("\n".join(lines))
