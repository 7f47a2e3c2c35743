"""Does the x-y chain's order bias its error bars? Each scene fitted twice (issue #3).

The chain (``FitOptions.cross_pairs``) fits the x pair as it is and the y pair
conditioned on it. Exchanging the recording's x and y channels makes the true y
pair the one fitted first. Fitting both versions of the same recording and
comparing the pulls by role (fitted first or conditioned) and by component
(major or minor) separates what the order does from what the scenes do. The
fitter without the chain mirrors exactly under the exchange (tests/test_fit.py).

Scenes are ``coverage.py``'s seeded draw. Prints the role table, writes
chain_order.json (rows: both fits' values, errors and truths) and
chain_order.png (pulls first against conditioned).

    python benchmarks/chain_order.py --scenes 500 --axis 20 --out benchmarks/out   # within 20 deg of an axis
    python benchmarks/chain_order.py --summary benchmarks/out/chain_order.json --out figs     # table and figure again
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from coverage import scenes  # noqa: E402  (benchmarks/ is the script's directory)
from tactile_jax.errors import TactileInputError  # noqa: E402
from tactile_jax.fit import FitOptions, fit_recording  # noqa: E402
from tactile_jax.scene import simulate  # noqa: E402

#: the recording's channels (x1, x2, y1, y2) with the pairs exchanged
SWAP = [2, 3, 0, 1]


def _fit(rec):
    t = time.perf_counter()
    r = fit_recording(rec, FitOptions())
    return r, time.perf_counter() - t


def run(n: int, skip: int = 0, axis_deg: float | None = None, seed: int = 2026, on_row=None):
    """Both orders of scenes ``skip``..n-1 (only those within ``axis_deg`` of an axis when given)."""
    rows = []
    for i, sc in scenes(n, seed):
        ang = float(np.degrees(np.arctan2(abs(sc.velocity[1]), abs(sc.velocity[0]))))
        if i < skip or (axis_deg is not None and axis_deg <= ang <= 90 - axis_deg):
            continue
        try:
            rec = simulate(sc)
        except TactileInputError:       # as coverage.py: a coarser grid for a large, fast scene
            sc = dataclasses.replace(sc, grid_spacing=60e-6)
            rec = simulate(sc)
        swapped = dataclasses.replace(rec, signals=np.ascontiguousarray(np.asarray(rec.signals)[SWAP]))
        (a, ta), (b, tb) = _fit(rec), _fit(swapped)
        # in the swapped fit the reported vx is the true y component, and vy the true x one
        row = {"i": i, "angle_deg": ang, "speed": float(np.hypot(*sc.velocity)), "a_true": sc.a,
               "x_true": abs(sc.velocity[0]), "y_true": abs(sc.velocity[1]),
               "status": [a.status, b.status], "fit_s": [ta, tb],
               "x_first": [a.vx, a.vx_err], "y_cond": [a.vy, a.vy_err],
               "y_first": [b.vx, b.vx_err], "x_cond": [b.vy, b.vy_err]}
        rows.append(row)
        print(f"{i:4d} {ang:5.1f} deg  {a.status}/{b.status}  {ta:.1f} + {tb:.1f} s", flush=True)
        if on_row is not None:
            on_row(rows)
    return rows


def _pull(pair, truth):
    v, e = pair
    return (v - truth) / e if (v is not None and e) else np.nan


def role_table(rows) -> list[tuple[str, int, float, float, float, float]]:
    """(group, n, mean squared pull fitted first, conditioned, 1-sigma coverage first, conditioned)."""
    ok = [r for r in rows if r["status"] == ["ok", "ok"]]
    groups = {"major, x-major scenes": [], "major, y-major scenes": [], "minor, all": []}
    for r in ok:
        x = (_pull(r["x_first"], r["x_true"]), _pull(r["x_cond"], r["x_true"]))
        y = (_pull(r["y_first"], r["y_true"]), _pull(r["y_cond"], r["y_true"]))
        major, minor = (x, y) if r["angle_deg"] < 45 else (y, x)
        groups["major, x-major scenes" if r["angle_deg"] < 45 else "major, y-major scenes"].append(major)
        groups["minor, all"].append(minor)
    out = []
    for name, pulls in groups.items():
        p = np.array(pulls, float).reshape(-1, 2)
        p = p[np.all(np.isfinite(p), axis=1)]
        out.append((name, len(p), *np.mean(p ** 2, axis=0), *(100 * np.mean(np.abs(p) < 1, axis=0))))
    return out


def figure(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tactile_jax.plotting import provenance

    ok = [r for r in rows if r["status"] == ["ok", "ok"]]
    fig, axes = plt.subplots(1, 2, figsize=(8, 4))
    for ax, c in zip(axes, ("x", "y")):
        first = np.array([_pull(r[f"{c}_first"], r[f"{c}_true"]) for r in ok])
        cond = np.array([_pull(r[f"{c}_cond"], r[f"{c}_true"]) for r in ok])
        ax.scatter(first, cond, s=8, c=[r["angle_deg"] for r in ok], cmap="coolwarm", vmin=0, vmax=90)
        ax.plot([-4, 4], [-4, 4], "k-", lw=0.5)
        ax.set(xlim=(-4, 4), ylim=(-4, 4), xlabel=f"|v{c}| pull, its pair fitted first",
               ylabel=f"|v{c}| pull, its pair conditioned", title=f"|v{c}| ({len(ok)} scenes; colour: angle)")
    fig.text(0.01, 0.01, provenance(), fontsize=6, color="0.4")
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def report(rows, out: Path | None = None):
    print("\n| group | n | mean sq pull, first | conditioned | 1-sigma, first | conditioned |")
    print("|---|---|---|---|---|---|")
    for name, n, m1, m2, c1, c2 in role_table(rows):
        print(f"| {name} | {n} | {m1:.2f} | {m2:.2f} | {c1:.0f} % | {c2:.0f} % |")
    if out is not None:
        figure(rows, out / "chain_order.png")


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenes", type=int, default=100)
    p.add_argument("--skip", type=int, default=0)
    p.add_argument("--axis", type=float, default=None, metavar="DEG",
                   help="only scenes whose slip is within DEG of the x or y axis")
    p.add_argument("--seed", type=int, default=2026)
    p.add_argument("--out", default="benchmarks/out")
    p.add_argument("--summary", type=Path, help="print the table of an earlier run's chain_order.json")
    a = p.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    if a.summary:
        report(json.loads(a.summary.read_text())["rows"], out)
        return
    head = (f"# chain order: scenes {a.skip}-{a.scenes - 1}, seed {a.seed}, axis {a.axis}; {platform.machine()}, "
            f"jax {jax.__version__}, numpy {np.__version__}")
    print(head)

    def save(rows):
        (out / "chain_order.json").write_text(json.dumps({"header": head, "rows": rows}, indent=1))

    rows = run(a.scenes, a.skip, a.axis, a.seed, on_row=save)
    report(rows, out)


if __name__ == "__main__":
    main()
