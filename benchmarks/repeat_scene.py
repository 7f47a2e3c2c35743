"""Repeated draws of coverage scenes: does a scene's reported error match its own scatter?

Each scene of ``coverage.scenes`` is simulated again ``--draws`` times with new
texture and noise (the scene's speeds, radius and SNR kept), fitted with the
defaults, and the major speed component's scatter across draws compared with
the median reported error, the median unit Laplace error (the reported one over
the root of its scale, ``FitResult.error_scales``), that scale and the component's
own jackknife variance ratio (the same since session 19, unless the reduced
chi-square is larger). With the texture fixed the scatter is about 5x smaller than the reported
error (session 16): the texture's randomness is most of what an error bar
covers, so only full redraws test it.

    python benchmarks/repeat_scene.py 1 4 --draws 30 --out benchmarks/out    # ~15 min per scene, 2 cores

Session 18 (2-core x86-64, jax 0.10.2): scene 4 (1.2 deg off x, 4 cm/s) err^2 / scatter^2
1.77 (unit Laplace 1.05, scale 1.68 pooled over vx, vy, a, vx's own jackknife ratio 1.06); scene 1
(16 deg, 6.6 cm/s) 1.17. Since session 19 each of vx, vy, a takes its own ratio.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import coverage  # noqa: E402

from tactile_jax.fit import FitOptions, fit_recording  # noqa: E402
from tactile_jax.plotting import provenance  # noqa: E402
from tactile_jax.scene import simulate  # noqa: E402


def repeat(scene, index: int, draws: int) -> dict:
    """Fit ``draws`` redraws of ``scene``; the major component's scatter against its error bars."""
    major = "vx" if abs(scene.velocity[0]) >= abs(scene.velocity[1]) else "vy"
    truth = abs(scene.velocity[0 if major == "vx" else 1])
    rng = np.random.default_rng(1000 + index)               # session 16-18's draws
    rows, statuses = [], []
    for k in range(draws):
        t0 = time.perf_counter()
        r = fit_recording(simulate(dataclasses.replace(scene, seed=int(rng.integers(1 << 30)))), FitOptions())
        statuses.append(r.status)
        print(f"  scene {index} draw {k}: {r.status} ({time.perf_counter() - t0:.0f} s)", flush=True)
        if r.status == "ok" and getattr(r, major + "_err") and r.jackknife:
            rows.append((getattr(r, major), getattr(r, major + "_err"), r.error_scales[major],
                         r.jackknife["variance_ratio"].get(major, np.nan)))
    a = np.array(rows, float).reshape(-1, 4)
    out = {"scene": index, "component": major, "speed": float(np.hypot(*scene.velocity)),
           "angle_deg": float(np.degrees(np.arctan2(abs(scene.velocity[1]), abs(scene.velocity[0])))),
           "contact_radius": scene.contact_radius, "snr_db": scene.snr_db, "draws": draws,
           "status": {s: statuses.count(s) for s in sorted(set(statuses))}, "n_ok": len(a)}
    if len(a) < 3:
        return out
    scatter = float(a[:, 0].std(ddof=1))
    err, unit = float(np.median(a[:, 1])), float(np.median(a[:, 1] / np.sqrt(a[:, 2])))
    out.update(scatter=scatter, median_err=err, err2_over_scatter2=(err / scatter) ** 2,
               unit_err2_over_scatter2=(unit / scatter) ** 2, median_scale=float(np.median(a[:, 2])),
               median_own_ratio=float(np.nanmedian(a[:, 3])), bias_sd=float((a[:, 0].mean() - truth) / scatter),
               ratio_sd=float(np.sqrt(2.0 / (len(a) - 1))) * (err / scatter) ** 2)
    return out


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("scenes", type=int, nargs="+", help="indices into coverage.scenes (seed 2026)")
    p.add_argument("--draws", type=int, default=30)
    p.add_argument("--out", type=Path, default=Path("benchmarks/out"))
    args = p.parse_args()
    wanted = set(args.scenes)
    results = [repeat(sc, i, args.draws) for i, sc in coverage.scenes(max(wanted) + 1) if i in wanted]
    print(f"\n{provenance()}")
    print("| scene | angle deg | \\|v\\| cm/s | ok of draws | scatter % of \\|v\\| | err^2 / scatter^2 (+/-) "
          "| unit Laplace | scale | own jackknife ratio | bias (sd) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in results:
        if "scatter" not in r:
            print(f"| {r['scene']} | {r['angle_deg']:.1f} | {100 * r['speed']:.2f} | {r['n_ok']} of {r['draws']} "
                  "| - | - | - | - | - | - |")
            continue
        print(f"| {r['scene']} | {r['angle_deg']:.1f} | {100 * r['speed']:.2f} | {r['n_ok']} of {r['draws']} "
              f"| {100 * r['scatter'] / r['speed']:.3f} | {r['err2_over_scatter2']:.2f} ({r['ratio_sd']:.2f}) "
              f"| {r['unit_err2_over_scatter2']:.2f} | {r['median_scale']:.2f} | {r['median_own_ratio']:.2f} "
              f"| {r['bias_sd']:+.2f} |")
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "repeat_scene.json"
    path.write_text(json.dumps({"provenance": provenance(), "results": results}, indent=1))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
