"""Batch throughput: recordings/s of ``batch.run_batch`` end to end, with errors and coverage, vs a scipy loop.

Two seeded scene sets, each a pool of ``--pool`` scenes simulated once without
noise (``scene.simulate``, random texture, Gaussian window) and cached in
``--out``; record j is pool scene j % P plus fresh white measurement noise
seeded by j (the scene's noise definition: sigma = sqrt(P_ref) 10^(-SNR/20),
P_ref the larger mean power of x1 and y1). So records share textures: the
statistics are over noise and over the pool's scenes, not over as many textures.

- ``x`` (the old script's set): |v| log-uniform in 2-8 cm/s along x or y
  (alternating), a uniform in 1.5-5 mm, 4 x 8192 samples at 1 kHz, SNR 50 dB, float64;
- ``oblique``: |v| log-uniform in 1-8 cm/s, direction uniform in 0-90 deg, a
  uniform in 0.8-3 mm, 16 s at 1 kHz, SNR uniform in 30-60 dB per record, float32.

For every set and size, in its own process (so that its first pass compiles and
its peak RSS is its own): the records are written to multi-record NPZ files
(not timed), then ``run_batch(files, out.json, chunk_size=--chunk)`` runs twice:
the first pass pays the compilations (rate "with compile"), the second is the
steady state (rate "warm"); both are end to end (scan, read, spectra, fit,
rows, write). Reported over the rows with status ``ok``: median |vx - |vx_true||
and |vy - |vy_true|| in % of |v|, and the share with |est - truth| <= err
(1 sigma) and <= 2 err (2 sigma) for vx, vy and a (a where the fit gave one).
Reference: ``scipy_reference.fit_record`` (scipy.signal + curve_fit per pair,
Welch segment ``spectra.default_nperseg(N)``) on the first ``--scipy-max`` of the
same records, timed per record (drawing excluded); its rate is given as a ratio.

    python benchmarks/throughput.py --out benchmarks/out                      # 100 records per set
    python benchmarks/throughput.py --sizes 16 --pool 4 --set oblique --out /tmp/tp   # quick
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

FS = 1000.0
SETS = {
    "x": {"n_samples": 8192, "snr_db": (50.0, 50.0), "dtype": "float64",
          "label": "slip along x or y, |v| 2-8 cm/s, a 1.5-5 mm, 50 dB, 8.2 s, float64"},
    "oblique": {"n_samples": 16000, "snr_db": (30.0, 60.0), "dtype": "float32",
                "label": "oblique 0-90 deg, |v| 1-8 cm/s, a 0.8-3 mm, 30-60 dB, 16 s, float32"},
}
#: records per NPZ file written for the batch (bounds the memory of the inputs)
FILE_RECORDS = 500


# --------------------------------------------------------------------------- pool and records


def _scene_params(name: str, k: int, rng):
    """(vx, vy, a, seed) of pool scene k of set ``name``."""
    import numpy as np

    if name == "x":                                     # as the old throughput script (rng seed 7)
        speed = float(np.exp(rng.uniform(np.log(0.02), np.log(0.08))))
        a = float(rng.uniform(1.5e-3, 5e-3))
        vel = (speed, 0.0) if k % 2 == 0 else (0.0, speed)
        return vel[0], vel[1], a, 100 + k
    speed = float(np.exp(rng.uniform(np.log(0.01), np.log(0.08))))
    angle = float(rng.uniform(0.0, np.pi / 2))
    a = float(rng.uniform(0.8e-3, 3e-3))
    return speed * np.cos(angle), speed * np.sin(angle), a, 200 + k


def pool(name: str, path: Path, n: int):
    """Noiseless signals (P, 4, N), reference rms (P,) and truth (P, 3) = (|vx|, |vy|, a); cached in ``path``."""
    import dataclasses

    import numpy as np

    if path.exists():
        z = np.load(path)
        return z["clean"], z["ref_rms"], z["truth"]
    from tactile_jax.errors import TactileInputError
    from tactile_jax.simulation.scene import Scene, simulate
    from tactile_jax.simulation.texture import RandomTexture

    rng = np.random.default_rng({"x": 7, "oblique": 8}[name])
    n_samples = SETS[name]["n_samples"]
    clean, ref, truth = [], [], []
    for k in range(n):
        vx, vy, a, seed = _scene_params(name, k, rng)
        scene = Scene(texture=RandomTexture(), velocity=(vx, vy), contact_radius=a, duration=n_samples / FS, fs=FS,
                      snr_db=None, seed=seed)
        t0 = time.perf_counter()
        try:
            rec = simulate(scene)
        except TactileInputError:       # a large contact at a fast slip: a coarser grid still resolves d1
            rec = simulate(dataclasses.replace(scene, grid_spacing=60e-6))
        sig = np.asarray(rec.signals, float)
        clean.append(sig)
        ref.append(np.sqrt(max(np.mean(sig[0] ** 2), np.mean(sig[2] ** 2))))
        truth.append((abs(vx), abs(vy), a))
        print(f"  {name} pool scene {k + 1}/{n}: v = ({100 * vx:.2f}, {100 * vy:.2f}) cm/s, a = {1e3 * a:.2f} mm "
              f"({time.perf_counter() - t0:.1f} s)", file=sys.stderr)
    clean, ref, truth = np.stack(clean), np.array(ref), np.array(truth)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, clean=clean, ref_rms=ref, truth=truth)
    return clean, ref, truth


def draw(name: str, clean, ref, j: int):
    """Record j of set ``name``: pool scene j % P plus noise seeded by j, in the set's dtype; and its SNR."""
    import numpy as np

    lo, hi = SETS[name]["snr_db"]
    snr = lo if lo == hi else float(np.random.default_rng(20_000 + j).uniform(lo, hi))
    k = j % len(clean)
    x = clean[k] + ref[k] * 10 ** (-snr / 20) * np.random.default_rng(10_000 + j).standard_normal(clean[k].shape)
    return x.astype(SETS[name]["dtype"]), snr


def _write_inputs(name, clean, ref, size, folder: Path) -> list[Path]:
    import numpy as np

    from tactile_jax.io.files import write_recording
    from tactile_jax.io.recording import Recording
    from tactile_jax.model.sensor import PAPER_SENSOR

    paths = []
    for f, start in enumerate(range(0, size, FILE_RECORDS)):
        stop = min(start + FILE_RECORDS, size)
        sig = np.stack([draw(name, clean, ref, j)[0] for j in range(start, stop)])
        rec = Recording(signals=sig, fs=FS, depths=(PAPER_SENSOR.d1, PAPER_SENSOR.d2),
                        curvature_radius=PAPER_SENSOR.curvature_radius)
        paths.append(write_recording(folder / f"{name}_{f:04d}.npz", rec))
    return paths


# --------------------------------------------------------------------------- statistics


def _median(values):
    import numpy as np

    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], float)
    return float(np.median(v)) if v.size else None


def accuracy(est, truth) -> dict:
    """est: rows (dicts with vx, vx_err, vy, vy_err, a, a_err); truth (n, 3). Median errors in % of |v| and
    1-/2-sigma coverage of vx, vy and a (where the row has the value and its error)."""
    import numpy as np

    out = {"n": len(est)}
    speed = np.hypot(truth[:, 0], truth[:, 1])
    for i, name in enumerate(("vx", "vy")):
        out[f"{name}_err_pct_median"] = _median(
            [100 * abs(r[name] - truth[k, i]) / speed[k] if r.get(name) is not None else None
             for k, r in enumerate(est)])
    for i, name in enumerate(("vx", "vy", "a")):
        dev = [(abs(r[name] - truth[k, i]), r[name + "_err"]) for k, r in enumerate(est)
               if r.get(name) is not None and r.get(name + "_err") and np.isfinite(r[name]) and np.isfinite(
                   r[name + "_err"])]
        out[f"{name}_n"] = len(dev)
        out[f"{name}_cover1"] = float(np.mean([d <= e for d, e in dev])) if dev else None
        out[f"{name}_cover2"] = float(np.mean([d <= 2 * e for d, e in dev])) if dev else None
    return out


def reported_cover(rows, truth) -> dict:
    """1-sigma coverage of vx and vy with the profile-likelihood interval of a minor component where the row has
    one (``vx_lo``, ``vx_hi``), else +/- err (what ``coverage.py`` calls the reported intervals)."""
    import numpy as np

    out = {}
    for i, name in enumerate(("vx", "vy")):
        hits = []
        for k, r in enumerate(rows):
            if r.get(name) is None or not r.get(name + "_err"):
                continue
            t = truth[k, i]
            if r.get(name + "_lo") is not None:
                hi = np.inf if r.get(name + "_hi") is None else r[name + "_hi"]
                hits.append(r[name + "_lo"] <= t <= hi)
            else:
                hits.append(abs(r[name] - t) <= r[name + "_err"])
        out[f"{name}_cover1_reported"] = float(np.mean(hits)) if hits else None
    return out


# --------------------------------------------------------------------------- one set and size (own process)


def one(name: str, size: int, args) -> dict:
    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import scipy_reference as ref_mod
    from tactile_jax.batch import run as batch_mod
    from tactile_jax.inference.options import FitOptions
    from tactile_jax.model.sensor import PAPER_SENSOR
    from tactile_jax.spectral.estimate import default_nperseg

    compiles = collections.defaultdict(lambda: [0, 0.0])
    phase = ["setup"]

    def listen(event, duration, **_):
        if event == "/jax/core/compile/backend_compile_duration":
            compiles[phase[0]][0] += 1
            compiles[phase[0]][1] += duration

    jax.monitoring.register_event_duration_secs_listener(listen)
    # a fresh persistent compilation cache, as the CLI keeps one: the first pass compiles (in each process the
    # batch spawns), the second loads the compiled program from it
    cache = Path(tempfile.mkdtemp(prefix="tjx_tp_cache_")) / "jax"
    jax.config.update("jax_compilation_cache_dir", str(cache))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    clean, ref, truth_pool = pool(name, Path(args.out) / f"throughput_pool_{name}_{args.pool}.npz", args.pool)
    work = Path(tempfile.mkdtemp(prefix=f"tjx_tp_{name}_"))
    try:
        files = _write_inputs(name, clean, ref, size, work)
        passes = []
        for k, label in enumerate(("with compile", "warm")):
            batch_mod._NPZ_CACHE.clear()            # the second pass reads its inputs again, as the first
            phase[0] = label
            t0 = time.perf_counter()
            summary = batch_mod.run_batch([str(p) for p in files], work / f"rows_{k}.json", chunk_size=args.chunk,
                                          progress=False, resume=False, processes=args.processes,
                                          options=FitOptions(window=args.window))
            wall = time.perf_counter() - t0
            rows = json.loads((work / f"rows_{k}.json").read_text())
            passes.append({"pass": label, "wall_s": wall, "rate": size / wall, "timings": summary.timings,
                           "n_rows": summary.n_rows, "n_failed": summary.n_failed,
                           "compiles": compiles[label][0], "compile_s": compiles[label][1]})
            print(f"  {name} {size}: {label}: {wall:.1f} s, {size / wall:.2f} rec/s, {compiles[label][0]} compiles "
                  f"({compiles[label][1]:.1f} s)", file=sys.stderr)
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        # rows in record order: (file index, index) -> j
        order = {str(p): f * FILE_RECORDS for f, p in enumerate(files)}
        by_j = {order[r["file"]] + int(r["index"]): r for r in rows}
        idx = np.arange(size)
        truth = truth_pool[idx % len(clean)]
        rows = [by_j.get(j, {"status": "missing"}) for j in idx]
        first = json.loads((work / "rows_0.json").read_text())
        same = all(a.get("vx") == b.get("vx") and a.get("status") == b.get("status")
                   for a, b in zip(sorted(first, key=lambda r: (r["file"], r["index"])),
                                   sorted(json.loads((work / "rows_1.json").read_text()),
                                          key=lambda r: (r["file"], r["index"]))))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    status = collections.Counter(r.get("status") for r in rows)
    ok = np.array([r.get("status") == "ok" for r in rows])
    acc = accuracy([r for r, o in zip(rows, ok) if o], truth[ok])
    acc.update(reported_cover([r for r, o in zip(rows, ok) if o], truth[ok]))
    # the scipy loop on the same records
    n_sp = min(size, args.scipy_max)
    n_samples = SETS[name]["n_samples"]
    nperseg = default_nperseg(n_samples)
    sp, t_sp = [], 0.0
    for j in range(n_sp):
        x, _ = draw(name, clean, ref, j)
        x = np.asarray(x, float)
        t1 = time.perf_counter()
        vx, vx_err, vy, vy_err, a, a_err = ref_mod.fit_record(x, FS, PAPER_SENSOR.d1, PAPER_SENSOR.d2, nperseg)
        t_sp += time.perf_counter() - t1
        sp.append({k: (None if not np.isfinite(v) else float(v)) for k, v in
                   zip(("vx", "vx_err", "vy", "vy_err", "a", "a_err"), (vx, vx_err, vy, vy_err, a, a_err))})
    fitted = np.array([r["vx"] is not None or r["vy"] is not None for r in sp])
    sp_acc = accuracy([r for r, f in zip(sp, fitted) if f], truth[:n_sp][fitted])
    return {"set": name, "size": size, "chunk": args.chunk, "pool": args.pool, "passes": passes,
            "rate_with_compile": passes[0]["rate"], "rate_warm": passes[1]["rate"],
            "passes_agree": bool(same), "status": dict(status), "ok_share": float(ok.mean()), "accuracy_ok": acc,
            "scipy": {"n": n_sp, "seconds": t_sp, "rate": n_sp / t_sp if t_sp > 0 else None, "nperseg": nperseg,
                      "fitted_share": float(fitted.mean()) if n_sp else None, "accuracy_fitted": sp_acc},
            "peak_rss_mb": rss, "cache_dir": jax.config.jax_compilation_cache_dir,
            "records": [{"j": int(j), "scene": int(j % len(clean)), "truth": [float(v) for v in truth[j]],
                         **{k: rows[j].get(k) for k in ("status", "vx", "vx_err", "vy", "vy_err", "a", "a_err",
                                                       "redchi", "message")}} for j in idx]}


# --------------------------------------------------------------------------- stage profile (one process)


def _device_memory():
    """Peak and current bytes of the default device (None where the backend keeps no statistics, a CPU)."""
    import jax

    stats = jax.devices()[0].memory_stats() or {}
    return {k: stats.get(k) for k in ("peak_bytes_in_use", "bytes_in_use", "bytes_limit")}


def stages(args) -> dict:
    """Where a batch spends its time on this process's default device (a GPU where there is one), on the
    oblique set, in one process with a fresh persistent cache, in this order:

    1. host spectra: ``fit.record_of`` (numpy) on 64 records, ms a record;
    2. ``run_batch`` end to end on ``--stage-batch`` records, chunk ``--chunk``: the first run, its compilations
       included (the rate "with compile"), with its statuses, errors and coverage against the truth;
    3. the analysis program on one chunk (``run.analyse_many``, vmapped, warm): its time, the device's peak
       memory, and each stage's iterations (the most any record took, which its block runs, against the
       record median);
    4. ``run_batch`` again: the warm rate;
    5. the chunk's spectra at once (``fit.records_of``, jnp), warm, ms a record.

    Steps begun after ``--deadline`` seconds are skipped; the profile is written after every step.
    """
    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    from tactile_jax.batch import run as batch_mod
    from tactile_jax.inference import run
    from tactile_jax.inference.analysis import STAGES
    from tactile_jax.inference.fit import record_of, records_of
    from tactile_jax.inference.options import FitOptions, analysis_settings, choices_of
    from tactile_jax.model.sensor import PAPER_SENSOR

    t_begin = time.perf_counter()
    cache = Path(tempfile.mkdtemp(prefix="tjx_stage_cache_")) / "jax"
    jax.config.update("jax_compilation_cache_dir", str(cache))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    out_path = Path(args.json or Path(args.out) / "throughput_stages.json")
    res = {"machine": machine(), "window": args.window or "default", "chunk": args.chunk, "steps": []}

    def save(step):
        res["steps"].append(step)
        res["elapsed_s"] = time.perf_counter() - t_begin
        res["memory"] = _device_memory()
        out_path.write_text(json.dumps(res, indent=1, default=str))
        print(f"  [{res['elapsed_s']:.0f} s] {step}", file=sys.stderr, flush=True)

    def late():
        return time.perf_counter() - t_begin > args.deadline

    clean, ref, truth_pool = pool("oblique", Path(args.out) / f"throughput_pool_oblique_{args.pool}.npz", args.pool)
    n, size = args.stage_batch, args.chunk
    depths = (PAPER_SENSOR.d1, PAPER_SENSOR.d2)
    options = FitOptions(window=args.window)
    settings, choices = analysis_settings(options), choices_of(options)
    sigs = np.stack([draw("oblique", clean, ref, j)[0] for j in range(max(n, size))]).astype(float)

    times = []
    for x in sigs[:64]:
        t0 = time.perf_counter()
        record_of(x, FS, depths, options)
        times.append(time.perf_counter() - t0)
    res["spectra_host_ms"] = 1e3 * float(np.median(times[1:]))
    save(f"host spectra (numpy): {res['spectra_host_ms']:.1f} ms a record (median of 63)")

    work = Path(tempfile.mkdtemp(prefix="tjx_stage_"))
    files = _write_inputs("oblique", clean, ref, n, work)
    order = {str(p): f * FILE_RECORDS for f, p in enumerate(files)}

    def batch(label):
        batch_mod._NPZ_CACHE.clear()
        t0 = time.perf_counter()
        summary = batch_mod.run_batch([str(p) for p in files], work / "rows.json", chunk_size=size, progress=False,
                                      resume=False, processes=args.processes, options=options)
        wall = time.perf_counter() - t0
        rows = json.loads((work / "rows.json").read_text())
        by_j = {order[r["file"]] + int(r["index"]): r for r in rows}
        rows = [by_j.get(j, {"status": "missing"}) for j in range(n)]
        truth = truth_pool[np.arange(n) % len(clean)]
        ok = np.array([r.get("status") == "ok" for r in rows])
        acc = accuracy([r for r, o in zip(rows, ok) if o], truth[ok])
        entry = res[label] = {"records": n, "chunk": size, "wall_s": wall, "rate": n / wall,
                              "timings": summary.timings, "accuracy_ok": acc,
                              "status": dict(collections.Counter(r.get("status") for r in rows))}
        save(f"run_batch {label}: {n} records, chunk {size}: {wall:.1f} s ({n / wall:.1f} rec/s); "
             + ", ".join(f"{k} {v:.1f} s" for k, v in summary.timings.items())
             + f"; {entry['status']}; median |vx|, |vy| error {_num(acc['vx_err_pct_median'])}, "
               f"{_num(acc['vy_err_pct_median'])} % of |v|; 1-sigma cover vx / vy / a {_pct(acc['vx_cover1'])} / "
               f"{_pct(acc['vy_cover1'])} / {_pct(acc['a_cover1'])} %")

    try:
        if n and not late():
            batch("batch_first")
        if not late():
            recs = records_of(sigs[:size], np.full(size, FS), [depths] * size, [options] * size)
            t0 = time.perf_counter()
            an = run.analyse_many(recs, settings, choices, size, vmapped=True)
            entry = res["analysis"] = {"size": size, "block": run.VMAP_BLOCK, "warm_s": time.perf_counter() - t0}
            it = np.stack([np.asarray(a.stages.iterations) for a in an])           # (size, K)
            act = np.stack([np.asarray(a.stages.active) for a in an])
            blocks = it.reshape(-1, min(run.VMAP_BLOCK, size), len(STAGES)) if size % min(run.VMAP_BLOCK, size) == 0 \
                else it[None]
            entry["iterations"] = {name: {"max": int(it[:, k].max()), "median": float(np.median(it[:, k])),
                                          "active_share": float(act[:, k].mean())} for k, name in enumerate(STAGES)}
            entry["iterations_per_block"] = float(blocks.max(axis=1).sum(axis=-1).mean())   # what a block runs
            entry["iterations_per_record"] = float(np.median(it.sum(axis=1)))              # what a record needs
            mem = res["memory"]["peak_bytes_in_use"] if res.get("memory") else None
            save(f"analysis program, {size} records in blocks of {min(run.VMAP_BLOCK, size)}, warm: "
                 f"{entry['warm_s']:.2f} s ({size / entry['warm_s']:.1f} rec/s); a block iterates "
                 f"{entry['iterations_per_block']:.0f} times (mean), a record needs "
                 f"{entry['iterations_per_record']:.0f} (median); peak device memory so far "
                 f"{'-' if mem is None else f'{mem / 2**30:.2f} GiB'}")
        if n and not late():
            batch("batch_warm")
        if not late():
            t0 = time.perf_counter()
            recs = records_of(sigs[:size], np.full(size, FS), [depths] * size, [options] * size)
            res["spectra_device_ms"] = 1e3 * (time.perf_counter() - t0) / size
            save(f"spectra of the chunk at once (jnp), warm: {res['spectra_device_ms']:.2f} ms a record")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return res


# --------------------------------------------------------------------------- report


def machine() -> dict:
    import jax
    import jaxlib
    import numpy as np
    import scipy

    from tactile_jax.viz.figures import provenance

    dev = jax.devices()[0]
    return {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
            "cpu_count": os.cpu_count(), "load_avg_1_5_15": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
            "python": platform.python_version(), "jax": jax.__version__, "jaxlib": jaxlib.__version__,
            "numpy": np.__version__, "scipy": scipy.__version__, "backend": f"{dev.platform} ({dev.device_kind})",
            "threads_env": {k: os.environ.get(k) for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "XLA_FLAGS")},
            "provenance": provenance()}


def _pct(x):
    return "-" if x is None else f"{100 * x:.0f}"


def _num(x, fmt=".2f"):
    return "-" if x is None else format(x, fmt)


def table(results, m, args) -> str:
    lines = [f"machine: {m['processor']}, {m['cpu_count']} CPUs, {m['platform']}, Python {m['python']}, jax {m['jax']} "
             f"(jaxlib {m['jaxlib']}, {m['backend']}), numpy {m['numpy']}, scipy {m['scipy']}; load average at start "
             f"{[round(v, 2) for v in m['load_avg_1_5_15']]}",
             f"run_batch, chunk_size {args.chunk}, window {args.window or 'default (Hertz and Gaussian)'}, pool {args.pool} scenes per set, float64 compute; "
             "errors and coverage over the rows with status ok", ""]
    for name in dict.fromkeys(r["set"] for r in results):
        lines.append(f"- {name}: {SETS[name]['label']}")
    lines += ["", "| set | records | rec/s with compile | rec/s warm | compiles (s) | ok | median |vx| err % of |v| | "
                  "median |vy| err % of |v| | 1-sigma cover vx / vy / a % | 2-sigma cover vx / vy / a % | n a | "
                  "scipy rec/s | warm / scipy |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        a, p0 = r["accuracy_ok"], r["passes"][0]
        sp = r["scipy"]["rate"]
        lines.append(
            f"| {r['set']} | {r['size']} | {r['rate_with_compile']:.2f} | {r['rate_warm']:.2f} | "
            f"{p0['compiles']} ({p0['compile_s']:.0f}) | {_pct(r['ok_share'])} % | {_num(a['vx_err_pct_median'])} | "
            f"{_num(a['vy_err_pct_median'])} | {_pct(a['vx_cover1'])} / {_pct(a['vy_cover1'])} / {_pct(a['a_cover1'])} "
            f"| {_pct(a['vx_cover2'])} / {_pct(a['vy_cover2'])} / {_pct(a['a_cover2'])} | {a['a_n']} | "
            f"{_num(sp, '.1f')} ({r['scipy']['n']}) | {_num(r['rate_warm'] / sp if sp else None, '.3f')} |")
    lines += ["", "| set | records | statuses | warm pass: spectra s / fit s / write s | peak RSS MB | "
                  "scipy: fitted | scipy median |vx| / |vy| err % of |v| | scipy 1-sigma cover vx / vy / a % |",
              "|---|---|---|---|---|---|---|---|"]
    for r in results:
        t = r["passes"][1]["timings"]
        s = r["scipy"]["accuracy_fitted"]
        lines.append(f"| {r['set']} | {r['size']} | {r['status']} | {t['spectra']:.1f} / {t['fit']:.1f} / "
                     f"{t['write']:.2f} | {r['peak_rss_mb']:.0f} | {_pct(r['scipy']['fitted_share'])} % | "
                     f"{_num(s['vx_err_pct_median'])} / {_num(s['vy_err_pct_median'])} | {_pct(s['vx_cover1'])} / "
                     f"{_pct(s['vy_cover1'])} / {_pct(s['a_cover1'])} |")
    return "\n".join(lines)


def figure(results, path: Path, m, args):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from tactile_jax.viz.figures import save_figure

    labels = [f"{r['set']}\n{r['size']} rec" for r in results]
    series = (("run_batch, with compile", [r["rate_with_compile"] for r in results]),
              ("run_batch, warm", [r["rate_warm"] for r in results]),
              ("scipy loop (reference)", [r["scipy"]["rate"] or np.nan for r in results]))
    fig, ax = plt.subplots(figsize=(1.6 + 1.9 * len(results), 3.8))
    x = np.arange(len(results))
    w = 0.26
    for k, (label, values) in enumerate(series):
        bars = ax.bar(x + (k - 1) * w, values, w, label=label)
        ax.bar_label(bars, fmt="%.3g", fontsize=7)
    ax.set_yscale("log")
    ax.set_xticks(x, labels)
    ax.set_ylabel("recordings / s")
    ax.set_title(f"tactile-jax batch throughput (chunk {args.chunk}); {m['processor']}, {m['cpu_count']} CPUs",
                 fontsize=9)
    ax.legend(fontsize=7, loc="upper left")
    ax.set_ylim(top=ax.get_ylim()[1] * 8)                # room for the legend above the bars
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    save_figure(fig, path)
    print(f"figure: {path}", file=sys.stderr)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", default="100", help="comma-separated batch sizes (records per set)")
    ap.add_argument("--set", dest="sets", default="both", choices=["x", "oblique", "both"])
    ap.add_argument("--pool", type=int, default=16, help="simulated scenes per set")
    ap.add_argument("--chunk", type=int, default=32, help="run_batch's chunk_size")
    ap.add_argument("--processes", type=int, default=None, help="run_batch's processes (default: one per core)")
    ap.add_argument("--window", choices=("gaussian", "hertz"), default=None,
                    help="fit one contact window (default: both, the one the data prefer kept, as batch does)")
    ap.add_argument("--scipy-max", type=int, default=1000, help="scipy loop on at most this many records")
    ap.add_argument("--out", default="benchmarks/out")
    ap.add_argument("--stages", action="store_true",
                    help="profile one process's stages on its default device (a GPU where there is one) instead")
    ap.add_argument("--stage-batch", type=int, default=1000, help="with --stages: records of run_batch end to end")
    ap.add_argument("--json", default=None, help="with --stages: where to write the profile (default: in --out)")
    ap.add_argument("--deadline", type=float, default=1e9, help="with --stages: skip the steps begun after this (s)")
    ap.add_argument("--one", nargs=2, metavar=("SET", "SIZE"), default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.stages:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        stages(args)
        return
    if args.one is not None:
        print(json.dumps(one(args.one[0], int(args.one[1]), args)))
        return
    Path(args.out).mkdir(parents=True, exist_ok=True)
    sizes = [int(s) for s in args.sizes.split(",")]
    sets = ["x", "oblique"] if args.sets == "both" else [args.sets]
    env = dict(os.environ)
    env.pop("JAX_COMPILATION_CACHE_DIR", None)             # every process compiles afresh: "with compile" is that
    results = []
    for name in sets:
        for size in sizes:
            cmd = [sys.executable, __file__, "--one", name, str(size), f"--pool={args.pool}", f"--chunk={args.chunk}", *([f"--window={args.window}"] if args.window else []), *([f"--processes={args.processes}"] if args.processes else []),
                   f"--scipy-max={args.scipy_max}", f"--out={args.out}"]
            proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
            sys.stderr.write("".join(line + "\n" for line in proc.stderr.splitlines()
                                     if line.startswith("  ") and "Warning" not in line))
            if proc.returncode:
                print(proc.stderr[-3000:], file=sys.stderr)
                raise SystemExit(f"set {name}, size {size} failed")
            results.append(json.loads(proc.stdout.strip().splitlines()[-1]))
    import jax

    jax.config.update("jax_enable_x64", True)
    m = machine()
    text = table(results, m, args)
    print(text)
    out = Path(args.out)
    (out / "throughput.json").write_text(json.dumps({"machine": m, "sets": {k: SETS[k] for k in sets},
                                                     "chunk": args.chunk, "pool": args.pool, "results": results,
                                                     "table": text}, indent=1, default=str))
    figure(results, out / "throughput.png", m, args)
    print(f"wrote {out / 'throughput.json'}", file=sys.stderr)


if __name__ == "__main__":
    main()
