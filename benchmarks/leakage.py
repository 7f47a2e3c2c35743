"""What the realised window term buys the pair fit: ``fit_pair(leakage=...)`` against the window average alone.

The H1 ratio at a bin is R averaged over the spectral window with the weights
of THIS recording's texture there; the window average models their expectation
(session 7), ``pair_fit.Leakage`` adds the realised first moment (the shallow
power's centroid, R' times it) and weights the bins by their errors of noise
alone (``pair_fit.noise_err``). Per cell (SNR, |v|, a), N seeded 8 s
recordings, slip along x, Gaussian window, the segment speed_vs_error uses:
RMSE and bias of |v| and a, the median stated error, the pull sd (scatter /
stated), and the efficiency CRB / MSE against the pair CRB of the cell's noise
(``crb.pair_crb(leakage=..., noise_alone=True)``: each bin's noise-alone
variance averaged over the cell's recordings, neighbouring bins correlated as
the estimator's ``CrossSpectra.bin_corr`` says); for comparison against each
recording's own noise-alone errors with bins independent (session 8's bound)
and against the Bendat-Piersol errors (sessions 5-7).

    python benchmarks/leakage.py --out benchmarks/out               # ~6 min on 2 cores
    python benchmarks/leakage.py --reps 4 --cells 1 --out /tmp/x    # a smoke run
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from speed_vs_error import cell_noise_err, pair_data, scene_grid, shallow_seen  # noqa: E402

from tactile_jax.crb import pair_crb  # noqa: E402
from tactile_jax.pair_fit import fit_pair, noise_err, pair_leakage  # noqa: E402
from tactile_jax.plotting import provenance, save_figure  # noqa: E402
from tactile_jax.scene import simulate  # noqa: E402

#: (SNR dB, |v| m/s, a m, Welch segment): high SNR small contact, the slow large-contact cell, the 30 dB cell
CELLS = ((60.0, 0.04, 0.0015, 1024), (45.0, 0.015, 0.004, 2048), (50.0, 0.015, 0.0015, 2048),
         (30.0, 0.04, 0.0015, 2048))
METHODS = ("window average", "with leakage")


def machine() -> str:
    return f"{provenance()}, {os.cpu_count()} cores, {jax.devices()[0].platform}"


def run_cell(snr, speed, a, nperseg, reps):
    rows = []
    for g in scene_grid(reps, [snr], [speed], [a], 8.0, False):
        rec = simulate(g["scene"])
        d1, d2 = rec.depths
        spec, ratio, band = pair_data(np.asarray(rec.signals, float), rec.fs, nperseg)
        omega, lr = np.asarray(ratio.omega), np.nan_to_num(np.asarray(ratio.log_ratio[0]))
        err = np.asarray(ratio.log_ratio_err[0])
        err = np.where(np.isfinite(err), err, 1.0)
        mask = np.asarray(band[0])
        kw = dict(kernel=spec.kernel, spectrum=shallow_seen(spec))
        lk = pair_leakage(spec, 0)
        row = {}
        for name, leak in zip(METHODS, (None, lk)):
            t0 = time.perf_counter()
            f = fit_pair(omega, lr, err, mask, d1, d2, leakage=leak, **kw)
            row[name] = {"dv": f.speed / speed - 1, "da": f.a / a - 1, "sv": f.speed_err / f.speed,
                         "sa": f.a_err / f.a, "ok": f.converged, "s": time.perf_counter() - t0}
        for tag, leak in (("noise", lk), ("bp", None)):
            b = pair_crb(omega, err, mask, d1, d2, speed, a, leakage=leak, **kw)
            row[f"crb_{tag}"] = (float(b.speed_sd[0]) / speed, float(b.a_sd) / a)
        row["bound_args"] = (omega, mask, d1, d2, kw, lk, spec.bin_corr)
        row["noise_var"] = np.where(mask, noise_err(omega, err, mask, speed, a, d1, d2, lk) ** 2, np.nan)
        rows.append(row)
    # the bound of the cell's noise: each bin's noise-alone variance averaged over the cell's recordings
    # (one recording's is an estimate with ~K degrees of freedom, and 1 / var over-counts information),
    # with the estimator's correlation between neighbouring bins (``CrossSpectra.bin_corr``)
    for r, err in zip(rows, cell_noise_err([r.pop("noise_var") for r in rows])):
        omega, mask, d1, d2, kw, lk, rho = r.pop("bound_args")
        b = pair_crb(omega, np.where(mask, err, 1.0), mask, d1, d2, speed, a, leakage=lk, noise_alone=True,
                     bin_corr=rho, **kw)
        r["crb_cell"] = (float(b.speed_sd[0]) / speed, float(b.a_sd) / a)
    return rows


def summarise(rows):
    out = {}
    for name in METHODS:
        ok = [r for r in rows if r[name]["ok"]]
        e = np.array([[r[name][k] for k in ("dv", "da", "sv", "sa")] for r in ok])
        c = np.array([r["crb_cell"] + r["crb_noise"] + r["crb_bp"] for r in ok])
        out[name] = {
            "n": len(ok),
            "v_rmse_pct": 100 * float(np.sqrt(np.mean(e[:, 0] ** 2))), "a_rmse_pct": 100 * float(np.sqrt(np.mean(e[:, 1] ** 2))),
            "v_bias_pct": 100 * float(np.mean(e[:, 0])), "a_bias_pct": 100 * float(np.mean(e[:, 1])),
            "v_stated_pct": 100 * float(np.median(e[:, 2])), "a_stated_pct": 100 * float(np.median(e[:, 3])),
            "v_pull_sd": float(np.sqrt(np.mean((e[:, 0] / e[:, 2]) ** 2))),
            "a_pull_sd": float(np.sqrt(np.mean((e[:, 1] / e[:, 3]) ** 2))),
            "crb_v_pct": 100 * float(np.median(c[:, 0])), "crb_a_pct": 100 * float(np.median(c[:, 1])),
            "eff_v": float(1 / np.mean(e[:, 0] ** 2 / c[:, 0] ** 2)), "eff_a": float(1 / np.mean(e[:, 1] ** 2 / c[:, 1] ** 2)),
            "eff_v_indep": float(1 / np.mean(e[:, 0] ** 2 / c[:, 2] ** 2)),
            "eff_a_indep": float(1 / np.mean(e[:, 1] ** 2 / c[:, 3] ** 2)),
            "eff_v_bp": float(1 / np.mean(e[:, 0] ** 2 / c[:, 4] ** 2)),
            "eff_a_bp": float(1 / np.mean(e[:, 1] ** 2 / c[:, 5] ** 2)),
            "ms": 1e3 * float(np.median([r[name]["s"] for r in ok[1:]] or [np.nan])),
        }
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--reps", type=int, default=24, help="seeded recordings per cell")
    ap.add_argument("--cells", type=int, default=len(CELLS), help="the first N cells of CELLS")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/out"))
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    print(machine(), flush=True)
    t0 = time.perf_counter()
    results = []
    head = ("| SNR dB | \\|v\\| cm/s | a mm | model | n | \\|v\\| RMSE % (bias) | a RMSE % (bias) | stated \\|v\\| / a % "
            "| pull sd \\|v\\| / a | CRB \\|v\\| / a % | CRB/MSE \\|v\\| / a | (bins independent) | (B-P bound) | ms |")
    lines = [head, "|" + "---|" * 14]
    for snr, speed, a, nperseg in CELLS[: args.cells]:
        s = summarise(run_cell(snr, speed, a, nperseg, args.reps))
        results.append({"snr_db": snr, "speed": speed, "a": a, "nperseg": nperseg, **s})
        for name in METHODS:
            q = s[name]
            lines.append(f"| {snr:.0f} | {100 * speed:.1f} | {1e3 * a:.1f} | {name} | {q['n']} | "
                         f"{q['v_rmse_pct']:.3f} ({q['v_bias_pct']:+.3f}) | {q['a_rmse_pct']:.2f} ({q['a_bias_pct']:+.2f}) | "
                         f"{q['v_stated_pct']:.3f} / {q['a_stated_pct']:.2f} | {q['v_pull_sd']:.2f} / {q['a_pull_sd']:.2f} | "
                         f"{q['crb_v_pct']:.3f} / {q['crb_a_pct']:.2f} | {q['eff_v']:.2f} / {q['eff_a']:.2f} | "
                         f"{q['eff_v_indep']:.2f} / {q['eff_a_indep']:.2f} | {q['eff_v_bp']:.2f} / {q['eff_a_bp']:.2f} | {q['ms']:.0f} |")
        print(lines[-2] + "\n" + lines[-1], flush=True)
    wall = time.perf_counter() - t0
    print("\n" + "\n".join(lines))
    print(f"\n{args.reps} recordings per cell; wall {wall:.0f} s")
    (args.out / "leakage.json").write_text(json.dumps({"machine": machine(), "reps": args.reps, "wall_s": wall,
                                                        "cells": results}, indent=1))
    _figure(results, args.out / "leakage.png")
    print(f"wrote {args.out / 'leakage.json'} and leakage.png")


def _figure(results, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    labels = [f"{r['snr_db']:.0f} dB\n{100 * r['speed']:.1f} cm/s\n{1e3 * r['a']:.1f} mm" for r in results]
    x = np.arange(len(results))
    for ax, q, name in ((axes[0], "v", "|v|"), (axes[1], "a", "a")):
        for k, m in enumerate(METHODS):
            ax.bar(x + (k - 0.5) * 0.38, [r[m][f"{q}_rmse_pct"] for r in results], 0.38, label=m)
            ax.scatter(x + (k - 0.5) * 0.38, [r[m][f"{q}_stated_pct"] for r in results], color="k", marker="_", s=200,
                       zorder=3, label="median stated error" if k == 0 else None)
        ax.set_xticks(x, labels, fontsize=8)
        ax.set_yscale("log")
        ax.set_ylabel(f"{name} RMSE, % of truth")
        ax.legend(fontsize=8)
    fig.suptitle("pair fit: window average alone vs with the realised window term (pair_fit.Leakage)", fontsize=9)
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    save_figure(fig, path)


if __name__ == "__main__":
    main()
