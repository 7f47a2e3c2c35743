"""Batch throughput (issue 7): recordings/s of the compiled chunk program vs a scipy loop and a numpy floor.

Recordings of 4 x 8192 samples at 1 kHz are drawn from a seeded pool of
simulated scenes (``--pool`` scenes, simulated once with ``scene.simulate``
without noise and cached in ``--out``; |v| log-uniform in 2-8 cm/s along x or
y, contact radius uniform in 1.5-5 mm, random texture), each draw adding fresh
white measurement noise at 50 dB SNR (the scene's own noise definition). So
recordings share textures: the error statistics are over noise, and over the
pool's scenes, not over 10,000 textures.

For every batch size (its own process, so that the peak RSS is that size's):

- batch: ``batch_fit.FitProgram`` (what ``tactile-jax batch`` runs), chunks of
  ``--chunk`` records generated on the fly; a warm-up chunk is timed apart as
  the compile time; spectral and fitting stages are timed separately;
- scipy: ``scipy_reference.fit_record`` per recording (scipy.signal +
  curve_fit of the same exact-R pair model) on the first ``--scipy-max``
  recordings (its rate does not depend on the batch size);
- floor: vectorised numpy/scipy Welch auto- and cross-spectra only.

Errors: relative deviation of the speed along the slip axis from |v|, and of
a from the truth (bias and RMSE in %), on records both methods fitted.

    python benchmarks/throughput.py --out benchmarks/out                 # 100, 1000, 10000
    python benchmarks/throughput.py --sizes 100 --pool 8 --scipy-max 50  # quick
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

N_SAMPLES, FS, SNR_DB = 8192, 1000.0, 50.0


def _pool(path: Path, n: int):
    import numpy as np

    if path.exists():
        z = np.load(path)
        return z["clean"], z["noise_std"], z["truth"]
    from tactile_jax.scene import Scene, simulate

    rng = np.random.default_rng(7)
    clean, noise, truth = [], [], []
    for k in range(n):
        speed = float(np.exp(rng.uniform(np.log(0.02), np.log(0.08))))
        axis = k % 2
        a = float(rng.uniform(1.5e-3, 5e-3))
        vel = (speed, 0.0) if axis == 0 else (0.0, speed)
        rec = simulate(Scene(velocity=vel, contact_radius=a, duration=N_SAMPLES / FS, fs=FS, snr_db=None, seed=100 + k))
        sig = np.asarray(rec.signals, float)
        p_ref = max(np.mean(sig[0] ** 2), np.mean(sig[2] ** 2))
        clean.append(sig)
        noise.append(np.sqrt(p_ref) * 10 ** (-SNR_DB / 20))
        truth.append((vel[0], vel[1], a))
        print(f"  pool scene {k + 1}/{n}: v = ({100 * vel[0]:.2f}, {100 * vel[1]:.2f}) cm/s, a = {1e3 * a:.2f} mm",
              file=sys.stderr)
    clean, noise, truth = np.stack(clean), np.array(noise), np.array(truth)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, clean=clean, noise_std=noise, truth=truth)
    return clean, noise, truth


def _draw(clean, noise, start, stop):
    """Records start..stop-1: pool scene j % P plus noise seeded by j."""
    import numpy as np

    out = np.empty((stop - start, 4, N_SAMPLES))
    idx = np.arange(start, stop) % len(clean)
    for k, j in enumerate(range(start, stop)):
        out[k] = clean[idx[k]] + noise[idx[k]] * np.random.default_rng(10_000 + j).standard_normal((4, N_SAMPLES))
    return out, idx


def _errors(est_v, est_a, truth_idx, truth):
    import numpy as np

    speed = np.maximum(truth[truth_idx, 0], truth[truth_idx, 1])
    along = np.where(truth[truth_idx, 0] >= truth[truth_idx, 1], est_v[:, 0], est_v[:, 1])
    dv = 100 * (along / speed - 1)
    da = 100 * (est_a / truth[truth_idx, 2] - 1)
    return dv, da


def _stats(d):
    import numpy as np

    d = d[np.isfinite(d)]
    return {"bias": float(np.mean(d)) if d.size else None, "rmse": float(np.sqrt(np.mean(d ** 2))) if d.size else None,
            "median_abs": float(np.median(np.abs(d))) if d.size else None, "n": int(d.size)}


def one_size(size: int, args) -> dict:
    """Run one batch size in this process; return the measurements."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import scipy_reference as ref
    from tactile_jax.batch_fit import ChunkMeta, FitProgram
    from tactile_jax.fit import FitOptions
    from tactile_jax.spectra import default_nperseg

    clean, noise, truth = _pool(Path(args.out) / f"throughput_pool_{args.pool}.npz", args.pool)
    chunk = min(args.chunk, size)
    program = FitProgram(options=FitOptions(), model=args.model, solver=args.solver)
    nperseg = default_nperseg(N_SAMPLES - (FitOptions().prewhiten or 0))

    def meta(b):
        return ChunkMeta(fs=np.full(b, FS), depths=np.tile([0.265e-3, 0.925e-3], (b, 1)), gains=np.ones((b, 2)),
                         velocity=np.zeros((b, 2)), known=np.zeros(b, bool), curvature_radius=np.full(b, 0.03))

    # compile: one warm-up chunk (drawn past the measured records), then the same chunk again
    warm, _ = _draw(clean, noise, 10 ** 7, 10 ** 7 + chunk)
    t0 = time.perf_counter()
    program(warm, meta(chunk))
    t_first = time.perf_counter() - t0
    t0 = time.perf_counter()
    program(warm, meta(chunk))
    t_again = time.perf_counter() - t0
    program.timings = {"spectra": 0.0, "fit": 0.0}
    rss_after_compile = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    est_v, est_a, status, t_gen = [], [], [], 0.0
    t_run = 0.0
    for start in range(0, size, chunk):
        stop = min(start + chunk, size)
        tg = time.perf_counter()
        x, _ = _draw(clean, noise, start, stop)
        if stop - start < chunk:                                   # pad the last chunk with copies
            x = np.concatenate([x, np.repeat(x[:1], chunk - (stop - start), axis=0)])
        t_gen += time.perf_counter() - tg
        t0 = time.perf_counter()
        fit = program(x, meta(chunk))
        t_run += time.perf_counter() - t0
        n = stop - start
        est_v.append(np.stack([fit.vx[:n], fit.vy[:n]], axis=-1))
        est_a.append(fit.a[:n])
        status.extend(fit.status[:n])
        del x
    est_v, est_a = np.concatenate(est_v), np.concatenate(est_a)
    idx = np.arange(size) % len(clean)
    dv, da = _errors(est_v, est_a, idx, truth)
    ok = np.array([s in ("ok", "poor_fit", "not_converged") for s in status])
    # scipy loop on the first records
    n_sp = min(size, args.scipy_max)
    sp = np.full((n_sp, 6), np.nan)
    t_sp = 0.0
    for j in range(n_sp):                                          # timed per record (draws excluded)
        x, _ = _draw(clean, noise, j, j + 1)
        t1 = time.perf_counter()
        sp[j] = ref.fit_record(x[0], FS, 0.265e-3, 0.925e-3, nperseg)
        t_sp += time.perf_counter() - t1
    n_timed = n_sp
    dv_sp, da_sp = _errors(sp[:, [0, 2]], sp[:, 4], idx[:n_sp], truth)
    both = np.isfinite(dv[:n_sp]) & np.isfinite(dv_sp)
    # numpy Welch floor (vectorised over chunks)
    t_floor, n_floor = 0.0, min(size, args.floor_max)
    for start in range(0, n_floor, chunk):
        x, _ = _draw(clean, noise, start, min(start + chunk, n_floor))
        t1 = time.perf_counter()
        ref.welch_floor(x, FS, nperseg)
        t_floor += time.perf_counter() - t1
    return {
        "size": size, "chunk": chunk, "model": args.model, "solver": args.solver, "compile_s": t_first - t_again, "first_chunk_s": t_first,
        "batch_s": t_run, "batch_rate": size / t_run, "spectra_s": program.timings["spectra"],
        "fit_s": program.timings["fit"], "scipy_rate": n_timed / t_sp, "scipy_n": n_sp, "scipy_timed": n_timed,
        "floor_rate": n_floor / t_floor, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "rss_after_compile_mb": rss_after_compile, "fitted_fraction": float(ok.mean()),
        "scipy_fitted_fraction": float(np.mean(np.isfinite(dv_sp))),
        "err_batch": {"v": _stats(dv), "a": _stats(da)},
        "err_batch_common": {"v": _stats(dv[:n_sp][both]), "a": _stats(da[:n_sp][both])},
        "err_scipy_common": {"v": _stats(dv_sp[both]), "a": _stats(da_sp[both])},
    }


def compare_solvers(n: int, args) -> dict:
    """The pair model with gauss_newton and with optimistix LM on the same ``n`` records: differences
    in units of the error bars, statuses, stage times. Prints a summary, writes solvers_pair.json."""
    import collections

    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    from tactile_jax.batch_fit import ChunkMeta, FitProgram

    clean, noise, truth = _pool(Path(args.out) / f"throughput_pool_{args.pool}.npz", args.pool)
    chunk = min(args.chunk, n)
    meta = ChunkMeta(fs=np.full(chunk, FS), depths=np.tile([0.265e-3, 0.925e-3], (chunk, 1)), gains=np.ones((chunk, 2)),
                     velocity=np.zeros((chunk, 2)), known=np.zeros(chunk, bool), curvature_radius=np.full(chunk, 0.03))
    fits, times = {}, {}
    for solver in ("gauss_newton", "optimistix"):
        program = FitProgram(model="pair", solver=solver)
        parts = []
        t0 = time.perf_counter()
        for start in range(0, n, chunk):
            x, _ = _draw(clean, noise, start, min(start + chunk, n))
            if len(x) < chunk:
                x = np.concatenate([x, np.repeat(x[:1], chunk - len(x), axis=0)])
            parts.append(program(x, meta))
        times[solver] = {"total_s": time.perf_counter() - t0, **program.timings}
        fits[solver] = {k: np.concatenate([np.asarray(getattr(p, k)) for p in parts])[:n]
                        for k in ("vx", "vx_err", "vy", "vy_err", "a", "a_err", "status", "message")}
    g, o = fits["gauss_newton"], fits["optimistix"]
    both_ok = (g["status"] == "ok") & (o["status"] == "ok")
    out = {"n": n, "times": times, "status_gauss_newton": dict(collections.Counter(g["status"])),
           "status_optimistix": dict(collections.Counter(o["status"])),
           "status_agree": int(np.sum(g["status"] == o["status"])), "both_ok": int(both_ok.sum())}
    differ = g["status"] != o["status"]
    weak = np.array(["too weak to measure a" in m for m in g["message"]]) & np.array(
        ["too weak to measure a" in m for m in o["message"]])
    out["status_differ_with_a_too_weak_in_both"] = int(np.sum(differ & weak))
    for name in ("vx", "vy", "a"):
        a, b, e = g[name], o[name], o[name + "_err"]
        fin = np.isfinite(a) & np.isfinite(b) & np.isfinite(e) & (e > 0)
        d = np.abs(a - b) / np.where(fin, e, 1.0)
        out[f"{name}_max_diff_sigma_both_ok"] = float(np.max(d[fin & both_ok])) if np.any(fin & both_ok) else None
        out[f"{name}_max_diff_sigma_all"] = float(np.max(d[fin])) if np.any(fin) else None
        out[f"{name}_nan_mismatch"] = int(np.sum(np.isfinite(a) != np.isfinite(b)))
    print(json.dumps(out, indent=1))
    (Path(args.out) / "solvers_pair.json").write_text(json.dumps(out, indent=1))
    return out


def _machine() -> str:
    import jax
    import numpy as np
    import scipy

    dev = jax.devices()[0]
    return (f"{platform.machine()} {os.cpu_count()} cores ({dev.platform}: {dev.device_kind}), Python "
            f"{platform.python_version()}, jax {jax.__version__}, numpy {np.__version__}, scipy {scipy.__version__}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", default="100,1000,10000")
    ap.add_argument("--pool", type=int, default=16)
    ap.add_argument("--chunk", type=int, default=256)
    ap.add_argument("--model", default="pair", choices=["pair", "joint"])
    ap.add_argument("--solver", default="gauss_newton", choices=["gauss_newton", "optimistix", "jaxopt"],
                    help="the pair fits' solver (batch_fit.SOLVERS)")
    ap.add_argument("--compare-solvers", type=int, default=0, metavar="N",
                    help="only compare gauss_newton with optimistix on the first N records, then exit")
    ap.add_argument("--scipy-max", type=int, default=1000, help="scipy loop on at most this many records")
    ap.add_argument("--floor-max", type=int, default=2000, help="numpy floor on at most this many records")
    ap.add_argument("--out", default="benchmarks/out")
    ap.add_argument("--one", type=int, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one is not None:
        print(json.dumps(one_size(args.one, args)))
        return
    if args.compare_solvers:
        compare_solvers(args.compare_solvers, args)
        return
    Path(args.out).mkdir(parents=True, exist_ok=True)
    results = []
    for size in (int(s) for s in args.sizes.split(",")):
        cmd = [sys.executable, __file__, "--one", str(size)] + [f"--{k.replace('_', '-')}={v}" for k, v in vars(args).items()
                                                              if k not in ("one", "sizes")]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode:
            print(proc.stderr[-3000:], file=sys.stderr)
            raise SystemExit(f"size {size} failed")
        results.append(json.loads(proc.stdout.strip().splitlines()[-1]))
        print(f"size {size} done: {results[-1]['batch_rate']:.1f} rec/s", file=sys.stderr)
    import jax

    jax.config.update("jax_enable_x64", True)
    machine = _machine()
    lines = [f"machine: {machine}", f"model: {args.model}, solver {args.solver}, chunk {args.chunk}, pool {args.pool} scenes, 4 x {N_SAMPLES} "
             f"samples at {FS:g} Hz, SNR {SNR_DB:g} dB", "",
             "| recordings | batch rec/s | compile s | spectra s | fit s | scipy loop rec/s | speed-up | numpy Welch floor rec/s | peak RSS MB |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        lines.append(f"| {r['size']} | {r['batch_rate']:.1f} | {r['compile_s']:.1f} | {r['spectra_s']:.1f} | "
                     f"{r['fit_s']:.1f} | {r['scipy_rate']:.1f} ({r['scipy_timed']} timed) | "
                     f"{r['batch_rate'] / r['scipy_rate']:.1f}x | {r['floor_rate']:.0f} | {r['peak_rss_mb']:.0f} |")
    lines += ["", "| recordings | method | fitted | |v| bias % | |v| RMSE % | a bias % | a RMSE % | on |",
              "|---|---|---|---|---|---|---|---|"]
    for r in results:
        for name, key, frac in (("batch (all)", "err_batch", r["fitted_fraction"]),
                                ("batch", "err_batch_common", None), ("scipy", "err_scipy_common", r["scipy_fitted_fraction"])):
            e = r[key]
            f = "" if frac is None else f"{100 * frac:.0f} %"
            def fmt(x):
                return "n/a" if x is None else f"{x:+.2f}"
            lines.append(f"| {r['size']} | {name} | {f} | {fmt(e['v']['bias'])} | {e['v']['rmse'] or float('nan'):.2f} | "
                         f"{fmt(e['a']['bias'])} | {e['a']['rmse'] or float('nan'):.2f} | {e['v']['n']} records |")
    table = "\n".join(lines)
    print(table)
    (Path(args.out) / f"throughput_{args.model}.json").write_text(json.dumps({"machine": machine, "results": results},
                                                                            indent=1))
    _figure(results, Path(args.out) / f"throughput_{args.model}.png", machine, args)


def _figure(results, path, machine, args):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tactile_jax.plotting import provenance

    sizes = [r["size"] for r in results]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    ax1.loglog(sizes, [r["batch_rate"] for r in results], "o-", label=f"batch ({args.model}, chunk {args.chunk})")
    ax1.loglog(sizes, [r["scipy_rate"] for r in results], "s--", label="scipy loop (welch + curve_fit)")
    ax1.loglog(sizes, [r["floor_rate"] for r in results], "^:", label="numpy Welch only (floor)")
    ax1.set_xlabel("recordings in the batch")
    ax1.set_ylabel("recordings / s")
    ax1.legend(fontsize=8)
    ax2.semilogx(sizes, [r["peak_rss_mb"] for r in results], "o-", label="peak RSS")
    ax2.semilogx(sizes, [r["rss_after_compile_mb"] for r in results], "x--", label="after compile")
    ax2.set_xlabel("recordings in the batch")
    ax2.set_ylabel("MB")
    ax2.set_ylim(bottom=0)
    ax2.legend(fontsize=8)
    fig.suptitle("tactile-jax batch throughput, 4 x 8192 samples per recording", fontsize=10)
    fig.text(0.01, 0.005, provenance() + " | " + machine, fontsize=5)
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    fig.savefig(path, dpi=120)
    print(f"figure: {path}", file=sys.stderr)


if __name__ == "__main__":
    main()
