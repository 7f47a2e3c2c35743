"""Memory of one ``fit`` process across many same-shape files: peak RSS, RSS after each file, compilations.

For each N of ``--sizes`` a fresh process fits N recordings (16 s at 1 kHz, 4 x
16000 samples, all one shape):

- cli: ``tactile-jax fit f000.h5 ... --out rows.csv``, the command as a user runs
  it. This script reads the command's progress lines on stderr (``[n/N] file``,
  then ``wrote ...``) and samples the child's VmRSS (``/proc/<pid>/status``) at
  each one: the RSS after file n-1 is the RSS when file n starts. Peak RSS:
  the child's ``ru_maxrss`` (``os.wait4``).
- loop: ``fit_recording`` file after file in a Python child that imports
  ``tactile_jax.cli`` first (the same float64 and cache settings), keeps each
  result's row as the command does and, after each file, records VmRSS,
  the XLA compilations and other ``jax.monitoring`` events of that file (traces,
  lowerings, persistent-cache hits), the live jax arrays and, after
  ``gc.collect()``, the objects the collector tracks and the live ``FitResult``s.

The persistent compilation cache is a fresh folder for this run
(``TACTILE_JAX_CACHE``): the first process (``cli, fresh cache``) compiles the
pipeline and fills it; the others load it, as a user's second run does. Growth
per file = (RSS after the last file - RSS after the first) / (N - 1).

Recordings: ``SCENES`` (random texture, Gaussian window) are simulated once
without noise and cached in ``--out``; file j is scene j % 4 plus white noise at
40 dB seeded by j, so that N files are N distinct same-shape records without
simulating each (4 x 2 s instead of 100 x 2 s). The files are written once under
``--out/memory_files`` and reused.

    python benchmarks/memory.py --out benchmarks/out            # N = 1, 10, 100: about 4-5 min on 2 cores
    python benchmarks/memory.py --quick --out /tmp/mem          # N = 1, 4, 12: about 1.5 min
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import platform
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

FS = 1000.0
DURATION = 16.0
SNR_DB = 40.0
#: (vx, vy) m/s, a m, seed of the scenes the files are drawn from (as ``joint_speed.py``'s)
SCENES = (((0.030, 0.006), 1.5e-3, 11), ((0.023, 0.0), 3.0e-3, 12), ((0.020, 0.020), 1.0e-3, 13),
          ((0.050, 0.015), 2.0e-3, 14))
COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"
MB = 1024.0 ** 2


# --------------------------------------------------------------------------- recordings


def _scenes(path: Path):
    """Noiseless signals (S, 4, N) of ``SCENES``, simulated once and cached in ``path``."""
    import numpy as np

    if path.exists():
        return np.load(path)["clean"]
    import jax

    jax.config.update("jax_enable_x64", True)
    from tactile_jax.simulation.scene import Scene, simulate

    clean = []
    for (vx, vy), a, seed in SCENES:
        t0 = time.perf_counter()
        rec = simulate(Scene(velocity=(vx, vy), contact_radius=a, snr_db=None, duration=DURATION, fs=FS, seed=seed))
        print(f"  simulated v = ({100 * vx:.1f}, {100 * vy:.1f}) cm/s, a = {1e3 * a:.1f} mm in "
              f"{time.perf_counter() - t0:.1f} s", file=sys.stderr)
        clean.append(np.asarray(rec.signals, float))
    clean = np.stack(clean)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, clean=clean)
    return clean


def recordings(out: Path, n: int) -> list[Path]:
    """Paths of files 0 .. n-1 (``out/memory_files/f{j:03d}.h5``), written where missing."""
    folder = out / "memory_files"
    paths = [folder / f"f{j:03d}.h5" for j in range(n)]
    missing = [j for j, p in enumerate(paths) if not p.exists()]
    if missing:
        import numpy as np

        from tactile_jax.io.files import write_recording
        from tactile_jax.io.recording import Recording
        from tactile_jax.model.sensor import PAPER_SENSOR

        clean = _scenes(out / "memory_scenes.npz")
        folder.mkdir(parents=True, exist_ok=True)
        for j in missing:
            x = clean[j % len(clean)]
            sigma = np.sqrt(max(np.mean(x[0] ** 2), np.mean(x[2] ** 2))) * 10 ** (-SNR_DB / 20)
            x = x + sigma * np.random.default_rng(70_000 + j).standard_normal(x.shape)
            write_recording(paths[j], Recording(signals=x, fs=FS, depths=(PAPER_SENSOR.d1, PAPER_SENSOR.d2),
                                                curvature_radius=PAPER_SENSOR.curvature_radius))
    return paths


# --------------------------------------------------------------------------- measuring a child


def _status(pid) -> dict:
    """VmRSS and VmHWM (bytes) of process ``pid`` (``self`` for this one); {} once it has gone."""
    out = {}
    try:
        with open(f"/proc/{pid}/status") as fh:
            for line in fh:
                if line.startswith(("VmRSS:", "VmHWM:")):
                    key, value = line.split(":")
                    out[key] = int(value.split()[0]) * 1024
    except OSError:
        pass
    return out


def _cli() -> list[str]:
    exe = shutil.which("tactile-jax")
    return [exe] if exe else [sys.executable, "-c", "from tactile_jax.cli import main; main()"]


def _wait(proc: subprocess.Popen) -> tuple[int, int]:
    """(exit status, peak RSS in bytes) of a finished child, from ``os.wait4``."""
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    return proc.returncode, usage.ru_maxrss * 1024          # Linux: kilobytes


def run_cli(files: list[Path], rows: Path, env: dict, limit: float) -> dict:
    """``tactile-jax fit FILES --out rows``: RSS after each file (sampled at its progress lines), peak, wall."""
    cmd = _cli() + ["fit", *map(str, files), "--out", str(rows)]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    after, at, tail = {}, {}, []
    watchdog = threading.Timer(limit, proc.kill)
    watchdog.start()
    for line in proc.stderr:
        now = time.perf_counter()
        tail = (tail + [line])[-20:]
        m = re.match(r"\[(\d+)/(\d+)\]", line)
        done = int(m.group(1)) - 1 if m else (len(files) if line.startswith("wrote ") else None)
        if done:
            after[done] = _status(proc.pid).get("VmRSS")
            at[done] = now - t0
    watchdog.cancel()
    code, peak = _wait(proc)
    wall = time.perf_counter() - t0
    rss = [after.get(k) for k in range(1, len(files) + 1)]
    ends = [at.get(k) for k in range(1, len(files) + 1)]
    per_file = [b - a for a, b in zip(ends[:-1], ends[1:]) if a is not None and b is not None]
    out = {"rc": code, "peak_rss": peak, "rss_after": rss, "wall_s": wall,
           "file_s_median": statistics.median(per_file) if per_file else None}
    if code:
        out["stderr"] = "".join(tail)
    return out


def run_loop(files: list[Path], env: dict, limit: float) -> dict:
    """``fit_recording`` file after file in a child (``--loop-child``): its per-file log, peak, wall."""
    t0 = time.perf_counter()
    with tempfile.NamedTemporaryFile("w+", suffix=".txt") as lst:
        lst.write("\n".join(map(str, files)))
        lst.flush()
        proc = subprocess.Popen([sys.executable, __file__, "--loop-child", lst.name], env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            stdout, stderr = proc.communicate(timeout=limit)
        except subprocess.TimeoutExpired:
            proc.kill()
            stdout, stderr = proc.communicate()
    log = [json.loads(line) for line in stdout.splitlines() if line.startswith("{")]
    out = {"rc": proc.returncode, "peak_rss": max((e["hwm"] for e in log), default=None),
           "rss_after": [e["rss"] for e in log], "wall_s": time.perf_counter() - t0,
           "file_s_median": statistics.median(e["seconds"] for e in log[1:]) if len(log) > 1 else None,
           "files": log}
    if proc.returncode:
        out["stderr"] = stderr[-3000:]
    return out


def loop_child(listing: str) -> None:
    """(--loop-child) Fit the files named in ``listing``; one JSON line per file on stdout."""
    import collections

    import jax

    import tactile_jax.cli  # noqa: F401  (float64 and the persistent cache, as the command sets them)
    from tactile_jax.inference.result import FitResult
    from tactile_jax.inference.fit import fit_recording
    from tactile_jax.io.files import read_recording

    events = collections.Counter()

    def listen(event, *_, **__):
        if event.startswith("/jax/"):
            events["compile" if event == COMPILE_EVENT else event.rsplit("/", 1)[-1]] += 1

    jax.monitoring.register_event_duration_secs_listener(listen)
    jax.monitoring.register_event_listener(listen)
    rows = []
    for k, path in enumerate([p for p in Path(listing).read_text().splitlines() if p], 1):
        events.clear()
        t0 = time.perf_counter()
        res = fit_recording(read_recording(path))
        rows.append(res.to_record())
        seconds = time.perf_counter() - t0
        del res
        st = _status("self")
        gc.collect()
        objects = gc.get_objects()
        entry = {"file": k, "seconds": seconds, "rss": st["VmRSS"], "hwm": st["VmHWM"],
                 "compiles": events.pop("compile", 0), "other_jax_events": dict(events),
                 "live_arrays": len(jax.live_arrays()), "gc_objects": len(objects),
                 "fit_results": sum(isinstance(o, FitResult) for o in objects), "status": rows[-1]["status"]}
        del objects
        print(json.dumps(entry), flush=True)


# --------------------------------------------------------------------------- report


def machine() -> dict:
    import jax
    import jaxlib
    import numpy as np
    import scipy

    from tactile_jax import __version__

    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count()
    return {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
            "cpu_count": os.cpu_count(), "cpus_usable": usable, "memory_total_gb": _mem_total_gb(),
            "load_avg_1_5_15": [round(v, 2) for v in os.getloadavg()], "python": platform.python_version(),
            "tactile_jax": __version__, "jax": jax.__version__, "jaxlib": jaxlib.__version__,
            "numpy": np.__version__, "scipy": scipy.__version__, "glibc": "-".join(platform.libc_ver())}


def _mem_total_gb():
    try:
        with open("/proc/meminfo") as fh:
            return round(int(fh.readline().split()[1]) / 1024 ** 2, 1)
    except (OSError, ValueError, IndexError):
        return None


def summarise(run: dict) -> dict:
    """Peak, RSS after the first file, growth per file after it (MB), from a run's measurements."""
    rss = [r for r in run["rss_after"] if r is not None]
    n = len(run["rss_after"])
    first = run["rss_after"][0] if run["rss_after"] else None
    last = run["rss_after"][-1] if run["rss_after"] else None
    growth = (last - first) / (n - 1) / MB if (n > 1 and first is not None and last is not None) else None
    return {"peak_mb": run["peak_rss"] / MB if run.get("peak_rss") else None,
            "first_mb": first / MB if first is not None else None,
            "max_after_mb": max(rss) / MB if rss else None, "growth_mb_per_file": growth}


def table(res: dict) -> str:
    m = res["machine"]
    lines = [f"machine: {m['processor']}, {m['cpu_count']} CPUs ({m['cpus_usable']} usable), {m['memory_total_gb']} GB, "
             f"{m['platform']}, Python {m['python']}, tactile_jax {m['tactile_jax']}, jax {m['jax']} (jaxlib "
             f"{m['jaxlib']}), numpy {m['numpy']}, scipy {m['scipy']}; load average at start {m['load_avg_1_5_15']}, "
             f"at end {res.get('load_avg_end')}",
             f"files: {int(DURATION * FS)} samples x 4 at {FS:g} Hz, {SNR_DB:g} dB; RSS in MB (1 MB = 2^20 bytes); "
             "growth per file = (RSS after the last - after the first) / (N - 1); s/file: median after the first",
             "",
             "| run | N | peak RSS | RSS after file 1 | highest RSS after a file | growth per file | wall s | s/file | exit |",
             "|---|---|---|---|---|---|---|---|---|"]

    def f(v, fmt):
        return "-" if v is None else format(v, fmt)

    for run in res["runs"]:
        s = run["summary"]
        lines.append(f"| {run['name']} | {run['n']} | {f(s['peak_mb'], '.0f')} | {f(s['first_mb'], '.0f')} | "
                     f"{f(s['max_after_mb'], '.0f')} | {f(s['growth_mb_per_file'], '+.2f')} | {run['wall_s']:.1f} | "
                     f"{f(run['file_s_median'], '.2f')} | {run['rc']} |")
    loop = next((r for r in res["runs"] if r["name"].startswith("loop") and r.get("files")), None)
    if loop:
        log = loop["files"]
        later = log[1:]
        lines += ["", f"loop, per file (N = {loop['n']}): XLA compilations {[e['compiles'] for e in log[:4]]}"
                      f"{' ...' if len(log) > 4 else ''} ({sum(e['compiles'] for e in later)} after the first file); "
                      f"other jax events after the first: {sum(sum(e['other_jax_events'].values()) for e in later)}; "
                      f"live jax arrays {log[0]['live_arrays']} -> {log[-1]['live_arrays']}; objects tracked by gc "
                      f"{log[0]['gc_objects']} -> {log[-1]['gc_objects']}; live FitResults after the last "
                      f"{log[-1]['fit_results']}; statuses {dict(_count(e['status'] for e in log))}"]
    return "\n".join(lines)


def _count(items):
    import collections

    return collections.Counter(items)


def figure(res: dict, path: Path) -> Path | None:
    try:
        from tactile_jax.viz.figures import pyplot, save_figure
        plt = pyplot()
    except Exception as err:  # noqa: BLE001 - the figure is an extra
        print(f"no figure: {err}", file=sys.stderr)
        return None
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for run in res["runs"]:
        rss = run["rss_after"]
        if len(rss) < 2:
            continue
        x = [k for k, r in enumerate(rss, 1) if r is not None]
        y = [r / MB for r in rss if r is not None]
        line, = ax.plot(x, y, marker="." if len(x) < 30 else None, label=f"{run['name']}, N = {run['n']}")
        if run.get("peak_rss"):
            ax.axhline(run["peak_rss"] / MB, color=line.get_color(), lw=0.8, ls=":")
    ax.set_xlabel("file number")
    ax.set_ylabel("RSS after the file, MB (dotted: the process's peak)")
    ax.set_title("tactile-jax fit: memory across same-shape files (16 s at 1 kHz each)")
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=8)
    return save_figure(fig, path)


# --------------------------------------------------------------------------- main


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("benchmarks/out"))
    ap.add_argument("--sizes", default="1,10,100", help="numbers of files, one fresh process each (comma-separated)")
    ap.add_argument("--loop", type=int, default=None, help="files in the fit_recording loop (default: the largest size; 0: none)")
    ap.add_argument("--quick", action="store_true", help="sizes 1, 4, 12")
    ap.add_argument("--limit", type=float, default=900.0, help="seconds one child may run")
    ap.add_argument("--loop-child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.loop_child:
        loop_child(args.loop_child)
        return
    sizes = [1, 4, 12] if args.quick else sorted({int(s) for s in args.sizes.split(",")})
    if not sizes or min(sizes) < 1:
        raise SystemExit("--sizes must be whole numbers >= 1")
    n_loop = max(sizes) if args.loop is None else args.loop
    args.out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    res = {"machine": machine(), "settings": {"sizes": sizes, "loop": n_loop, "fs": FS, "duration_s": DURATION,
                                              "snr_db": SNR_DB, "scenes": [list(s) for s in SCENES]}}
    files = recordings(args.out, max(sizes + [n_loop]))
    cache = Path(tempfile.mkdtemp(prefix="tjx_memory_"))
    env = dict(os.environ, TACTILE_JAX_CACHE=str(cache / "jax"))
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    plan = [("cli, fresh cache", "cli", sizes[1] if len(sizes) > 1 else sizes[0])]
    plan += [("cli", "cli", n) for n in sizes]
    if n_loop:
        plan.append(("loop (fit_recording)", "loop", n_loop))
    res["runs"] = []
    try:
        for name, kind, n in plan:
            print(f"{name}, N = {n} ...", file=sys.stderr, flush=True)
            if kind == "cli":
                run = run_cli(files[:n], cache / f"rows_{n}.csv", env, args.limit)
            else:
                run = run_loop(files[:n], env, args.limit)
            run.update(name=name, n=n)
            run["summary"] = summarise(run)
            res["runs"].append(run)
            s = run["summary"]
            print(f"  peak {s['peak_mb']:.0f} MB, after file 1 {s['first_mb'] or float('nan'):.0f} MB, growth "
                  f"{s['growth_mb_per_file'] if s['growth_mb_per_file'] is not None else float('nan'):+.2f} MB/file, "
                  f"{run['wall_s']:.1f} s, exit {run['rc']}", file=sys.stderr, flush=True)
            if run["rc"]:
                print(run.get("stderr", ""), file=sys.stderr)
    finally:
        shutil.rmtree(cache, ignore_errors=True)
    res["total_s"] = time.perf_counter() - t_start
    res["load_avg_end"] = [round(v, 2) for v in os.getloadavg()]
    text = table(res)
    print(text)
    res["table"] = text
    path = args.out / "memory.json"
    path.write_text(json.dumps(res, indent=1, default=str))
    fig = figure(res, args.out / "memory.png")
    print(f"\nwrote {path}{' and ' + str(fig) if fig else ''} ({res['total_s']:.0f} s in all)", file=sys.stderr)


if __name__ == "__main__":
    main()
