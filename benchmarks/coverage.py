"""Coverage of the joint fit's error bars on simulated scenes.

Seeded scenes across speeds (1-8 cm/s), slip directions (0-90 deg), contact
radii (0.8-2.5 mm, and 5-8 mm large contacts) and SNR 30-60 dB, each 16 s at
1 kHz with the Gaussian window; each is fitted with the default joint model
and the 1- and 2-sigma intervals of |vx|, |vy| and a are checked against the
truth. Prints a table, writes coverage.json and coverage.png.

    python benchmarks/coverage.py --scenes 120 --out benchmarks/out
    python benchmarks/coverage.py --scenes 300 --skip 100 --out part2     # resume after scene 99
    python benchmarks/coverage.py --merge part1/coverage.json part2/coverage.json --out all
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import json
import math
import platform
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from tactile_jax.errors import TactileInputError  # noqa: E402
from tactile_jax.inference.options import FitOptions
from tactile_jax.inference.fit import fit_recording  # noqa: E402
from tactile_jax.simulation.scene import Scene, simulate  # noqa: E402
from tactile_jax.simulation.texture import RandomTexture  # noqa: E402


def scenes(n: int, seed: int = 2026, large_fraction: float = 0.15, snr_db: float | None = None):
    """Seeded scenes; ``snr_db`` fixes the SNR (the draw is still made, so the other draws do not move)."""
    rng = np.random.default_rng(seed)
    for i in range(n):
        speed = float(np.exp(rng.uniform(np.log(0.01), np.log(0.08))))
        angle = float(rng.uniform(0, np.pi / 2))
        large = rng.uniform() < large_fraction
        a = float(rng.uniform(5e-3, 8e-3)) if large else float(np.exp(rng.uniform(np.log(0.8e-3), np.log(2.5e-3))))
        snr = float(rng.uniform(30, 60))
        if snr_db is not None:
            snr = float(snr_db)        # the draw above is still made, so the other draws do not move
        yield i, Scene(texture=RandomTexture(), velocity=(speed * np.cos(angle), speed * np.sin(angle)),
                       contact_radius=a, snr_db=snr, duration=16.0, fs=1000.0, seed=int(rng.integers(1 << 30)))


def run(n: int, options: FitOptions = FitOptions(), seed: int = 2026, verbose: bool = True, skip: int = 0,
        large_fraction: float = 0.15, snr_db: float | None = None, on_row=None):
    """Fit the scenes from ``skip`` to ``n``; ``on_row(rows)`` after each (a long run's partial file)."""
    rows = []
    for i, scene in scenes(n, seed, large_fraction, snr_db):
        if i < skip:
            continue
        t0 = time.perf_counter()
        try:
            rec = simulate(scene)
        except TactileInputError:
            # large contact and fast slip: the default 25 um grid would be too big; 60 um still
            # resolves the shallow probe's kernel (d1 = 265 um)
            scene = dataclasses.replace(scene, grid_spacing=60e-6)
            rec = simulate(scene)
        t1 = time.perf_counter()
        res = fit_recording(rec, options)
        t2 = time.perf_counter()
        row = {"i": i, "vx_true": abs(scene.velocity[0]), "vy_true": abs(scene.velocity[1]), "a_true": scene.a,
               "snr_db": scene.snr_db, "speed": float(np.hypot(*scene.velocity)),
               "angle_deg": float(np.degrees(np.arctan2(abs(scene.velocity[1]), abs(scene.velocity[0])))),
               "sim_s": t1 - t0, "fit_s": t2 - t1, **res.to_record(),
               "jackknife": res.error_method.startswith("laplace x jackknife")}
        rows.append(row)
        if verbose:
            print(_line(row), flush=True)
        if on_row is not None:
            on_row(rows)
    return rows


def _line(r):
    def f(v, s=1.0, p=3):
        return "  -  " if v is None else f"{v * s:.{p}f}"
    return (f"{r['i']:4d} |v|={100 * r['speed']:.2f} ang={r['angle_deg']:5.1f} a={1e3 * r['a_true']:.2f} "
            f"snr={r['snr_db']:.0f} | vx {f(r['vx'], 100)}+/-{f(r['vx_err'], 100)} ({100 * r['vx_true']:.3f}) "
            f"vy {f(r['vy'], 100)}+/-{f(r['vy_err'], 100)} ({100 * r['vy_true']:.3f}) "
            f"a {f(r['a'], 1e3)}+/-{f(r['a_err'], 1e3)} lo {f(r['a_lower'], 1e3)} | {r['status']} "
            f"chi2r {f(r['redchi'], 1, 2)} {r['fit_s']:.1f}s")


def _interval_hits(r, name):
    """(truth in the 1-sigma interval, in the 2-sigma one): the profile interval if the fit gave one, else +/- err."""
    true = r[name + "_true"]
    if r.get(name + "_lo") is not None:
        hi, hi2 = (np.inf if r[name + k] is None else r[name + k] for k in ("_hi", "_hi2"))
        return r[name + "_lo"] <= true <= hi, r[name + "_lo2"] <= true <= hi2
    dev = abs(r[name] - true)
    return dev <= r[name + "_err"], dev <= 2 * r[name + "_err"]


def _target(small):
    """The accuracy target on the small contacts, and what the stated errors allow.

    ``both_speeds_2pct``: share of fits with |vx| and |vy| each within 2 % of |v|;
    ``a_5pct``: a within 5 %. ``*_expected``: the same shares for an unbiased
    estimator whose errors are the fits' own one-sigma errors (Gaussian), the
    mean over scenes of P(|N(0, sx)| < 0.02 |v|) P(|N(0, sy)| < 0.02 |v|): what an
    efficient estimator at the information this model uses would reach.
    """
    ok = [r for r in small if r["vx"] is not None and r["vy"] is not None and r["vx_err"] and r["vy_err"]]
    if not ok:
        return {"n": 0}

    def p_within(err, tol):
        return math.erf(tol / (err * math.sqrt(2.0)))

    hit = [abs(r["vx"] - r["vx_true"]) <= 0.02 * r["speed"] and abs(r["vy"] - r["vy_true"]) <= 0.02 * r["speed"]
           for r in ok]
    expected = [p_within(r["vx_err"], 0.02 * r["speed"]) * p_within(r["vy_err"], 0.02 * r["speed"]) for r in ok]
    with_a = [r for r in ok if r["a"] is not None and r["a_err"]]
    return {"n": len(ok), "both_speeds_2pct": float(np.mean(hit)), "both_speeds_2pct_expected": float(np.mean(expected)),
            "n_a": len(with_a),
            "a_5pct": float(np.mean([abs(r["a"] - r["a_true"]) <= 0.05 * r["a_true"] for r in with_a])) if with_a else None,
            "a_5pct_expected": float(np.mean([p_within(r["a_err"], 0.05 * r["a_true"]) for r in with_a])) if with_a else None}


ANGLE_BANDS = ((0, 20), (20, 45), (45, 70), (70, 90))     # deg from the x axis


def _by_angle(rows):
    """1-sigma coverage of the reported intervals of vx and vy per slip-angle band (deg from the x axis)."""
    out = {}
    for lo, hi in ANGLE_BANDS:
        band = [r for r in rows if lo <= r["angle_deg"] < hi or (hi == 90 and r["angle_deg"] == 90)]
        entry = {"n": len(band)}
        for name in ("vx", "vy"):
            hits = [_interval_hits(r, name)[0] for r in band if r[name] is not None and r[name + "_err"]]
            entry[name] = float(np.mean(hits)) if hits else None
        out[f"{lo}-{hi}"] = entry
    return out


def summarize(rows):
    out = {}
    for name in ("vx", "vy", "a"):
        pulls = np.array([(r[name] - r[name + "_true"]) / r[name + "_err"] for r in rows
                          if r[name] is not None and r[name + "_err"]])
        out[name] = {"n": int(pulls.size), "cover_1sigma": float(np.mean(np.abs(pulls) <= 1)) if pulls.size else None,
                     "cover_2sigma": float(np.mean(np.abs(pulls) <= 2)) if pulls.size else None,
                     "pull_mean": float(np.mean(pulls)) if pulls.size else None,
                     "pull_sd": float(np.std(pulls)) if pulls.size else None}
    # the intervals the fit reports: the profile-likelihood ones of a minor component where given
    for name in ("vx", "vy"):
        hits = [_interval_hits(r, name) for r in rows if r[name] is not None and r[name + "_err"]]
        n_prof = sum(r.get(name + "_lo") is not None for r in rows if r[name] is not None and r[name + "_err"])
        out[name].update({"cover_1sigma_reported": float(np.mean([h[0] for h in hits])) if hits else None,
                          "cover_2sigma_reported": float(np.mean([h[1] for h in hits])) if hits else None,
                          "n_profile": n_prof})
    out["by_angle"] = _by_angle(rows)
    small = [r for r in rows if r["a_true"] <= 2.5e-3]
    for name in ("vx", "vy"):
        dev = np.array([abs(r[name] - r[name + "_true"]) / r["speed"] for r in small if r[name] is not None])
        out[name + "_dev_over_speed_p95"] = float(np.percentile(dev, 95)) if dev.size else None
        out[name + "_dev_over_speed_max"] = float(dev.max()) if dev.size else None
    dev_a = np.array([abs(r["a"] - r["a_true"]) / r["a_true"] for r in small if r["a"] is not None])
    out["a_rel_dev_p95"] = float(np.percentile(dev_a, 95)) if dev_a.size else None
    out["a_rel_dev_max"] = float(dev_a.max()) if dev_a.size else None
    out["target"] = _target(small)
    large = [r for r in rows if r["a_true"] > 2.5e-3]
    out["large_a_reported_as_bound"] = sum(r["a"] is None for r in large)
    out["large_n"] = len(large)
    out["large_a_bound_holds"] = sum(r["a_lower"] is not None and r["a_lower"] <= r["a_true"] for r in large)
    out["status"] = {s: sum(r["status"] == s for r in rows) for s in sorted({r["status"] for r in rows})}
    out["fit_s_median"] = float(np.median([r["fit_s"] for r in rows]))
    return out


def figure(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tactile_jax.viz.figures import provenance

    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6))
    for ax, name in zip(axes, ("vx", "vy", "a")):
        pulls = np.array([(r[name] - r[name + "_true"]) / r[name + "_err"] for r in rows
                          if r[name] is not None and r[name + "_err"]])
        ax.hist(np.clip(pulls, -5, 5), bins=np.linspace(-5, 5, 41), density=True, alpha=0.7)
        z = np.linspace(-5, 5, 200)
        ax.plot(z, np.exp(-z * z / 2) / np.sqrt(2 * np.pi), "k-", lw=1)
        c1 = np.mean(np.abs(pulls) <= 1) if pulls.size else np.nan
        c2 = np.mean(np.abs(pulls) <= 2) if pulls.size else np.nan
        ax.set_title(f"{name}: 1$\\sigma$ {100 * c1:.0f}%, 2$\\sigma$ {100 * c2:.0f}% (n={pulls.size})")
        ax.set_xlabel("(estimate - truth) / error")
    fig.text(0.01, 0.01, provenance(), fontsize=6, color="0.4")
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _save(out: Path, **fields):
    """Write a study's ``coverage.json`` (what ``--merge`` reads)."""
    (out / "coverage.json").write_text(json.dumps(fields, indent=1, default=str))


def merge(paths, out: Path):
    """Summarise the rows of several coverage.json files (each scene index once) into ``out``."""
    rows, options = {}, set()
    for path in paths:
        try:
            d = json.loads(Path(path).read_text())
            part = d["rows"]
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise SystemExit(f"{path}: not a coverage.json ({e})") from None
        options.add(json.dumps(d.get("options", [])))
        for r in part:
            if r["i"] in rows:
                raise SystemExit(f"{path}: scene {r['i']} is also in an earlier file")
            rows[r["i"]] = r
    if len(options) > 1:
        raise SystemExit(f"{', '.join(map(str, paths))}: the runs used different options {sorted(options)}")
    rows = [rows[i] for i in sorted(rows)]
    summary = summarize(rows)
    print(f"# coverage study: {len(rows)} scenes merged from {', '.join(map(str, paths))}")
    print(json.dumps(summary, indent=1))
    out.mkdir(parents=True, exist_ok=True)
    _save(out, summary=summary, options=json.loads(options.pop()), merged_from=[str(p) for p in paths], rows=rows)
    figure(rows, out / "coverage.png")


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", type=int, default=120)
    p.add_argument("--seed", type=int, default=2026)
    p.add_argument("--out", default="benchmarks/out")
    p.add_argument("--skip", type=int, default=0, help="start at scene SKIP (resume a run)")
    p.add_argument("--option", action="append", default=[], metavar="NAME=VALUE",
                   help="a FitOptions field to change, e.g. --option band_neighbours=3 (repeatable)")
    p.add_argument("--snr", type=float, default=None, help="fix the SNR (dB) instead of drawing it in 30-60")
    p.add_argument("--large-fraction", type=float, default=0.15, help="share of 5-8 mm contacts (default 0.15)")
    p.add_argument("--merge", nargs="+", type=Path, metavar="JSON",
                   help="summarise the rows of earlier runs' coverage.json files (a run and its resumed parts) "
                        "instead of fitting")
    a = p.parse_args()
    if a.merge:
        merge(a.merge, Path(a.out))
        return
    options = FitOptions(**{k: ast.literal_eval(v) for k, v in (o.split("=", 1) for o in a.option)})
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f"# coverage study: {a.scenes} scenes, seed {a.seed}, SNR {a.snr or '30-60'} dB, "
          f"large contacts {a.large_fraction:.0%}; {platform.machine()} {platform.processor()}, "
          f"jax {jax.__version__}, numpy {np.__version__}" + (f"; options {a.option}" if a.option else ""))
    # rewritten after every scene: an interrupted run keeps its rows for ``--merge``
    rows = run(a.scenes, options, seed=a.seed, skip=a.skip, large_fraction=a.large_fraction, snr_db=a.snr,
               on_row=lambda rows: _save(out, partial=True, options=a.option, rows=rows))
    summary = summarize(rows)
    print(json.dumps(summary, indent=1))
    _save(out, summary=summary, options=a.option, rows=rows)
    figure(rows, out / "coverage.png")


if __name__ == "__main__":
    main()
