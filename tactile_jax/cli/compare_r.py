"""``tactile-jax compare-r``: the rough Eq. 26 against the exact R curve, and the Gaussian against the Hertz window."""

from __future__ import annotations

import click

from ..errors import TactileInputError
from .common import user_errors


@click.command("compare-r", short_help="Rough Eq. 26 against the exact R curve.")
@click.option("--out", "out_dir", default="compare_r", show_default=True, type=click.Path(file_okay=False),
              help="Folder for the PNG figures and the bias table (CSV).")
@click.option("--tol", type=float, default=0.05, show_default=True, help="Tolerance on |log R_rough - log R_exact|.")
@click.option("--seeds", type=int, default=3, show_default=True, help="Seeds per cell of the fit-bias table.")
@click.option("--simulate/--no-simulate", default=True, show_default=True,
              help="Also fit simulated recordings (space-domain simulator) at a = 0.85, 2.2 mm, 4.7 cm/s.")
@click.option("--hertz/--no-hertz", default=True, show_default=True,
              help="Also compare the Gaussian window with the Hertz window (slower: the Hertz curve is a quadrature).")
@user_errors
def compare_r(out_dir, tol, seeds, simulate, hertz):
    """Rough (Eq. 26) vs exact (Eq. 23) R curve, and Gaussian vs Hertz window: maps, fit bias, time per fit."""
    import csv
    import time
    from pathlib import Path

    import numpy as np

    from ..studies import compare_r as cr
    from ..model.sensor import PAPER_SENSOR

    if not tol > 0 or seeds < 1:
        raise TactileInputError("--tol must be positive and --seeds at least 1", code="bad_setting")
    t0 = time.perf_counter()
    out = Path(out_dir)
    paths = cr.write_figures(out, tol=tol)
    d1, d2 = float(PAPER_SENSOR.d1), float(PAPER_SENSOR.d2)
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
