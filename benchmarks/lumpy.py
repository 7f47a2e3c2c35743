"""Lumpy textures: the default fit on few-hundred-mode textures, and the misfit's trend test that tells their
scatter from a wrong model.

A texture of a few hundred plane waves (``ModeTexture``, 300 modes, seeded per
scene) makes every Welch segment hear the same modes: each probe's spectrum
scatters from bin to bin far above the segments' noise, with no trend across
frequency. The fit names such a poor fit's texture "..., lumpy" where its
misfit has no trend in any block (``core._roughness``: the median trend ratio at
most ``core.LUMPY_F`` bin factors, the largest at most ``core.LUMPY_F_MAX``), and
refits it with the texture's power and angular spread at each bin as random
effects (stage TL of ``inference.analysis``). Scene sets (16 s at
1 kHz, 40-50 dB, |v| log-uniform 1-8 cm/s, the contact window drawn per scene,
Gaussian or Hertz):

- ``axis``: 300 modes, slips within 10 deg of x or of y, a 0.8-3 mm;
- ``oblique``: 300 modes, slips at 0-90 deg, a 0.8-3 mm;
- ``large``: 300 modes, slips at 0-90 deg, a 5-8 mm;
- ``smooth``: RandomTexture (the model's own assumption), slips at 0-90 deg, a 0.8-3 mm;
- ``wrong_window``: RandomTexture under the Hertz disk fitted with ``--window gaussian``: a model that
  does not describe the spectra, which must not be called lumpy (the control of the trend test).

Per set: statuses and how many fits are ``lumpy``; over the ``ok`` rows and over the lumpy rows
separately: both speeds within 3 % of |v| (a held speed counts by its held value) and a within 5 %, 1- and
2-sigma coverage of vx, vy and a, and rows with a value more than 3 sigma from the truth (confident wrong
where ``ok``); the median trend ratio and its range. Times are medians per record after compilation.

    python benchmarks/lumpy.py --scenes 30 --out benchmarks/out                  # all five sets
    python benchmarks/lumpy.py --sets axis,large --scenes 30 --out /tmp/a        # a part; then
    python benchmarks/lumpy.py --summarize /tmp/a/lumpy.jsonl /tmp/b/lumpy.jsonl --out benchmarks/out
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from tactile_jax.errors import TactileInputError  # noqa: E402
from tactile_jax.inference.fit import fit_recording  # noqa: E402
from tactile_jax.inference.options import FitOptions  # noqa: E402
from tactile_jax.simulation.scene import Scene, simulate  # noqa: E402
from tactile_jax.simulation.texture import ModeTexture, RandomTexture  # noqa: E402

SETS = ("axis", "oblique", "large", "smooth", "wrong_window")
FS, DURATION = 1000.0, 16.0
RIGHT_SPEED, RIGHT_A = 0.03, 0.05


def scenes(kind: str, n: int, seed: int = 53):
    rng = np.random.default_rng([seed, SETS.index(kind)])
    for i in range(n):
        speed = float(np.exp(rng.uniform(np.log(0.01), np.log(0.08))))
        if kind == "axis":
            angle = np.radians(rng.uniform(0, 10))
            angle = float(np.pi / 2 - angle if rng.random() < 0.5 else angle)
        else:
            angle = float(rng.uniform(0, np.pi / 2))
        a = float(rng.uniform(5e-3, 8e-3) if kind == "large" else rng.uniform(0.8e-3, 3e-3))
        snr = float(rng.uniform(40, 50))
        s = int(rng.integers(1 << 30))
        window = "hertz" if kind == "wrong_window" or rng.random() < 0.5 else "gaussian"
        texture = RandomTexture() if kind in ("smooth", "wrong_window") else ModeTexture(n_modes=300, seed=s)
        yield Scene(texture=texture, velocity=(speed * np.cos(angle), speed * np.sin(angle)), contact_radius=a,
                    snr_db=snr, window=window, duration=DURATION, fs=FS, seed=s)


def _simulate(scene):
    try:
        return simulate(scene)
    except TactileInputError:       # a large contact at a fast slip: a coarser grid still resolves d1
        return simulate(dataclasses.replace(scene, grid_spacing=60e-6))


def run_set(kind: str, n: int, sink, seed: int = 53) -> list[dict]:
    options = FitOptions(window="gaussian") if kind == "wrong_window" else FitOptions()
    rows = []
    for i, scene in enumerate(scenes(kind, n, seed)):
        rec = _simulate(scene)
        t0 = time.perf_counter()
        res = fit_recording(rec, options)
        elapsed = time.perf_counter() - t0
        s = res.summary
        row = dict(set=kind, i=i, seed=scene.seed, window_true=scene.window, speed=float(np.hypot(*scene.velocity)),
                   angle=float(np.degrees(np.arctan2(scene.velocity[1], scene.velocity[0]))), snr=scene.snr_db,
                   status=res.status.value, texture=res.texture, window=res.window, direction=res.direction,
                   redchi=res.redchi, roughness=None if s is None else float(s.roughness),
                   lumpy=bool(s is not None and bool(s.lumpy)), time=elapsed, error_method=res.error_method,
                   lump_sd=None if s is None or s.data is None else [float(x) for x in np.asarray(s.data.lump_sd)])
        for q, truth in zip(("vx", "vy", "a"), (*scene.velocity, scene.a)):
            e = res[q]
            row.update({q: e.value, f"{q}_err": e.err, f"{q}_true": float(truth)})
        rows.append(row)
        sink.write(json.dumps(row) + "\n")
        sink.flush()
        print(f"{kind} {i + 1}/{n}: {row['status']} ({row['texture']}), redchi {row['redchi']}, trend ratio "
              f"{row['roughness']}, {elapsed:.1f} s", flush=True)
    return rows


def _close(r: dict, q: str) -> bool:
    """Whether a row's ``q`` (vx, vy: within ``RIGHT_SPEED`` of |v|; a: within ``RIGHT_A`` of a) is right; a held speed
    counts by its held value, 0."""
    tol = RIGHT_A * r["a_true"] if q == "a" else RIGHT_SPEED * r["speed"]
    return r[q] is not None and abs(r[q] - r[f"{q}_true"]) <= tol


def _judged(rows: list[dict]) -> dict:
    pulls, right, beyond = [], 0, 0
    for r in rows:
        p = [(r[q] - r[f"{q}_true"]) / r[f"{q}_err"] for q in ("vx", "vy", "a") if r[q] is not None and r[f"{q}_err"]]
        pulls += p
        beyond += any(abs(x) > 3 for x in p)
        right += all(_close(r, q) for q in ("vx", "vy", "a"))
    p = np.abs(np.asarray(pulls))
    return dict(n=len(rows), right=right, beyond_3_sigma=beyond, n_pulls=int(p.size),
                cover1=float(np.mean(p < 1)) if p.size else None, cover2=float(np.mean(p < 2)) if p.size else None)


def _held(rows: list[dict]) -> dict:
    """The fits whose slip direction held a speed at 0 (the minor one), and those wrong only through it: the held
    speed's truth beyond ``RIGHT_SPEED`` of |v| while the other speed and a are right."""
    held, wrong, truths = 0, 0, []
    for r in rows:
        axis = {"along x": "vy", "along y": "vx"}.get(r["direction"])
        if axis is None:
            continue
        held += 1
        other = "vx" if axis == "vy" else "vy"
        if _close(r, other) and _close(r, "a") and not _close(r, axis):
            wrong += 1
            truths.append(abs(r[f"{axis}_true"]) / r["speed"])
    return dict(held=held, wrong_by_held=wrong, held_truths=[min(truths), max(truths)] if truths else None)


def summarize(rows: list[dict]) -> dict:
    statuses: dict = {}
    for r in rows:
        statuses[r["status"]] = statuses.get(r["status"], 0) + 1
    trend = np.asarray([r["roughness"] for r in rows if r["roughness"] is not None and np.isfinite(r["roughness"])])
    return dict(n=len(rows), statuses=statuses, ok=_judged([r for r in rows if r["status"] == "ok"]),
                lumpy=_judged([r for r in rows if r["lumpy"]]), lumpy_held=_held([r for r in rows if r["lumpy"]]),
                trend_median=float(np.median(trend)) if trend.size else None,
                trend_range=[float(trend.min()), float(trend.max())] if trend.size else None,
                time_median=float(np.median([r["time"] for r in rows])))


def table(summary: dict) -> str:
    def judged(j):
        if not j["n"]:
            return "-", "-", "-"
        cov = "-" if j["cover1"] is None else f"{j['cover1']:.2f} / {j['cover2']:.2f}"
        return f"{j['n']}", f"{j['right']}", f"{cov}, {j['beyond_3_sigma']}"

    head = ("| set | scenes | statuses | ok | ok and right | ok: coverage 1 / 2 sigma, confident wrong | lumpy "
            "| lumpy and right | lumpy: coverage 1 / 2 sigma, beyond 3 sigma | trend ratio median (range) "
            "| s per fit |")
    lines = [head, "|" + "---|" * 11]
    for kind, s in summary.items():
        st = ", ".join(f"{k} {v}" for k, v in sorted(s["statuses"].items()))
        tr = "-" if s["trend_median"] is None else (f"{s['trend_median']:.2f} ({s['trend_range'][0]:.2f}-"
                                                    f"{s['trend_range'][1]:.2f})")
        lines.append(f"| {kind} | {s['n']} | {st} | {' | '.join(judged(s['ok']))} | {' | '.join(judged(s['lumpy']))} "
                     f"| {tr} | {s['time_median']:.1f} |")
    return "\n".join(lines)


def figure(rows: list[dict], path: Path, machine: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    colors = dict(zip(SETS, plt.rcParams["axes.prop_cycle"].by_key()["color"]))
    bins = np.geomspace(0.2, 500, 40)
    for kind in SETS:
        t = [r["roughness"] for r in rows if r["set"] == kind and r["roughness"] is not None
             and np.isfinite(r["roughness"])]
        if t:
            ax1.hist(t, bins=bins, histtype="step", lw=1.5, label=kind, color=colors[kind])
    ax1.set_xscale("log")
    ax1.set_xlabel("trend ratio of the misfit (core._roughness)")
    ax1.set_ylabel("records")
    ax1.legend(fontsize=8)
    ax1.set_title("a lumpy texture's misfit has no trend; a wrong window's has", fontsize=9)
    pulls = {}
    for r in rows:
        if r["lumpy"]:
            for q in ("vx", "vy", "a"):
                if r[q] is not None and r[f"{q}_err"]:
                    pulls.setdefault(r["set"], []).append((r[q] - r[f"{q}_true"]) / r[f"{q}_err"])
    edges = np.linspace(-5, 5, 41)
    for kind, p in pulls.items():
        ax2.hist(np.clip(p, -5, 5), bins=edges, histtype="step", lw=1.5, density=True, label=f"{kind} ({len(p)})",
                 color=colors[kind])
    x = np.linspace(-5, 5, 200)
    ax2.plot(x, np.exp(-x * x / 2) / np.sqrt(2 * np.pi), "k--", lw=1, label="N(0, 1)")
    ax2.set_xlabel("pull (value - truth) / error, lumpy rows")
    ax2.legend(fontsize=8)
    fig.suptitle(machine, fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def _machine() -> str:
    import jaxlib

    return (f"{platform.machine()}, {platform.system()}, Python {platform.python_version()}, jax {jax.__version__} "
            f"(jaxlib {jaxlib.__version__}), numpy {np.__version__}")


def report(rows: list[dict], out: Path) -> None:
    machine = _machine()
    summary = {k: summarize([r for r in rows if r["set"] == k]) for k in SETS if any(r["set"] == k for r in rows)}
    print(f"\nmachine: {machine}\n\n{table(summary)}\n")
    for kind, s in summary.items():
        h = s["lumpy_held"]
        if h["held"]:
            span = "" if h["held_truths"] is None else (f" (held speeds of {100 * h['held_truths'][0]:.1f}-"
                                                        f"{100 * h['held_truths'][1]:.1f} % of |v|)")
            print(f"{kind}: {h['held']} lumpy fits hold the minor speed at 0; {h['wrong_by_held']} are wrong only "
                  f"through it{span}")
    (out / "lumpy.json").write_text(json.dumps({"machine": machine, "summary": summary}, indent=1))
    figure(rows, out / "lumpy.png", machine)
    print(f"\nwrote {out / 'lumpy.json'} and {out / 'lumpy.png'}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default=",".join(SETS))
    ap.add_argument("--scenes", type=int, default=20)
    ap.add_argument("--out", type=Path, default=Path("benchmarks/out"))
    ap.add_argument("--seed", type=int, default=53, help="another draw of the scenes")
    ap.add_argument("--summarize", type=Path, nargs="+", help="re-table saved lumpy.jsonl files")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.summarize:
        rows = [json.loads(line) for path in args.summarize for line in path.read_text().splitlines() if line]
        report(rows, args.out)
        return
    kinds = [k.strip() for k in args.sets.split(",") if k.strip()]
    unknown = sorted(set(kinds) - set(SETS))
    if unknown:
        ap.error(f"unknown sets {', '.join(unknown)}; expected some of {', '.join(SETS)}")
    rows = []
    with open(args.out / "lumpy.jsonl", "w") as sink:
        for kind in kinds:
            rows += run_set(kind, args.scenes, sink, args.seed)
    report(rows, args.out)


if __name__ == "__main__":
    main()
