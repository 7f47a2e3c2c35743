"""Where the time of one joint fit goes (issue 5): spectra, compile, solve, bounds, posterior.

Wraps the calls that ``fit.fit_recording`` makes (without changing them) with
timers that block on their results, and listens to JAX's compile events, so
each stage is charged its own wall time; the first fit of a shape pays the
compilations, the next ones show the steady state. Then times an emcee run on
the fit's problem. Prints a table, writes ``profile_stages.json``.

    python benchmarks/profile_stages.py --out benchmarks/out            # ~3-6 min on 2 cores
    python benchmarks/profile_stages.py --duration 8 --repeats 1        # smaller
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import json
import platform
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from tactile_jax import fit as fit_mod  # noqa: E402
from tactile_jax.fit import FitOptions, fit_recording  # noqa: E402
from tactile_jax.plotting import provenance  # noqa: E402
from tactile_jax.posterior import run_emcee  # noqa: E402
from tactile_jax.scene import Scene, simulate  # noqa: E402
from tactile_jax.texture import RandomTexture  # noqa: E402

#: the calls of ``fit`` that are timed (module attribute names)
STAGES = ("estimate_spectra", "_resolution_nperseg", "amplitude_ratio", "usable_band", "fit_pair", "least_squares",
          "_profile_bound", "_texture_sections")


class Profiler:
    """Accumulates wall time per label; nested timers are charged to the innermost label only."""

    def __init__(self):
        self.total = collections.defaultdict(float)
        self.calls = collections.Counter()
        self.compile_s = collections.defaultdict(float)
        self.steps = collections.defaultdict(list)
        self.converged = collections.defaultdict(list)
        self._stack: list[str] = []
        self._child = [0.0]

    @contextlib.contextmanager
    def stage(self, label):
        self._stack.append(label)
        self._child.append(0.0)
        t0 = time.perf_counter()
        try:
            yield
        finally:
            dt = time.perf_counter() - t0
            child = self._child.pop()
            self._stack.pop()
            self.total[label] += dt - child
            self.calls[label] += 1
            self._child[-1] += dt

    def on_event(self, event, duration, **_):
        if "compile" in event or "trace" in event or "lower" in event:
            where = self._stack[-1] if self._stack else "(outside)"
            self.compile_s[(where, event.rsplit("/", 1)[-1])] += duration

    def reset(self):
        self.total.clear()
        self.calls.clear()
        self.compile_s.clear()
        self.steps.clear()
        self.converged.clear()


def _blocked(fn, prof: Profiler, label: str):
    def wrapper(*args, **kw):
        with prof.stage(label):
            out = fn(*args, **kw)
            return jax.block_until_ready(out) if label in ("least_squares", "estimate_spectra",
                                                           "amplitude_ratio", "usable_band") else out
    return wrapper


def _label_least_squares(fn, prof: Profiler):
    """least_squares is called from three places: stage-1 texture fit, full fit, profile bounds."""
    def wrapper(residuals, theta0, data, free, **kw):
        free_np = np.asarray(free)
        if "_profile_bound" in prof._stack:
            label = "least_squares (profile bound)"
        elif not free_np[:3].any():
            label = "least_squares (stage 1: texture only)"
        else:
            label = "least_squares (full joint fit)"
        with prof.stage(label):
            out = jax.block_until_ready(fn(residuals, theta0, data, free, **kw))
        prof.steps[label].append(int(out.n_steps))
        prof.converged[label].append(bool(out.converged))
        return out
    return wrapper


def install(prof: Profiler):
    for name in STAGES:
        orig = getattr(fit_mod, name)
        if name == "least_squares":
            setattr(fit_mod, name, _label_least_squares(orig, prof))
        else:
            setattr(fit_mod, name, _blocked(orig, prof, name))
    jax.monitoring.register_event_duration_secs_listener(prof.on_event)


def scenes(duration):
    return [
        ("slip along x, a = 3 mm", Scene(texture=RandomTexture(), velocity=(0.023, 0.0), contact_radius=3e-3,
                                           duration=duration, snr_db=40.0, seed=11)),
        ("oblique 3+1 cm/s, a = 1.5 mm", Scene(texture=RandomTexture(), velocity=(0.03, 0.01), contact_radius=1.5e-3,
                                                duration=duration, snr_db=40.0, seed=12)),
    ]


def _rows(prof: Profiler, wall: float):
    rows = []
    for label, t in sorted(prof.total.items(), key=lambda kv: -kv[1]):
        comp = sum(v for (w, ev), v in prof.compile_s.items() if w == label and ev.endswith("backend_compile_duration"))
        rows.append({"stage": label, "calls": prof.calls[label], "seconds": t, "share": t / wall,
                     "of_which_backend_compile_s": comp, "lm_steps": prof.steps.get(label, []),
                     "converged": prof.converged.get(label, [])})
    return rows


def _print(title, rows, wall):
    print(f"\n{title}  (wall {wall:.2f} s)")
    print(f"{'stage':42s} {'calls':>5s} {'seconds':>8s} {'share':>6s} {'compile':>8s}  LM steps (converged)")
    for r in rows:
        steps = " ".join(f"{n}{'' if c else '!'}" for n, c in zip(r.get("lm_steps", []), r.get("converged", [])))
        print(f"{r['stage']:42s} {r['calls']:5d} {r['seconds']:8.2f} {100 * r['share']:5.1f}% "
              f"{r['of_which_backend_compile_s']:8.2f}  {steps}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=16.0, help="seconds per recording")
    ap.add_argument("--repeats", type=int, default=2, help="steady-state fits per scene after the first")
    ap.add_argument("--emcee-steps", type=int, default=500)
    ap.add_argument("--out", type=Path, default=Path("benchmarks/out"))
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)

    prof = Profiler()
    install(prof)
    report = {"provenance": provenance(), "machine": platform.processor() or platform.machine(),
              "duration_s": args.duration, "runs": []}
    for name, scene in scenes(args.duration):
        t0 = time.perf_counter()
        rec = simulate(scene)
        sim_s = time.perf_counter() - t0
        for rep in range(1 + args.repeats):
            prof.reset()
            t0 = time.perf_counter()
            res = fit_recording(rec, FitOptions())
            wall = time.perf_counter() - t0
            rows = _rows(prof, wall)
            other = wall - sum(r["seconds"] for r in rows)
            rows.append({"stage": "rest of fit (python, band, model grid)", "calls": 1, "seconds": other,
                         "share": other / wall, "of_which_backend_compile_s": 0.0})
            kind = "first fit (compiles)" if rep == 0 else f"steady state #{rep}"
            _print(f"{name}: {kind}; status {res.status}, {res.n_bins} bins", rows, wall)
            report["runs"].append({"scene": name, "kind": kind, "wall_s": wall, "simulate_s": sim_s,
                                   "status": res.status, "n_bins": res.n_bins, "stages": rows,
                                   "compile_events": {f"{w} | {e}": v for (w, e), v in prof.compile_s.items()}})
        if res.problem is not None and args.emcee_steps:
            n_free = int(np.sum(res.problem.free))
            n_walkers = max(32, 2 * n_free + 2)
            for rep in range(2):
                t0 = time.perf_counter()
                post = run_emcee(res.problem, n_walkers=n_walkers, n_steps=args.emcee_steps, seed=rep)
                dt = time.perf_counter() - t0
                kind = "first (compiles)" if rep == 0 else "steady state"
                print(f"{name}: emcee {n_walkers} walkers x {args.emcee_steps} steps ({kind}): {dt:.2f} s, "
                      f"{1e6 * dt / (n_walkers * args.emcee_steps):.0f} us per log-prob, acceptance "
                      f"{post.acceptance_fraction:.2f}")
                report["runs"].append({"scene": name, "kind": f"emcee {kind}", "wall_s": dt,
                                       "n_walkers": n_walkers, "n_steps": args.emcee_steps})
    path = args.out / "profile_stages.json"
    path.write_text(json.dumps(report, indent=1))
    print(f"\n{provenance()}\nwrote {path}")


if __name__ == "__main__":
    main()
