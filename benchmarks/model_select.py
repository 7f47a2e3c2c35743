"""Where does the selector drop the contact window? ``model="auto"`` on simulated scenes across contact radius.

Random texture sliding along x, Gaussian window, 8 s at 1 kHz, 50 dB; for each
radius and seed the joint fit with ``FitOptions(model="auto")`` picks among
slip / window / window+gain / window+noise by BIC (``model_select``). Prints the
choice, its margin, dBIC(slip - window) and the radius or its lower bound, and
the crossover radius (geometric mean of the largest radius where every seed
kept the window and the smallest where the majority dropped it).

    python benchmarks/model_select.py [--quick] [--speed 0.047] [--out benchmarks/out]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np

from tactile_jax.inference.options import FitOptions
from tactile_jax.inference.fit import fit_recording
from tactile_jax.viz.figures import provenance
from tactile_jax.simulation.scene import Scene, simulate


def run(radii, seeds, speed, duration):
    rows = []
    for a in radii:
        for seed in seeds:
            scene = Scene(velocity=(speed, 0.0), contact_radius=a, duration=duration, seed=seed,
                          grid_spacing=25e-6 if a < 7e-3 else 50e-6)
            rec = simulate(scene)
            t = time.perf_counter()
            r = fit_recording(rec, FitOptions(model="auto"))
            secs = time.perf_counter() - t
            slip_gap = _slip_gap(r.message or "")
            row = dict(a=a, seed=seed, model=r.model, margin=r.model_margin, slip_minus_window=slip_gap, a_fit=r.a, a_err=r.a_err,
                       a_lower=r.a_lower, vx=r.vx, vx_err=r.vx_err, redchi=r.redchi, status=r.status,
                       seconds=secs, message=r.message)
            rows.append(row)
            a_txt = (f"{1e3 * r.a:.3f} +/- {1e3 * r.a_err:.3f}" if r.a is not None else
                     f"> {1e3 * r.a_lower:.2f} (95 %)" if r.a_lower else "n/a")
            if r.a_lower and r.a_lower > a:
                a_txt += " VIOLATED"          # the reported lower bound excludes the truth
            print(f"{1e3 * a:6.1f} {seed:4d}  {r.model:<18}{(r.model_margin or 0):>8.1f}{slip_gap:>+10.1f}  {a_txt:<22}"
                  f"{100 * r.vx:8.3f}  {r.redchi:6.2f}  {secs:6.1f}  {r.status}", flush=True)
    return rows


def _slip_gap(message: str) -> float:
    """BIC(slip) - BIC(window) from the selector's note (negative: slip chosen, by that margin over window)."""
    head = message.split(")")[0]
    if head.startswith("model slip"):
        return -float(head.split("window +")[1].split(",")[0].split(")")[0]) if "window +" in head else float("nan")
    return float(head.split("slip +")[1].split(",")[0].split(")")[0]) if "slip +" in head else float("nan")


def crossover(rows):
    radii = sorted({r["a"] for r in rows})
    keep = [a for a in radii if all(r["model"].startswith("window") for r in rows if r["a"] == a)]
    drop = [a for a in radii if np.mean([r["model"].startswith("slip") for r in rows if r["a"] == a]) > 0.5]
    if not drop:
        return None, max(keep) if keep else None, None
    lo = max([a for a in keep if a < min(drop)], default=None)
    return (float(np.sqrt(lo * min(drop))) if lo else None), lo, min(drop)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="one seed, fewer radii")
    ap.add_argument("--speed", type=float, default=0.047)
    ap.add_argument("--duration", type=float, default=8.0)
    ap.add_argument("--out", default="benchmarks/out")
    ap.add_argument("--radii", default=None, help="comma-separated contact radii, mm (overrides the list)")
    ap.add_argument("--seeds", type=int, default=None, help="seeds per radius")
    args = ap.parse_args()
    radii = [2e-3, 5e-3, 8e-3, 12e-3] if args.quick else [2e-3, 4e-3, 6e-3, 8e-3, 10e-3, 14e-3]
    seeds = [0] if args.quick else [0, 1]
    if args.radii:
        radii = [1e-3 * float(v) for v in args.radii.split(",")]
    if args.seeds:
        seeds = list(range(args.seeds))
    print(provenance())
    print(f"slip along x at {100 * args.speed:g} cm/s, {args.duration:g} s at 1 kHz, 50 dB, Gaussian window")
    print(f"{'a mm':>6} {'seed':>4}  {'chosen':<18}{'margin':>8}{'dBIC slip':>10}  {'a fit mm':<22}{'vx cm/s':>8}  {'redchi':>6}  {'s':>6}")
    t0 = time.perf_counter()
    rows = run(radii, seeds, args.speed, args.duration)
    x, lo, hi = crossover(rows)
    if x is None:
        print(f"no crossover in the range: the window was kept up to {1e3 * (lo or 0):.1f} mm")
    else:
        print(f"crossover: window kept up to a = {1e3 * lo:.1f} mm, dropped from {1e3 * hi:.1f} mm: "
              f"about {1e3 * x:.1f} mm at {100 * args.speed:g} cm/s")
    print(f"total {time.perf_counter() - t0:.0f} s")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "model_select.json").write_text(json.dumps({"provenance": provenance(), "rows": rows,
                                                       "crossover_m": x}, indent=1, default=str))


if __name__ == "__main__":
    main()
