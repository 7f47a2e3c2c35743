"""`fit --mcmc`: what the posterior costs after the fit, and what sampling in float32 changes.

For each scene (an oblique Gaussian contact, a small and a large Hertz contact, a slip 8 deg off x under a large
Gaussian contact; 16 s at 1 kHz, 50 dB, seed 3) the default fit runs, then ``run_emcee`` with the CLI's defaults (32
walkers x 500 steps, seed 0): in float32, the default (median of ``--repeats`` runs), and in float64 (one run,
the reference of the same process). The first call's compilation is excluded. Reported per scene: seconds
after the fit, ESS, largest tau, the float32 log-probability's sd from float64 (``PosteriorResult.lp_error``)
and the precision the run kept. Then, for a float32 chain, what float32 did to the posterior: every 4th kept
draw reweighted by exp(lp_float64 - lp_float32), the shift of each quantity's mean in posterior sds and the
ratio of its sds (an exact measure of the float32 target's error, free of Monte Carlo noise between two
chains). Last, ``tactile-jax fit --mcmc`` less ``tactile-jax fit`` on the first scene's file, new processes
with a warm cache (medians of ``--repeats``).

Writes ``posterior_speed.json`` and ``posterior_speed.png`` (seconds after the fit per scene and precision)
to ``--out``.

Usage: python benchmarks/posterior_speed.py [--repeats 3] [--out benchmarks/out]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import jax

import tactile_jax.cli.common  # noqa: F401 - float64 and the persistent compilation cache, as the CLI has them
import emcee  # noqa: E402
import numpy as np  # noqa: E402

import tactile_jax  # noqa: E402
from tactile_jax.inference.fit import fit_recording  # noqa: E402
from tactile_jax.inference.options import FitOptions  # noqa: E402
from tactile_jax.io.files import write_recording  # noqa: E402
from tactile_jax.simulation.scene import Scene, simulate  # noqa: E402
from tactile_jax.simulation.texture import RandomTexture  # noqa: E402
from tactile_jax.uncertainty.posterior import make_log_prob, run_emcee  # noqa: E402

SCENES = {
    "Gaussian, (3.0, 1.2) cm/s, a 1.5 mm": dict(velocity=(0.03, 0.012), contact_radius=1.5e-3, window="gaussian"),
    "Hertz, (2.0, 2.0) cm/s, a 1.0 mm": dict(velocity=(0.02, 0.02), contact_radius=1.0e-3, window="hertz"),
    "Hertz, (3.0, 1.0) cm/s, a 2.5 mm": dict(velocity=(0.03, 0.01), contact_radius=2.5e-3, window="hertz"),
    "Gaussian, 8 deg off x, 4 cm/s, a 3.0 mm": dict(velocity=(0.04 * np.cos(np.radians(8)),
                                                              0.04 * np.sin(np.radians(8))),
                                                    contact_radius=3.0e-3, window="gaussian"),
}
QUANTITIES = ("vx", "vy", "a")


def _timed(problem, precision, repeats):
    warm = run_emcee(problem, n_walkers=32, n_steps=20, precision=precision)   # compile (or load) first
    times, post = [], None
    for _ in range(repeats if warm.precision == precision else 1):         # float32 not kept: float64's run
        t0 = time.perf_counter()
        post = run_emcee(problem, n_walkers=32, n_steps=500, seed=0, precision=precision)
        times.append(time.perf_counter() - t0)
    return statistics.median(times), post


def _reweighted(problem, post):
    """Per quantity: (mean shift in posterior sds, sd ratio) of the chain's draws reweighted to float64."""
    theta = post.theta[:, ::4].reshape(-1, post.theta.shape[-1])
    eps = make_log_prob(problem)(theta) - post.log_prob[:, ::4].ravel()
    w = np.exp(eps - eps.max())
    w /= w.sum()
    out = {}
    for q in QUANTITIES:
        if q not in post.samples:
            continue
        x = np.asarray(post.samples[q][:, ::4], float).ravel()
        sd = np.std(x)
        sd_w = np.sqrt(np.sum(w * np.square(x - np.sum(w * x))))
        out[q] = ((np.sum(w * x) - np.mean(x)) / sd, sd_w / sd)
    return out


def _cli(args, repeats):
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        subprocess.run(["tactile-jax", *args], check=True, capture_output=True)
        out.append(time.perf_counter() - t0)
    return statistics.median(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default="benchmarks/out", help="folder for posterior_speed.json and .png")
    args = ap.parse_args()
    machine = (f"{platform.machine()} {platform.processor()}, {os.cpu_count()} cores, python "
               f"{platform.python_version()}, jax {jax.__version__}, emcee {emcee.__version__}, tactile_jax "
               f"{tactile_jax.__version__}; load average {os.getloadavg()[0]:.1f}")
    print(f"machine: {machine}")
    runs = []
    print("\n| scene | precision | s after the fit | ESS | max tau | lp sd from float64 | precision kept |")
    print("|---|---|---|---|---|---|---|")
    compare = []
    first_file = None
    tmp = Path(tempfile.mkdtemp())
    for name, kw in SCENES.items():
        rec = simulate(Scene(texture=RandomTexture(), fs=1000.0, duration=16.0, snr_db=50.0, seed=3, **kw))
        if first_file is None:
            first_file = write_recording(tmp / "scene.h5", rec)
        res = fit_recording(rec, FitOptions())
        if res.problem is None or res.status != "ok":
            print(f"| {name} | fit {res.status}: no posterior | | | | | |")
            continue
        for precision, repeats in (("float32", args.repeats), ("float64", 1)):
            sec, post = _timed(res.problem, precision, repeats)
            err = "-" if not np.isfinite(post.lp_error) else f"{post.lp_error:.3f}"
            print(f"| {name} ({res.window}) | {precision} | {sec:.2f} | {post.ess:.0f} | {post.max_tau:.1f} | {err} "
                  f"| {post.precision} |", flush=True)
            runs.append(dict(scene=name, window=res.window, asked=precision, kept=post.precision, seconds=sec,
                             ess=post.ess, max_tau=post.max_tau, lp_error=post.lp_error))
            if post.precision == "float32":
                compare.append((name, _reweighted(res.problem, post)))
    print("\n| scene (float32 kept) | quantity | mean shift reweighted to float64 (posterior sds) | sd ratio |")
    print("|---|---|---|---|")
    for name, moments in compare:
        for q, (shift, ratio) in moments.items():
            print(f"| {name} | {q} | {shift:+.4f} | {ratio:.4f} |")
    fit_s = _cli(["fit", str(first_file), "--out", str(tmp / "r.json"), "--quiet"], args.repeats)
    mcmc_s = _cli(["fit", str(first_file), "--out", str(tmp / "m.json"), "--mcmc", "--quiet"], args.repeats)
    print(f"\n`tactile-jax fit --mcmc` on the first scene, warm cache: {mcmc_s:.1f} s against `fit` {fit_s:.1f} s: "
          f"{mcmc_s - fit_s:.1f} s after the fit (medians of {args.repeats} processes)")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "posterior_speed.json").write_text(json.dumps(
        {"machine": machine, "runs": runs, "reweighted": {name: m for name, m in compare},
         "cli": {"fit_s": fit_s, "fit_mcmc_s": mcmc_s}}, indent=1, default=float))
    _figure(runs, machine, out / "posterior_speed.png")


def _figure(runs, machine, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = list(dict.fromkeys(r["scene"] for r in runs))
    fig, ax = plt.subplots(figsize=(7.5, 3.6))
    for j, asked in enumerate(("float32", "float64")):
        sel = {r["scene"]: r for r in runs if r["asked"] == asked}
        xs = [i + (j - 0.5) * 0.38 for i, sc in enumerate(scenes) if sc in sel]
        ys = [sel[sc]["seconds"] for sc in scenes if sc in sel]
        ax.bar(xs, ys, width=0.36, color=("C0", "C1")[j], label=f"asked {asked}")
        for x, sc in zip(xs, [sc for sc in scenes if sc in sel]):
            ax.annotate(f"kept {sel[sc]['kept']}", (x, sel[sc]["seconds"]), ha="center", va="bottom", fontsize=7)
    ax.axhline(10.0, color="k", lw=0.8, ls="--", label="10 s")
    ax.set_xticks(range(len(scenes)), [sc.replace(", ", ",\n", 1) for sc in scenes], fontsize=7)
    ax.set_ylabel("s after the fit (32 walkers x 500 steps)")
    ax.legend(fontsize=7)
    fig.text(0.01, 0.01, machine, fontsize=6, color="0.4")
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
