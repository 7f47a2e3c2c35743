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

Each stage's call runs under a watchdog: a call that does not return within
``--hang-timeout`` seconds (``--compile-timeout`` for one that compiles) ends its
process, the stage is reported as hung, and a fresh process goes on with the next
(jaxlib 0.10.2 on a 2-core CPU has deadlocked in the separately jitted, vmapped
``finish``; see ``run_stages``). The stages run in child processes without a
persistent compilation cache.

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
    from tactile_jax.simulation.scene import Scene, simulate
    from tactile_jax.simulation.texture import RandomTexture

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
    from tactile_jax.io.recording import Recording
    from tactile_jax.model.sensor import PAPER_SENSOR

    return Recording(signals=x, fs=FS, depths=(PAPER_SENSOR.d1, PAPER_SENSOR.d2),
                     curvature_radius=PAPER_SENSOR.curvature_radius, source=f"joint_speed record {j}")


# --------------------------------------------------------------------------- timing (a child process)


@contextlib.contextmanager
def _watch(seconds: float):
    """End the process (traceback on stderr) if the block runs longer than ``seconds``: a call that never
    returns (an XLA CPU deadlock, see ``run_stages``) must not stall the benchmark."""
    import faulthandler

    faulthandler.dump_traceback_later(seconds, exit=True)
    try:
        yield
    finally:
        faulthandler.cancel_dump_traceback_later()


def _stage_programs():
    """The stages ``core`` composes, as separate functions (same calls as ``core.core``)."""
    import jax.numpy as jnp

    from tactile_jax.inference import core as core_mod
    from tactile_jax.inference.solve import levenberg_marquardt

    def solve(prep, start):
        starts, free, skip = prep.starts, prep.free, False
        if start is not None:
            starts = jnp.where(start.use, start.theta.astype(starts.dtype), starts)
            free = jnp.where(start.use, start.free, free)
            skip = start.use
        n_first, n_start, n_final = core_mod.ITERATIONS
        out = levenberg_marquardt(core_mod.residuals_and_model, starts, (prep.data, None), free, prep.first,
                                  n_start=n_start, n_first=n_first, n_final=n_final, skip_starts=skip,
                                  n_explore=core_mod.OWN_STARTS["gaussian"], stop_tol=core_mod.STOP_TOL)
        return out, free

    def finish(rec, prep, free, out):
        b = prep.band
        return core_mod.finish(rec, prep.data, free, core_mod.Located(b.i0, b.n_leak, b.k0, b.speed0), *out)

    return core_mod.prepare, solve, finish


def _row(s):
    from tactile_jax.inference.result import result_from_summary
    from tactile_jax.inference.select import model_name

    return result_from_summary(s, model=model_name(s.free, False)).to_record()


#: the measurements in order: (target, stage)
ORDER = [(t, st) for t in ("one", "chunk") for st in STAGES if not (t == "chunk" and st == "fit_recording")]


class StageRunner:
    """Measures the stages in ``ORDER`` in this process, skipping those in ``done``; every stage's inputs are
    computed (untimed) where an earlier stage that would give them was skipped. The results so far go to
    ``partial`` (JSON) before and after each measurement, so a process ended by ``_watch`` leaves them."""

    def __init__(self, args, clean, comp: Compiles, partial: Path):
        from tactile_jax.inference import run
        from tactile_jax.inference.core import Settings, no_start
        from tactile_jax.model.sensor import PAPER_SENSOR

        self.args, self.clean, self.comp, self.partial = args, clean, comp, partial
        self.run, self.settings, self.no_start = run, Settings(), no_start
        self.depths = (PAPER_SENSOR.d1, PAPER_SENSOR.d2)
        self.state = json.loads(partial.read_text()) if partial.exists() else {"one": {}, "chunk": {}, "hung": []}
        self.memo = {}
        self.programs = dict(zip(("prepare", "solve", "finish"), _stage_programs()))

    def _save(self, current=None):
        self.state["current"] = current
        self.partial.write_text(json.dumps(self.state, default=str))

    # ---- inputs (memoised; a measured stage stores its output under the same name)
    def value(self, name):
        if name in self.memo:
            return self.memo[name]
        run, s, n = self.run, self.settings, self.args.chunk
        j = jax.jit
        make = {
            "one/x": lambda: _draw(self.clean, 0),
            "one/record": lambda: run.record(self.value("one/x"), FS, self.depths, settings=s),
            "one/rec_j": lambda: run._as_jnp(self.value("one/record")),
            "one/start_j": lambda: run._as_jnp(self.no_start()),
            "one/set-up": lambda: j(self.programs["prepare"])(self.value("one/rec_j"), s),
            "one/solve": lambda: j(self.programs["solve"])(self.value("one/set-up"), self.value("one/start_j")),
            "one/core": lambda: run.fit_one(self.value("one/record"), s),
            "chunk/x": lambda: [_draw(self.clean, k) for k in range(1, n + 1)],
            "chunk/record": lambda: [run.record(x, FS, self.depths, settings=s) for x in self.value("chunk/x")],
            "chunk/rec_j": lambda: run._as_jnp(jax.tree.map(lambda *v: np.stack(v), *self.value("chunk/record"))),
            "chunk/set-up": lambda: j(jax.vmap(self.programs["prepare"], in_axes=(0, None)))(
                self.value("chunk/rec_j"), s),
            "chunk/solve": lambda: j(jax.vmap(lambda p: self.programs["solve"](p, None)))(self.value("chunk/set-up")),
            "chunk/core": lambda: run.fit_many(self.value("chunk/record"), s, n),
        }
        self.memo[name] = make[name]()
        return self.memo[name]

    def _call(self, key, fn, args):
        """(cold entry, output, warm seconds): cold = the first call (compile included), warm = repeats."""
        cold_limit, hang = self.args.compile_timeout, self.args.hang_timeout
        with self.comp.phase(key + "/cold"):
            if hasattr(fn, "lower"):                   # a jitted stage: compile, then run under the hang watch
                t0 = time.perf_counter()
                with _watch(cold_limit):
                    fn = fn.lower(*args).compile()
                with _watch(hang):
                    out = jax.block_until_ready(fn(*args))
                cold = time.perf_counter() - t0
            else:
                with _watch(cold_limit):
                    t0 = time.perf_counter()
                    out = jax.block_until_ready(fn(*args))
                    cold = time.perf_counter() - t0
        warm = []
        with self.comp.phase(key + "/warm"):
            for _ in range(self.args.repeats):
                with _watch(hang):
                    t0 = time.perf_counter()
                    jax.block_until_ready(fn(*args))
                    warm.append(time.perf_counter() - t0)
        return cold, out, warm

    def measure(self, target, stage):
        key = f"{target}/{stage}"
        run, s, n = self.run, self.settings, self.args.chunk
        progs, v = self.programs, self.value
        if target == "one":
            calls = {
                "spectra": (lambda: run.record(v("one/x"), FS, self.depths, settings=s), ()),
                "set-up": (jax.jit(progs["prepare"]), lambda: (v("one/rec_j"), s)),
                "solve": (jax.jit(progs["solve"]), lambda: (v("one/set-up"), v("one/start_j"))),
                "finish": (jax.jit(progs["finish"]), lambda: (v("one/rec_j"), v("one/set-up"), v("one/solve")[1],
                                                             v("one/solve")[0])),
                "core": (run.fit_one, lambda: (v("one/record"), s)),
                "fit_recording": (None, None),
                "row": (_row, lambda: (v("one/core"),)),
            }
        else:
            calls = {
                "spectra": (lambda: [run.record(x, FS, self.depths, settings=s) for x in v("chunk/x")], ()),
                "set-up": (jax.jit(jax.vmap(progs["prepare"], in_axes=(0, None))), lambda: (v("chunk/rec_j"), s)),
                "solve": (jax.jit(jax.vmap(lambda p: progs["solve"](p, None))), lambda: (v("chunk/set-up"),)),
                "finish": (jax.jit(jax.vmap(progs["finish"])), lambda: (v("chunk/rec_j"), v("chunk/set-up"),
                                                                       v("chunk/solve")[1], v("chunk/solve")[0])),
                "core": (run.fit_many, lambda: (v("chunk/record"), s, n)),
                "row": (lambda summaries: [_row(q) for q in summaries], lambda: (v("chunk/core"),)),
            }
        if stage == "fit_recording":
            return self._fit_recording()
        fn, args = calls[stage]
        args = args() if callable(args) else args
        self._save(current=key)
        cold, out, warm = self._call(key, fn, args)
        self.memo[{"spectra": f"{target}/record"}.get(stage, key)] = out
        entry = {"cold_s": cold, "warm_s": statistics.median(warm), "warm_all_s": warm,
                 "compiles_cold": self.comp.of(key + "/cold"), "compiles_warm": self.comp.of(key + "/warm")}
        if stage == "finish":
            core = self.memo.get(f"{target}/core")
            entry["theta_equals_core"] = None if core is None else self._same(out, core)
        if stage == "core":
            fin = self.memo.get(f"{target}/finish")
            entry["theta_equals_staged"] = None if fin is None else self._same(fin, out)
        if stage == "row":
            rows = out if isinstance(out, list) else [out]
            entry["statuses"] = dict(collections.Counter(r["status"] for r in rows))
        self._done(key, entry)

    @staticmethod
    def _same(staged, core):
        theta = np.stack([q.theta for q in core]) if isinstance(core, list) else np.asarray(core.theta)
        return bool(np.allclose(np.asarray(staged.theta), theta, rtol=1e-8, atol=1e-10))

    def _fit_recording(self):
        """``fit_recording`` of record 0, counting the core calls its layers make (refits go through fit_one)."""
        from tactile_jax.inference.options import FitOptions
        from tactile_jax.inference.fit import fit_recording

        key = "one/fit_recording"
        run = self.run
        calls = collections.Counter()
        orig = run.fit_one

        def counting(*a, **kw):
            calls["n"] += 1
            return orig(*a, **kw)

        recording = _recording(self.value("one/x"), 0)
        self._save(current=key)
        run.fit_one = counting
        try:
            cold, res, warm = self._call(key, fit_recording, (recording, FitOptions()))
        finally:
            run.fit_one = orig
        entry = {"cold_s": cold, "warm_s": statistics.median(warm), "warm_all_s": warm,
                 "compiles_cold": self.comp.of(key + "/cold"), "compiles_warm": self.comp.of(key + "/warm"),
                 "core_calls": calls["n"] // (self.args.repeats + 1), "status": res.status, "message": res.message}
        self._done(key, entry)

    def _done(self, key, entry):
        target, stage = key.split("/")
        self.state[target][stage] = entry
        self._save()
        c = entry["compiles_cold"]
        print(f"  {key:24s} cold {entry['cold_s']:8.3f} s  warm {entry['warm_s']:8.4f} s  compiles {c['n']} "
              f"({c['compile_s']:.1f} s) / {entry['compiles_warm']['n']}", file=sys.stderr, flush=True)

    def run_all(self):
        for target, stage in ORDER:
            key = f"{target}/{stage}"
            if stage in self.state[target] or key in self.state["hung"]:
                continue
            self.measure(target, stage)
        self._save()


def stages_child(args) -> None:
    """(--stages-child) measure the stages not yet in the partial file, in this fresh process."""
    comp = Compiles()
    jax.monitoring.register_event_duration_secs_listener(comp.listen)
    clean, _ = _scenes(args.out / "joint_speed_scenes.npz")
    StageRunner(args, clean, comp, Path(args.stages_child)).run_all()


def run_stages(args, partial: Path) -> dict:
    """Every stage, in child processes: a call that does not return within ``--hang-timeout`` s (compiles:
    ``--compile-timeout``) ends its process; that stage is marked hung and a fresh process goes on with the
    next. (jaxlib 0.10.2 on a 2-core CPU: the separately jitted, vmapped ``finish`` has deadlocked in
    ``block_until_ready`` with both intra-op threads waiting in batched LAPACK kernels, ``ParallelBatchMap``.)"""
    partial.unlink(missing_ok=True)
    for attempt in range(len(ORDER)):
        cmd = [sys.executable, __file__, "--stages-child", str(partial), "--out", str(args.out), "--repeats",
               str(args.repeats), "--chunk", str(args.chunk), "--hang-timeout", str(args.hang_timeout),
               "--compile-timeout", str(args.compile_timeout)]
        proc = subprocess.run(cmd, env=_clean_env(), stderr=subprocess.PIPE, text=True)
        sys.stderr.write("".join(line + "\n" for line in proc.stderr.splitlines()
                                 if line.startswith("  ") and "Warning" not in line))
        state = json.loads(partial.read_text()) if partial.exists() else None
        if proc.returncode == 0 and state is not None:
            return state
        if state is None or not state.get("current") or "Timeout (" not in proc.stderr:
            raise SystemExit(f"the stage process failed:\n{proc.stderr[-3000:]}")
        print(f"  {state['current']}: no result within the time limit (process ended, exit {proc.returncode}); "
              "going on in a fresh process", file=sys.stderr)
        state["hung"].append(state["current"])
        state["current"] = None
        partial.write_text(json.dumps(state))
    raise SystemExit("too many stage processes ended")


# --------------------------------------------------------------------------- subprocesses


def _clean_env(**extra):
    env = dict(os.environ)
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    env.update(extra)
    return env


def _timed(fn, *args):
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    return time.perf_counter() - t0, out


def cold_fit(path: str, limit: float) -> dict:
    """(--cold-fit) ``fit_recording`` twice in this fresh process, no persistent cache: JSON on stdout."""
    comp = Compiles()
    jax.monitoring.register_event_duration_secs_listener(comp.listen)
    t0 = time.perf_counter()
    from tactile_jax.inference.options import FitOptions
    from tactile_jax.inference.fit import fit_recording
    from tactile_jax.io.files import read_recording

    rec = read_recording(path)
    t_import = time.perf_counter() - t0
    with comp.phase("first"), _watch(limit):
        t1, res = _timed(fit_recording, rec, FitOptions())
    with comp.phase("second"), _watch(limit):
        t2, _ = _timed(fit_recording, rec, FitOptions())
    return {"import_read_s": t_import, "first_s": t1, "second_s": t2, "status": res.status,
            "compiles_first": comp.of("first"), "compiles_second": comp.of("second"),
            "cache_dir": jax.config.jax_compilation_cache_dir}


def _cli() -> list[str]:
    exe = shutil.which("tactile-jax")
    return [exe] if exe else [sys.executable, "-c", "from tactile_jax.cli import main; main()"]


def _files_in(folder: Path) -> int:
    return sum(1 for p in folder.rglob("*") if p.is_file()) if folder.exists() else 0


def persistent_cache(files: list[Path], work: Path, limit: float) -> dict:
    """Wall seconds of ``tactile-jax fit`` with a fresh persistent cache, the warm cache, and 4 files."""
    tmp = Path(tempfile.mkdtemp(prefix="tjx_cache_"))
    cache = tmp / "jax"                  # the CLI writes its jax.export file beside it (tmp / "export")
    env = _clean_env(TACTILE_JAX_CACHE=str(cache))
    out = {"cache_dir": "<tmp>/jax", "runs": []}

    def call(name, paths):
        dest = work / f"cli_{name}.json"
        cmd = _cli() + ["fit", *map(str, paths), "--out", str(dest), "--quiet"]
        t0 = time.perf_counter()
        try:
            proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=limit)
        except subprocess.TimeoutExpired as exc:
            proc = subprocess.CompletedProcess(cmd, "timeout", "", str(exc))
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
        subprocess.run([sys.executable, "-c", "import tactile_jax.cli, tactile_jax.inference.fit"], env=env, check=True)
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

    from tactile_jax.viz.figures import provenance

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
    st_all, cold = res["stages"], res.get("fit_recording_fresh_process") or {}
    one, chunk, hung = st_all["one"], st_all["chunk"], set(st_all.get("hung", []))
    n = args.chunk
    lines = [f"machine: {m['processor']}, {m['cpu_count']} CPUs ({m['cpus_usable']} usable), {m['platform']}, "
             f"Python {m['python']}, jax {m['jax']} (jaxlib {m['jaxlib']}, {m['backend']}), numpy {m['numpy']}, "
             f"scipy {m['scipy']}; load average at start {m['load_avg_1_5_15']}, at end {res.get('load_avg_end')}",
             f"records: {int(DURATION * FS)} samples x 4 at {FS:g} Hz, SNR {SNR_DB:g} dB; cold = first call in the "
             f"process (compile included); warm = median of {args.repeats}; compiles = XLA backend compilations "
             "(their seconds) in the phase", "",
             f"| stage | one: cold s | one: warm s | one: compiles cold / warm | chunk {n}: cold s | "
             f"chunk {n}: warm s | per record warm s | chunk: compiles cold / warm |",
             "|---|---|---|---|---|---|---|---|"]

    def cells(target, st, e):
        if e is None:
            if f"{target}/{st}" in hung:
                return [f"hung (no result in {args.hang_timeout:g} s)", "-", "-"]
            return ["-", "-", "-"]
        return [f"{e['cold_s']:.3f}", f"{e['warm_s']:.4f}", f"{_fmt_c(e['compiles_cold'])} / {e['compiles_warm']['n']}"]

    for st in STAGES:
        o = cells("one", st, one.get(st))
        if st == "fit_recording" and cold.get("first_s") is not None and one.get(st):
            o[0] = f"{cold['first_s']:.2f} fresh process ({one[st]['cold_s']:.2f} here)"
            o[2] = (f"{_fmt_c(cold['compiles_first'])} fresh; {one[st]['compiles_cold']['n']} here / "
                    f"{one[st]['compiles_warm']['n']}")
        if st == "fit_recording":
            c = ["n/a (the batch does not layer)", "", "", ""]
        else:
            c = cells("chunk", st, chunk.get(st))
            e = chunk.get(st)
            c.insert(2, f"{e['warm_s'] / n:.4f}" if e else "-")
        lines.append(f"| {st} | " + " | ".join(o + c) + " |")
    fr = one.get("fit_recording") or {}
    lines += ["", f"fit_recording of record 0: status {fr.get('status')}, {fr.get('core_calls')} core calls per fit "
                  f"({fr.get('message') or 'no message'}); staged prepare + solve + finish give core's theta: one "
                  f"{(one.get('core') or {}).get('theta_equals_staged')}, chunk "
                  f"{(chunk.get('core') or {}).get('theta_equals_staged')}; statuses: one "
                  f"{(one.get('row') or {}).get('statuses')}, chunk {(chunk.get('row') or {}).get('statuses')}"]
    if hung:
        lines.append(f"hung: {sorted(hung)} (a call that did not return; its process was ended and a fresh one "
                     "went on; see run_stages)")
    pc = res.get("persistent_cache")
    if pc:
        lines += ["", f"persistent cache (`tactile-jax fit FILE --out X.json --quiet`, TACTILE_JAX_CACHE=<tmp>/jax; "
                      f"`import tactile_jax.cli, tactile_jax.inference.fit` alone {pc['import_only_s']:.2f} s):", "",
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
    ap.add_argument("--hang-timeout", type=float, default=120.0,
                    help="seconds a compiled call may run before it counts as hung (its process is ended)")
    ap.add_argument("--compile-timeout", type=float, default=900.0, help="the same for a call that compiles")
    ap.add_argument("--cold-fit", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--stages-child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.cold_fit:
        print(json.dumps(cold_fit(args.cold_fit, args.compile_timeout)))
        return
    if args.stages_child:
        stages_child(args)
        return
    if args.repeats < 1 or args.chunk < 1:
        raise SystemExit("--repeats and --chunk must be at least 1")
    if os.environ.get("JAX_COMPILATION_CACHE_DIR"):
        print("note: JAX_COMPILATION_CACHE_DIR is set; the benchmark's processes run without it", file=sys.stderr)
    args.out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    res = {"machine": machine(), "settings": {"chunk": args.chunk, "repeats": args.repeats, "fs": FS,
                                              "duration_s": DURATION, "snr_db": SNR_DB,
                                              "scenes": [list(s) for s in SCENES]}}
    clean, _ = _scenes(args.out / "joint_speed_scenes.npz")
    print("stages (one record, then the chunk):", file=sys.stderr)
    res["stages"] = run_stages(args, args.out / "joint_speed_partial.json")

    from tactile_jax.io.files import write_recording

    work = Path(tempfile.mkdtemp(prefix="tjx_speed_"))
    try:
        files = [write_recording(work / f"rec{j}.npz", _recording(_draw(clean, j), j)) for j in (0, 4, 5, 6, 7, 8)]
        print("fit_recording in a fresh process:", file=sys.stderr)
        try:
            proc = subprocess.run([sys.executable, __file__, "--cold-fit", str(files[0]), "--compile-timeout",
                                   str(args.compile_timeout)], env=_clean_env(), capture_output=True, text=True,
                                  timeout=args.compile_timeout + 60)
            if proc.returncode:
                print(f"  the fresh-process fit failed:\n{proc.stderr[-2000:]}", file=sys.stderr)
                res["fit_recording_fresh_process"] = {"error": proc.stderr[-2000:]}
            else:
                res["fit_recording_fresh_process"] = json.loads(proc.stdout.strip().splitlines()[-1])
                print(f"  first {res['fit_recording_fresh_process']['first_s']:.2f} s, second "
                      f"{res['fit_recording_fresh_process']['second_s']:.2f} s", file=sys.stderr)
        except subprocess.TimeoutExpired:
            res["fit_recording_fresh_process"] = {"error": "timeout"}
        print("persistent cache:", file=sys.stderr)
        res["persistent_cache"] = persistent_cache(files, work, args.compile_timeout)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    res["total_s"] = time.perf_counter() - t_start
    res["load_avg_end"] = [round(v, 2) for v in os.getloadavg()] if hasattr(os, "getloadavg") else None
    text = table(res, args)
    print(text)
    res["table"] = text
    path = args.out / "joint_speed.json"
    path.write_text(json.dumps(res, indent=1, default=str))
    (args.out / "joint_speed_partial.json").unlink(missing_ok=True)
    print(f"\nwrote {path} ({res['total_s']:.0f} s in all)", file=sys.stderr)


if __name__ == "__main__":
    main()
