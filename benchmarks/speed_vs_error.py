"""Speed against error of every estimator of |v| and a, on the same recordings.

Seeded scenes (random texture, slip along x, so every single-pair method is a
valid model; Gaussian window) over SNR 10-60 dB, two speeds and two contact
radii, 8 s at 1 kHz. Each recording goes through:

  slope         Eq. 6 line of the x pair's log ratio (closed_form.slope_speed); a from its Eq. 26 offset
  pair fit      pair_fit.fit_pair: the x pair's exact R (Eq. 23) with its realised window term (optimistix LM)
  lmfit peer    benchmarks/peer_lmfit.py: scipy Welch, numpy exact R, lmfit leastsq (x pair)
  joint fit     fit.fit_recording: both pairs, the x-y chain, jackknife errors, profiles (the tool's default)

Times are per recording after compilation (medians; the first joint fit, which
compiles, is timed apart), each method's own spectra included. Errors: bias
and RMSE of |v| and a relative to the truth, over the recordings at >= 30 dB
and over all. Prints a markdown table, writes speed_vs_error.json and
speed_vs_error.png (time against RMSE) with the machine and versions.

    python benchmarks/speed_vs_error.py --out benchmarks/out              # 40 recordings, ~4 min on 2 cores
    python benchmarks/speed_vs_error.py --seeds 1 --out /tmp/sve          # 20 recordings
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import peer_lmfit  # noqa: E402

from tactile_jax.model.closed_form import radius_from_offset, slope_speed  # noqa: E402
from tactile_jax.inference.fit import fit_recording  # noqa: E402
from tactile_jax.inference.pair_fit import fit_pair, pair_leakage  # noqa: E402
from tactile_jax.viz.figures import provenance  # noqa: E402
from tactile_jax.simulation.scene import Scene, simulate  # noqa: E402
from tactile_jax.spectral.estimate import amplitude_ratio, estimate_spectra, usable_band, whitened_psd  # noqa: E402
from tactile_jax.simulation.texture import RandomTexture  # noqa: E402

METHODS = ("slope", "pair fit", "lmfit peer", "joint fit")


def scene_grid(seeds: int, snrs, speeds, radii, duration: float):
    rows = []
    for snr in snrs:
        for v in speeds:
            for a in radii:
                for s in range(seeds):
                    seed = 1000 * s + int(snr) * 7 + int(v * 1e3) * 13 + int(a * 1e5)
                    rows.append({"snr_db": snr, "speed": v, "a": a, "seed": seed,
                                 "scene": Scene(texture=RandomTexture(), velocity=(v, 0.0), contact_radius=a,
                                                snr_db=snr, duration=duration, seed=seed)})
    return rows


def _pair_methods(rec):
    """slope and pair fit on the x pair: ((v, a), seconds) each."""
    d1, d2 = rec.depths
    t0 = time.perf_counter()
    spec = estimate_spectra(np.asarray(rec.signals, float), rec.fs, prewhiten=8)
    ratio = amplitude_ratio(spec)
    band = usable_band(ratio, neighbours=3)
    args = (ratio.omega, ratio.log_ratio[0], ratio.log_ratio_err[0], band[0], d1, d2)
    t_spec = time.perf_counter() - t0
    t0 = time.perf_counter()
    line = slope_speed(*args, bin_factor=spec.bin_factor)
    a_line = float(radius_from_offset(line.intercept, d1, d2))
    t_slope = time.perf_counter() - t0 + t_spec
    t0 = time.perf_counter()
    fit = fit_pair(*args, bin_factor=spec.bin_factor, kernel=spec.kernel, spectrum=np.asarray(whitened_psd(spec)[0]),
                   leakage=pair_leakage(spec, 0))
    t_fit = time.perf_counter() - t0 + t_spec
    return {"slope": ((float(line.speed), a_line), t_slope), "pair fit": ((fit.speed, fit.a), t_fit)}


def _peer(rec):
    d1, d2 = rec.depths
    t0 = time.perf_counter()
    sp = peer_lmfit.spectra(np.asarray(rec.signals, float), rec.fs, 1024)
    f = peer_lmfit.fit_pair(sp.omega, sp.log_ratio[0], sp.log_ratio_err[0], sp.band[0], d1, d2)
    return (f.speed, f.a), time.perf_counter() - t0


def _joint(rec):
    t0 = time.perf_counter()
    res = fit_recording(rec)
    return (res.vx if res.vx is not None else np.nan, res.a if res.a is not None else np.nan), \
        time.perf_counter() - t0, res.status


def run(args):
    rows = scene_grid(args.seeds, args.snr, args.speeds, args.radii, args.duration)
    out = []
    # warm-up: every method compiles on a scene of its own first
    warm = simulate(Scene(texture=RandomTexture(), velocity=(0.03, 0.0), contact_radius=2e-3, duration=args.duration,
                          seed=99))
    t0 = time.perf_counter()
    _joint(warm)
    compile_joint = time.perf_counter() - t0
    _pair_methods(warm)
    _peer(warm)
    for k, row in enumerate(rows):
        rec = simulate(row["scene"])
        res = _pair_methods(rec)
        res["lmfit peer"] = _peer(rec)
        est, t, status = _joint(rec)
        res["joint fit"] = (est, t)
        rec_row = {"snr_db": row["snr_db"], "speed": row["speed"], "a": row["a"], "seed": row["seed"],
                   "joint_status": status}
        for m in METHODS:
            (v, a), t = res[m]
            rec_row[m] = {"v": v, "a": a, "seconds": t}
        out.append(rec_row)
        print(f"{k + 1}/{len(rows)} snr {row['snr_db']:g} v {100 * row['speed']:.1f} a {1e3 * row['a']:.1f}: "
              + "  ".join(f"{m} {100 * (rec_row[m]['v'] / row['speed'] - 1):+.2f}%" for m in METHODS), flush=True)
    return out, compile_joint


def summarise(rows, min_snr=None):
    sel = [r for r in rows if min_snr is None or r["snr_db"] >= min_snr]
    table = {}
    for m in METHODS:
        ev = np.array([r[m]["v"] / r["speed"] - 1 for r in sel], float)
        ea = np.array([r[m]["a"] / r["a"] - 1 for r in sel], float)
        t = np.array([r[m]["seconds"] for r in sel])
        ok_v, ok_a = np.isfinite(ev), np.isfinite(ea)
        table[m] = {"ms": 1e3 * float(np.median(t)), "n": len(sel), "v_fitted": int(ok_v.sum()),
                    "v_bias": 100 * float(np.mean(ev[ok_v])) if ok_v.any() else None,
                    "v_rmse": 100 * float(np.sqrt(np.mean(ev[ok_v] ** 2))) if ok_v.any() else None,
                    "a_fitted": int(ok_a.sum()),
                    "a_bias": 100 * float(np.mean(ea[ok_a])) if ok_a.any() else None,
                    "a_rmse": 100 * float(np.sqrt(np.mean(ea[ok_a] ** 2))) if ok_a.any() else None}
    return table


def markdown(table, label):
    def f(v):
        return "n/d" if v is None else f"{v:+.2f}" if abs(v) < 1e4 else f"{v:+.3g}"
    lines = [f"| method ({label}) | ms / recording | \\|v\\| bias / RMSE % | a bias / RMSE % (fitted) |",
             "|---|---|---|---|"]
    for m, s in table.items():
        lines.append(f"| {m} | {s['ms']:.1f} | {f(s['v_bias'])} / {f(s['v_rmse'])} | "
                     f"{f(s['a_bias'])} / {f(s['a_rmse'])} ({s['a_fitted']} of {s['n']}) |")
    return "\n".join(lines)


def figure(table, path, info):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for m, s in table.items():
        if s["v_rmse"] is not None:
            ax.scatter(s["ms"], s["v_rmse"], s=40)
            ax.annotate(m, (s["ms"], s["v_rmse"]), textcoords="offset points", xytext=(5, 4), fontsize=9)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("time per recording after compilation, ms (median)")
    ax.set_ylabel("|v| RMSE, % (recordings >= 30 dB)")
    ax.set_title("speed against error, slip along x, 8 s at 1 kHz", fontsize=10)
    fig.text(0.01, 0.01, info, fontsize=6, color="0.4")
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    fig.savefig(path, dpi=130)
    plt.close(fig)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=2)
    p.add_argument("--snr", type=float, nargs="+", default=[10.0, 20.0, 30.0, 45.0, 60.0])
    p.add_argument("--speeds", type=float, nargs="+", default=[0.015, 0.04])
    p.add_argument("--radii", type=float, nargs="+", default=[1.5e-3, 4e-3])
    p.add_argument("--duration", type=float, default=8.0)
    p.add_argument("--out", default="benchmarks/out")
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows, compile_joint = run(args)
    info = provenance()
    high, every = summarise(rows, 30.0), summarise(rows)
    text = (f"{info}\n\njoint fit, first call (compiles): {compile_joint:.1f} s\n\n" + markdown(high, ">= 30 dB") + "\n\n"
            + markdown(every, "all SNR") + "\n\njoint fit statuses: "
            + ", ".join(f"{s} {sum(r['joint_status'] == s for r in rows)}" for s in sorted({r['joint_status'] for r in rows})))
    print(text)
    (out / "speed_vs_error.json").write_text(json.dumps({"machine": info, "compile_joint_s": compile_joint,
                                                         "summary_30db": high, "summary_all": every, "rows": rows},
                                                        indent=1))
    figure(high, out / "speed_vs_error.png", info)
    print(f"wrote {out / 'speed_vs_error.json'} and {out / 'speed_vs_error.png'}")


if __name__ == "__main__":
    main()
