"""Where the time of the joint pipeline goes: per stage, one record and a chunk, cold and warm, compilations.

Stages (``tactile_jax.joint``), for ONE record and for a CHUNK of ``--chunk``
records (``jax.vmap``, as ``batch`` runs them):

- spectra: ``run.record`` (numpy ``segments``, the compiled ``locate``, the
  segments again where a slow slip wants a longer Welch segment); a chunk
  loops over its records, as ``batch`` does;
- set-up: ``core.prepare`` (band selection, pair-fit starts, data), jitted alone;
- solve: ``solve.levenberg_marquardt`` (the multi-start loop), jitted alone;
- finish: ``core.finish`` (statistics, jackknife, texture sections), jitted alone;
- core: the whole program as the package runs it (``run.fit_one``: one record,
  ``run.fit_many``: the chunk), conversions included;
- fit_recording: ``fit.fit_recording`` (spectra, core, and the layers on top:
  more solves, model checks, profile-likelihood bounds; one record only, the
  batch does not layer). Its cold time comes from a fresh process without a
  persistent cache (in this process the core program is compiled by then);
- row: ``fit.result_from_summary(...).to_record()`` (a chunk: every record).

The staged programs are the ones ``core`` composes (``prepare`` -> ``solve`` ->
``finish``, checked to give the same theta), compiled separately here to time
them; the package itself compiles ``core`` as one program. Cold = the first call
in this process (compile included); warm = median of ``--repeats`` calls. Every
phase counts the XLA compilations (``/jax/core/compile/backend_compile_duration``
events of ``jax.monitoring``) and their seconds; a warm phase should show none.

Then the persistent compilation cache: ``tactile-jax fit FILE --out X.json
--quiet`` in a subprocess with a fresh cache (``TACTILE_JAX_CACHE=<tmp>/jax``),
again on another same-shape file with that (now warm) cache, and once with 4 files.

Records: 4 seeded scenes (random texture, 16 s at 1 kHz, Gaussian window),
simulated once without noise and cached in ``--out``; record j is scene j % 4
plus fresh white noise at 40 dB (seeded by j). Scene 0 (3 + 0.6 cm/s, a = 1.5 mm)
has a minor speed component, so its ``fit_recording`` runs the profile intervals.

    python benchmarks/joint_speed.py --out benchmarks/out                    # ~6-8 min on 2 cores
    python benchmarks/joint_speed.py --chunk 8 --repeats 5 --out /tmp/js     # smaller
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

FS = 1000.0
DURATION = 16.0
SNR_DB = 40.0
#: (vx, vy) m/s, a m, seed of the scenes the records are drawn from
SCENES = (((0.030, 0.006), 1.5e-3, 11), ((0.023, 0.0), 3.0e-3, 12), ((0.020, 0.020), 1.0e-3, 13),
          ((0.050, 0.015), 2.0e-3, 14))
STAGES = ("spectra", "set-up", "solve", "finish", "core", "fit_recording", "row")
COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"


# --------------------------------------------------------------------------- compile events


class Compiles:
    """Backend compilations (count, seconds, per program) and trace/lowering seconds per labelled phase."""

    def __init__(self):
        self.label = "(outside)"
        self.count = collections.Counter()
        self.seconds = collections.defaultdict(float)
        self.trace_s = collections.defaultdict(float)
        self.programs = collections.defaultdict(lambda: collections.defaultdict(float))

    def listen(self, event, duration, **kw):
        if event == COMPILE_EVENT:
            self.count[self.label] += 1
            self.seconds[self.label] += duration
            self.programs[self.label][kw.get("fun_name", "?")] += duration
        elif event.startswith("/jax/core/compile/"):        # jaxpr trace, jaxpr -> MLIR
            self.trace_s[self.label] += duration

    @contextlib.contextmanager
    def phase(self, label):
        old, self.label = self.label, label
        try:
            yield
        finally:
            self.label = old

    def of(self, label):
        progs = sorted(self.programs[label].items(), key=lambda kv: -kv[1])
        return {"n": int(self.count[label]), "compile_s": float(self.seconds[label]),
                "trace_lower_s": float(self.trace_s[label]),
                "programs": {k: round(v, 3) for k, v in progs if v >= 0.05}}


# --------------------------------------------------------------------------- records


def _scenes(path: Path):
    """Noiseless signals (S, 4, N) and truth (S, 3) of ``SCENES``, simulated once and cached."""
    if path.exists():
        z = np.load(path)
        return z["clean"], z["truth"]
    import dataclasses

    from tactile_jax.errors import TactileInputError
    from tactile_jax.scene import Scene, simulate
    from tactile_jax.texture import RandomTexture

    clean, truth = [], []
    for (vx, vy), a, seed in SCENES:
        scene = Scene(texture=RandomTexture(), velocity=(vx, vy), contact_radius=a, snr_db=None, duration=DURATION,
                      fs=FS, seed=seed)
        t0 = time.perf_counter()
        try:
            rec = simulate(scene)
        except TactileInputError:
            rec = simulate(dataclasses.replace(scene, grid_spacing=60e-6))
        print(f"  simulated v = ({100 * vx:.1f}, {100 * vy:.1f}) cm/s, a = {1e3 * a:.1f} mm in "
              f"{time.perf_counter() - t0:.1f} s", file=sys.stderr)
        clean.append(np.asarray(rec.signals, float))
        truth.append((vx, vy, a))
    clean, truth = np.stack(clean), np.array(truth)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, clean=clean, truth=truth)
    return clean, truth


def _draw(clean, j):
    """Record j: scene j % S plus white noise at ``SNR_DB`` (the scene's definition), seeded by j."""
    x = clean[j % len(clean)]
    sigma = np.sqrt(max(np.mean(x[0] ** 2), np.mean(x[2] ** 2))) * 10 ** (-SNR_DB / 20)
    return x + sigma * np.random.default_rng(50_000 + j).standard_normal(x.shape)


def _recording(x, j):
    from tactile_jax.recording import Recording
    from tactile_jax.sensor import PAPER_SENSOR

    return Recording(signals=x, fs=FS, depths=(PAPER_SENSOR.d1, PAPER_SENSOR.d2),
                     curvature_radius=PAPER_SENSOR.curvature_radius, source=f"joint_speed record {j}")


# --------------------------------------------------------------------------- timing


def _timed(fn, *args):
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    return time.perf_counter() - t0, out


def _measure(comp: Compiles, key: str, fn, args, repeats: int):
    """Cold (first) and warm (median of ``repeats``) seconds of ``fn(*args)``, with the phases' compilations."""
    with comp.phase(key + "/cold"):
        cold, out = _timed(fn, *args)
    warm = []
    with comp.phase(key + "/warm"):
        for _ in range(repeats):
            warm.append(_timed(fn, *args)[0])
    entry = {"cold_s": cold, "warm_s": statistics.median(warm), "warm_all_s": warm,
             "compiles_cold": comp.of(key + "/cold"), "compiles_warm": comp.of(key + "/warm")}
    print(f"  {key:24s} cold {cold:8.3f} s  warm {entry['warm_s']:8.4f} s  compiles {entry['compiles_cold']['n']}"
          f" ({entry['compiles_cold']['compile_s']:.1f} s) / {entry['compiles_warm']['n']}", file=sys.stderr)
    return entry, out


def _stage_programs():
    """The stages ``core`` composes, as separate functions (same calls as ``core.core``)."""
    import jax.numpy as jnp

    from tactile_jax.joint import core as core_mod
    from tactile_jax.joint.solve import levenberg_marquardt

    def solve(prep, start):
        starts, free, skip = prep.starts, prep.free, False
        if start is not None:
            starts = jnp.where(start.use, jnp.broadcast_to(start.theta.astype(starts.dtype), starts.shape), starts)
            free = jnp.where(start.use, start.free, free)
            skip = start.use
        n_first, n_start, n_final = core_mod.ITERATIONS
        out = levenberg_marquardt(core_mod.residuals_and_model, starts, prep.data, free, prep.first,
                                  n_start=n_start, n_first=n_first, n_final=n_final, skip_starts=skip)
        return out, free

    def finish(rec, prep, free, out):
        b = prep.band
        return core_mod.finish(rec, prep.data, free, core_mod.Located(b.i0, b.n_leak, b.k0, b.speed0), *out)

    return core_mod.prepare, solve, finish


def _row(s):
    from tactile_jax.fit import result_from_summary
    from tactile_jax.model_select import model_name

    return result_from_summary(s, model=model_name(s.free, False)).to_record()


def one_and_chunk(args, clean, comp: Compiles) -> dict:
    """Every stage for one record, then for a chunk, in this process (compiles counted per phase)."""
    from tactile_jax.fit import FitOptions, fit_recording
    from tactile_jax.joint import run
    from tactile_jax.joint.core import Settings, no_start
    from tactile_jax.sensor import PAPER_SENSOR

    depths = (PAPER_SENSOR.d1, PAPER_SENSOR.d2)
    settings = Settings()
    prepare, solve, finish = _stage_programs()
    out = {"one": {}, "chunk": {}}
    r = args.repeats

    # ---- one record (record 0: scene 0)
    x0 = _draw(clean, 0)
    out["one"]["spectra"], rec = _measure(comp, "one/spectra", lambda: run.record(x0, FS, depths, settings=settings),
                                          (), r)
    rec_j, start_j = run._as_jnp(rec), run._as_jnp(no_start())
    j_prep, j_solve, j_finish = jax.jit(prepare), jax.jit(solve), jax.jit(finish)
    out["one"]["set-up"], prep = _measure(comp, "one/set-up", j_prep, (rec_j, settings), r)
    out["one"]["solve"], (sol, free) = _measure(comp, "one/solve", j_solve, (prep, start_j), r)
    out["one"]["finish"], staged = _measure(comp, "one/finish", j_finish, (rec_j, prep, free, sol), r)
    out["one"]["core"], s = _measure(comp, "one/core", run.fit_one, (rec, settings), r)
    out["one"]["staged_equals_core"] = bool(np.allclose(np.asarray(staged.theta), s.theta, rtol=1e-8, atol=1e-10))
    # fit_recording: count the core calls its layers make (refits go through run.fit_one)
    calls = collections.Counter()
    orig = run.fit_one

    def counting(*a, **kw):
        calls["n"] += 1
        return orig(*a, **kw)

    run.fit_one = counting
    try:
        recording = _recording(x0, 0)
        calls.clear()
        out["one"]["fit_recording"], res = _measure(comp, "one/fit_recording", fit_recording,
                                                    (recording, FitOptions()), r)
        out["one"]["fit_recording"]["core_calls"] = calls["n"] // (r + 1)
    finally:
        run.fit_one = orig
    out["one"]["fit_recording"]["status"] = res.status
    out["one"]["fit_recording"]["message"] = res.message
    out["one"]["row"], row = _measure(comp, "one/row", _row, (s,), r)
    out["one"]["status"] = row["status"]

    # ---- a chunk: records 1..chunk (scenes 1, 2, 3, 0, ...), vmapped
    n = args.chunk
    xs = [_draw(clean, j) for j in range(1, n + 1)]
    out["chunk"]["spectra"], recs = _measure(
        comp, "chunk/spectra", lambda: [run.record(x, FS, depths, settings=settings) for x in xs], (), r)
    stacked = run._as_jnp(jax.tree.map(lambda *v: np.stack(v), *recs))
    v_prep = jax.jit(jax.vmap(prepare, in_axes=(0, None)))
    v_solve = jax.jit(jax.vmap(lambda p: solve(p, None)))
    v_finish = jax.jit(jax.vmap(finish))
    out["chunk"]["set-up"], prep = _measure(comp, "chunk/set-up", v_prep, (stacked, settings), r)
    out["chunk"]["solve"], (sol, free) = _measure(comp, "chunk/solve", v_solve, (prep,), r)
    out["chunk"]["finish"], staged = _measure(comp, "chunk/finish", v_finish, (stacked, prep, free, sol), r)
    out["chunk"]["core"], summaries = _measure(comp, "chunk/core", run.fit_many, (recs, settings, n), r)
    theta = np.stack([q.theta for q in summaries])
    out["chunk"]["staged_equals_core"] = bool(np.allclose(np.asarray(staged.theta), theta, rtol=1e-8, atol=1e-10))
    out["chunk"]["row"], rows = _measure(comp, "chunk/row", lambda: [_row(q) for q in summaries], (), r)
    out["chunk"]["status"] = dict(collections.Counter(q["status"] for q in rows))
    return out


# --------------------------------------------------------------------------- subprocesses


def _clean_env(**extra):
    env = dict(os.environ)
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    env.update(extra)
    return env


def cold_fit(path: str) -> dict:
    """(--cold-fit) ``fit_recording`` twice in this fresh process, no persistent cache: JSON on stdout."""
    comp = Compiles()
    jax.monitoring.register_event_duration_secs_listener(comp.listen)
    t0 = time.perf_counter()
    from tactile_jax.fit import FitOptions, fit_recording
    from tactile_jax.io import read_recording

    rec = read_recording(path)
    t_import = time.perf_counter() - t0
    with comp.phase("first"):
        t1, res = _timed(fit_recording, rec, FitOptions())
    with comp.phase("second"):
        t2, _ = _timed(fit_recording, rec, FitOptions())
    return {"import_read_s": t_import, "first_s": t1, "second_s": t2, "status": res.status,
            "compiles_first": comp.of("first"), "compiles_second": comp.of("second"),
            "cache_dir": jax.config.jax_compilation_cache_dir}


def _cli() -> list[str]:
    exe = shutil.which("tactile-jax")
    return [exe] if exe else [sys.executable, "-c", "from tactile_jax.cli import main; main()"]


def _files_in(folder: Path) -> int:
    return sum(1 for p in folder.rglob("*") if p.is_file()) if folder.exists() else 0


def persistent_cache(files: list[Path], work: Path) -> dict:
    """Wall seconds of ``tactile-jax fit`` with a fresh persistent cache, the warm cache, and 4 files."""
    tmp = Path(tempfile.mkdtemp(prefix="tjx_cache_"))
    cache = tmp / "jax"                  # the CLI writes its jax.export file beside it (tmp / "export")
    env = _clean_env(TACTILE_JAX_CACHE=str(cache))
    out = {"cache_dir": "<tmp>/jax", "runs": []}

    def call(name, paths):
        dest = work / f"cli_{name}.json"
        cmd = _cli() + ["fit", *map(str, paths), "--out", str(dest), "--quiet"]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        rows = json.loads(dest.read_text()) if dest.exists() else []
        entry = {"run": name, "files": len(paths), "wall_s": wall, "rc": proc.returncode,
                 "statuses": dict(collections.Counter(r.get("status") for r in rows)),
                 "cache_files": _files_in(cache), "export_files": _files_in(tmp / "export")}
        if proc.returncode:
            entry["stderr"] = proc.stderr[-2000:]
        out["runs"].append(entry)
        print(f"  cli {name:28s} {wall:7.2f} s  rc {proc.returncode}  cache files {entry['cache_files']}",
              file=sys.stderr)

    try:
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", "import tactile_jax.cli, tactile_jax.fit"], env=env, check=True)
        out["import_only_s"] = time.perf_counter() - t0
        call("cold (fresh cache)", files[:1])
        call("warm (another file)", files[1:2])
        call("warm (4 files)", files[2:6])
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out


# --------------------------------------------------------------------------- report


def machine() -> dict:
    import jaxlib
    import scipy

    from tactile_jax.plotting import provenance

    dev = jax.devices()[0]
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count()
    return {"platform": platform.platform(), "machine": platform.machine(),
            "processor": platform.processor() or platform.machine(), "cpu_count": os.cpu_count(),
            "cpus_usable": usable, "load_avg_1_5_15": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
            "python": platform.python_version(), "jax": jax.__version__, "jaxlib": jaxlib.__version__,
            "numpy": np.__version__, "scipy": scipy.__version__, "backend": f"{dev.platform} ({dev.device_kind})",
            "x64": bool(jax.config.jax_enable_x64),
            "threads_env": {k: os.environ.get(k) for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "XLA_FLAGS")},
            "provenance": provenance()}


def _fmt_c(c):
    return f"{c['n']} ({c['compile_s']:.1f} s)"


def table(res: dict, args) -> str:
    m = res["machine"]
    one, chunk, cold = res["stages"]["one"], res["stages"]["chunk"], res["fit_recording_fresh_process"]
    n = args.chunk
    lines = [f"machine: {m['processor']}, {m['cpu_count']} CPUs ({m['cpus_usable']} usable), {m['platform']}, "
             f"Python {m['python']}, jax {m['jax']} (jaxlib {m['jaxlib']}, {m['backend']}), numpy {m['numpy']}, "
             f"scipy {m['scipy']}; load average at start {m['load_avg_1_5_15']}",
             f"records: 4 x {int(DURATION * FS)} samples at {FS:g} Hz, SNR {SNR_DB:g} dB; warm = median of "
             f"{args.repeats}; compiles = XLA backend compilations (seconds) in the phase", "",
             f"| stage | one: cold s | one: warm s | one: compiles cold / warm | chunk {n}: cold s | "
             f"chunk {n}: warm s | per record warm s | chunk: compiles cold / warm |",
             "|---|---|---|---|---|---|---|---|"]
    for st in STAGES:
        o = one.get(st)
        c = chunk.get(st)
        if st == "fit_recording":
            ocold = f"{cold['first_s']:.2f} (fresh process; {o['cold_s']:.2f} here)"
            ocomp = f"{_fmt_c(cold['compiles_first'])} fresh; {o['compiles_cold']['n']} here / {o['compiles_warm']['n']}"
        else:
            ocold = f"{o['cold_s']:.3f}"
            ocomp = f"{_fmt_c(o['compiles_cold'])} / {o['compiles_warm']['n']}"
        row = f"| {st} | {ocold} | {o['warm_s']:.4f} | {ocomp} | "
        if c is None:
            row += "n/a (the batch does not layer) | | | |"
        else:
            row += (f"{c['cold_s']:.3f} | {c['warm_s']:.4f} | {c['warm_s'] / n:.4f} | "
                    f"{_fmt_c(c['compiles_cold'])} / {c['compiles_warm']['n']} |")
        lines.append(row)
    fr = one["fit_recording"]
    lines += ["", f"fit_recording of record 0: status {fr['status']}, {fr['core_calls']} core calls per fit "
                  f"({fr['message'] or 'no message'}); staged prepare+solve+finish = core: one "
                  f"{one['staged_equals_core']}, chunk {chunk['staged_equals_core']}; chunk statuses "
                  f"{chunk['status']}"]
    pc = res.get("persistent_cache")
    if pc:
        lines += ["", f"persistent cache (`tactile-jax fit FILE --out X.json --quiet`, TACTILE_JAX_CACHE=<tmp>/jax; "
                      f"`import tactile_jax.cli` alone {pc['import_only_s']:.2f} s):", "",
                  "| run | files | wall s | exit | statuses | cache files after |", "|---|---|---|---|---|---|"]
        for e in pc["runs"]:
            lines.append(f"| {e['run']} | {e['files']} | {e['wall_s']:.2f} | {e['rc']} | {e['statuses']} | "
                         f"{e['cache_files']} (+{e['export_files']} export) |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("benchmarks/out"))
    ap.add_argument("--repeats", type=int, default=5, help="warm calls per stage (the median is reported)")
    ap.add_argument("--chunk", type=int, default=16, help="records in the batch chunk")
    ap.add_argument("--cold-fit", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.cold_fit:
        print(json.dumps(cold_fit(args.cold_fit)))
        return
    if args.repeats < 1 or args.chunk < 1:
        raise SystemExit("--repeats and --chunk must be at least 1")
    if jax.config.jax_compilation_cache_dir:
        print(f"note: a persistent compilation cache is set ({jax.config.jax_compilation_cache_dir}): cold times "
              "may be cache hits", file=sys.stderr)
    args.out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    res = {"machine": machine(), "settings": {"chunk": args.chunk, "repeats": args.repeats, "fs": FS,
                                              "duration_s": DURATION, "snr_db": SNR_DB,
                                              "scenes": [list(s) for s in SCENES]}}
    clean, _ = _scenes(args.out / "joint_speed_scenes.npz")
    comp = Compiles()
    jax.monitoring.register_event_duration_secs_listener(comp.listen)
    print("stages:", file=sys.stderr)
    res["stages"] = one_and_chunk(args, clean, comp)

    from tactile_jax.io import write_recording

    work = Path(tempfile.mkdtemp(prefix="tjx_speed_"))
    try:
        files = [write_recording(work / f"rec{j}.npz", _recording(_draw(clean, j), j)) for j in (0, 4, 5, 6, 7, 8)]
        print("fit_recording in a fresh process:", file=sys.stderr)
        proc = subprocess.run([sys.executable, __file__, "--cold-fit", str(files[0])], env=_clean_env(),
                              capture_output=True, text=True)
        if proc.returncode:
            raise SystemExit(f"the fresh-process fit failed:\n{proc.stderr[-3000:]}")
        res["fit_recording_fresh_process"] = json.loads(proc.stdout.strip().splitlines()[-1])
        print(f"  first {res['fit_recording_fresh_process']['first_s']:.2f} s, second "
              f"{res['fit_recording_fresh_process']['second_s']:.2f} s", file=sys.stderr)
        print("persistent cache:", file=sys.stderr)
        res["persistent_cache"] = persistent_cache(files, work)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    res["total_s"] = time.perf_counter() - t_start
    text = table(res, args)
    print(text)
    res["table"] = text
    path = args.out / "joint_speed.json"
    path.write_text(json.dumps(res, indent=1, default=str))
    print(f"\nwrote {path} ({res['total_s']:.0f} s in all)", file=sys.stderr)


if __name__ == "__main__":
    main()
