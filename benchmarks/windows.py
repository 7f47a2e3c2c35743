"""Contact windows: scenes made with each physics (Gaussian, Hertz) fitted with each window and with the default.

Seeded scenes per physics: random isotropic texture, 16 s at 1 kHz, SNR
uniform 40-50 dB, contact radius uniform 0.8-3 mm, |v| log-uniform 1-8 cm/s,
half of the slips along x and half oblique (direction uniform 0-90 deg). Each
recording is fitted three ways through ``fit_recording``: the window forced to
"gaussian", forced to "hertz", and the default (``window=None``: chosen per
record by the information criterion, the choice and its margin reported),
and by the per-pair scipy reference (``scipy_reference.fit_record``, Gaussian
exact R curve, no 2-D model).

Reported per physics and fit: statuses; over the ``ok`` rows both speeds
within 2 % of |v|, a within 5 %, 1-sigma coverage of vx, vy and a (of the
interval the fit states: a minor speed's profile-likelihood interval where it
has one, else value -/+ err; a speed reported as consistent with 0, with a
95 % upper bound, is left out); "confident wrong": ``ok`` with a quantity
outside its 3-sigma interval (a profile interval's 2-sigma one widened by
half; twice an upper bound); for the
default, how often the chosen window is the one that made the data (among
all scenes, and among those whose margin is decisive, > 10); how often the
slip model holds a speed at 0, on the scenes along x (right) and on the
oblique ones (a truth that is not 0, read as 0 with an upper bound); the median time
per fit (warm). Hertz scenes' a is the Hertz radius, the quantity a Hertz fit
reports; a Gaussian fit's a of a Hertz scene is compared with it too, which
shows the bias of the Gaussian window's radius.

    python benchmarks/windows.py --scenes 50 --out benchmarks/out      # 100 scenes, 300 fits: ~26 min on 2 cores
    python benchmarks/windows.py --scenes 6 --out /tmp/win              # a quick look
    python benchmarks/windows.py --scenes 100 --fits default --out /tmp/win   # the default's window choice alone
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import json
import platform
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import scipy_reference  # noqa: E402

import tactile_jax as tj  # noqa: E402
from tactile_jax.spectral.estimate import default_nperseg  # noqa: E402

PHYSICS = ("gaussian", "hertz")
FITS = {"gaussian": "gaussian", "hertz": "hertz", "default": None}
ALL_FITS = (*FITS, "scipy")             # the package's three and the per-pair scipy reference
FS, DURATION = 1000.0, 16.0
DECISIVE = 10.0


def scenes(physics: str, n: int, seed: int = 34):
    rng = np.random.default_rng([seed, PHYSICS.index(physics)])
    for i in range(n):
        speed = float(np.exp(rng.uniform(np.log(0.01), np.log(0.08))))
        angle = 0.0 if i % 2 == 0 else float(rng.uniform(0, np.pi / 2))
        a = float(rng.uniform(0.8e-3, 3e-3))
        snr = float(rng.uniform(40, 50))
        s = int(rng.integers(1 << 30))
        yield tj.Scene(texture=tj.RandomTexture(), velocity=(speed * np.cos(angle), speed * np.sin(angle)),
                       contact_radius=a, window=physics, snr_db=snr, duration=DURATION, fs=FS, seed=s)


#: where simulated recordings are kept between runs (``--cache``); None: simulate every time
_CACHE: Path | None = None


def _simulate(scene):
    cached = _CACHE / f"{scene.window}_{scene.seed}.npz" if _CACHE else None
    if cached is not None and cached.exists():
        return tj.read_recording(cached)
    rec = _simulate_fresh(scene)
    if cached is not None:
        tj.write_recording(cached, rec)
    return rec


def _simulate_fresh(scene):
    try:
        return tj.simulate(scene)
    except tj.TactileInputError:       # a large contact at a fast slip: a coarser grid still resolves d1
        return tj.simulate(dataclasses.replace(scene, grid_spacing=60e-6))


def run_physics(physics: str, n: int, verbose: bool = True, fits=ALL_FITS) -> list[dict]:
    rows = []
    nperseg = default_nperseg(int(DURATION * FS))
    for i, scene in enumerate(scenes(physics, n)):
        rec = _simulate(scene)
        vx, vy = (abs(v) for v in scene.velocity)
        row = {"physics": physics, "i": i, "vx_true": vx, "vy_true": vy, "a_true": scene.a,
               "speed": float(np.hypot(vx, vy)), "snr_db": scene.snr_db, "fits": {}}
        for name, window in FITS.items():
            if name not in fits:
                continue
            t0 = time.perf_counter()
            res = tj.fit_recording(rec, tj.FitOptions(window=window))
            fit = {k: getattr(res, k) for k in ("vx", "vx_err", "vy", "vy_err", "a", "a_err", "redchi", "window",
                                                "model_margin", "window_margin", "texture", "direction", "direction_margin")
                   if hasattr(res, k)}
            # a minor component's profile-likelihood interval (1 and 2 sigma) and a 95 % upper bound, where given
            fit.update({f"{q}_{b}": getattr(res[q], b) for q in ("vx", "vy") for b in ("lo", "hi", "lo2", "hi2", "upper")})
            fit.update(status=str(res.status), seconds=time.perf_counter() - t0, message=res.message)
            row["fits"][name] = fit
        if "scipy" in fits:
            t0 = time.perf_counter()
            sp = scipy_reference.fit_record(np.asarray(rec.signals, float), FS, rec.depths[0], rec.depths[1], nperseg)
            row["fits"]["scipy"] = dict(zip(("vx", "vx_err", "vy", "vy_err", "a", "a_err"),
                                            (None if not np.isfinite(v) else float(v) for v in sp)),
                                        status="ok", seconds=time.perf_counter() - t0)
        rows.append(row)
        if verbose:
            name = "default" if "default" in row["fits"] else next(iter(row["fits"]))
            d = row["fits"][name]
            print(f"{physics:8s} {i:3d} v=({100 * vx:.2f}, {100 * vy:.2f}) a={1e3 * scene.a:.2f} | {name}: "
                  f"{d['status']} window {d.get('window')} margin {d.get('window_margin')} "
                  f"vx {_f(d['vx'])} vy {_f(d['vy'])} a {_f(d['a'], 1e3)} | "
                  + " ".join(f"{k} {r['seconds']:.2f}s" for k, r in row["fits"].items()), flush=True)
    return rows


def core_cost(n: int = 6, repeat: int = 5) -> dict:
    """Warm time of one joint solve (``inference.run.fit_one``, the compiled core) per window on the same
    records (the first scenes of each physics), medians over ``repeat`` calls each; and their ratio."""
    from tactile_jax.inference import run
    from tactile_jax.inference.fit import record_of
    from tactile_jax.inference.options import settings_of

    recs = [_simulate(sc) for p in PHYSICS for sc in list(scenes(p, n // 2))]
    out = {}
    for window in ("gaussian", "hertz"):
        options = tj.FitOptions(window=window)
        settings = settings_of(options)
        times = []
        for rec in recs:
            r = record_of(rec.signals, rec.fs, rec.depths, options)
            run.fit_one(r, settings)                                   # compile / warm
            for _ in range(repeat):
                t0 = time.perf_counter()
                run.fit_one(r, settings)
                times.append(time.perf_counter() - t0)
        out[window] = float(np.median(times))
    out["ratio"] = out["hertz"] / out["gaussian"]
    return out


def _f(v, s=100.0):
    return "-" if v is None else f"{s * v:.3f}"


def _dev(row, fit, name):
    v = fit.get(name)
    return None if v is None else abs(v - row[name + "_true"])


def _interval(fit, q, n_sigma):
    """The n-sigma interval (n = 1 or 3) the fit states for q, or None where it states none at that level:
    a speed consistent with 0 has a 95 % upper bound U and no 1-sigma interval (3 sigma: [0, 2 U]); a minor
    speed has a profile-likelihood interval (1 sigma: lo, hi; 3 sigma: its 2-sigma interval widened by
    half, an approximation); anything else value -/+ n err."""
    v, lo, hi, lo2, hi2, upper = (fit.get(f"{q}{s}") for s in ("", "_lo", "_hi", "_lo2", "_hi2", "_upper"))
    if upper is not None:
        return None if n_sigma == 1 else (0.0, 2.0 * upper)
    if lo is not None:
        if n_sigma == 1:
            return lo, (np.inf if hi is None else hi)
        return v - 1.5 * (v - lo2), (np.inf if hi2 is None else v + 1.5 * (hi2 - v))
    err = fit.get(q + "_err")
    return None if not err else (v - n_sigma * err, v + n_sigma * err)


def _inside(row, fit, q, n_sigma):
    lo, hi = _interval(fit, q, n_sigma)
    return lo <= row[q + "_true"] <= hi


def summarize(rows: list[dict], name: str) -> dict:
    fits = [(r, r["fits"][name]) for r in rows]
    ok = [(r, f) for r, f in fits if f["status"] == "ok"]

    def share(pred, pool):
        return float(np.mean([pred(r, f) for r, f in pool])) if pool else None

    out = {"n": len(fits), "status": dict(collections.Counter(f["status"] for _, f in fits))}
    out["both_speeds_2pct"] = share(lambda r, f: all(_dev(r, f, k) is not None and _dev(r, f, k) <= 0.02 * r["speed"]
                                                     for k in ("vx", "vy")), ok)
    out["a_5pct"] = share(lambda r, f: _dev(r, f, "a") is not None and _dev(r, f, "a") <= 0.05 * r["a_true"], ok)
    for q in ("vx", "vy", "a"):
        pool = [(r, f) for r, f in ok if f.get(q) is not None and _interval(f, q, 1) is not None]
        out[q + "_cover1"] = share(lambda r, f: _inside(r, f, q, 1), pool)
    # status ok with vx, vy or a more than 3 of its sigmas from the truth, as a share of all scenes
    out["confident_wrong"] = share(lambda r, f: f["status"] == "ok" and any(
        f.get(q) is not None and _interval(f, q, 3) is not None and not _inside(r, f, q, 3)
        for q in ("vx", "vy", "a")), fits)
    # the slip model: scenes along x whose vy is held at 0, oblique scenes with a speed held (truth not 0)
    out["held_along_x"] = share(lambda r, f: f.get("direction") == "along x", [(r, f) for r, f in ok if r["vy_true"] == 0])
    out["held_oblique"] = share(lambda r, f: f.get("direction") not in (None, "oblique"),
                                [(r, f) for r, f in ok if r["vy_true"] > 0])
    out["seconds_median"] = float(np.median([f["seconds"] for _, f in fits[1:]] or [fits[0][1]["seconds"]]))
    if name == "default":
        right = [(r, f) for r, f in fits if f.get("window") is not None]
        out["chose_physics"] = share(lambda r, f: f["window"] == r["physics"], right)
        decisive = [(r, f) for r, f in right if (f.get("window_margin") or 0) > DECISIVE]
        out["chose_physics_decisive"] = share(lambda r, f: f["window"] == r["physics"], decisive)
        out["n_decisive"] = len(decisive)
    return out


def _pct(x):
    return "-" if x is None else f"{100 * x:.0f} %"


def table(summary: dict) -> str:
    lines = ["| physics | fit | statuses | both speeds within 2 % | a within 5 % | 1-sigma cover vx / vy / a | "
             "confident wrong | default picks the physics (decisive) | speed held at 0: along x / oblique | s / fit |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for physics, by_fit in summary.items():
        for name, s in by_fit.items():
            st = ", ".join(f"{k} {v}" for k, v in sorted(s["status"].items()))
            cover = " / ".join(_pct(s[q + "_cover1"]) for q in ("vx", "vy", "a"))
            pick = (f"{_pct(s['chose_physics'])} ({_pct(s['chose_physics_decisive'])} of {s['n_decisive']})"
                    if name == "default" else "")
            lines.append(f"| {physics} | {name} | {st} | {_pct(s['both_speeds_2pct'])} | {_pct(s['a_5pct'])} | "
                         f"{cover} | {_pct(s.get('confident_wrong'))} | {pick} | "
                         f"{_pct(s.get('held_along_x'))} / {_pct(s.get('held_oblique'))} | {s['seconds_median']:.2f} |")
    return "\n".join(lines)


def figure(rows: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tactile_jax.viz.figures import save_figure

    fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    for ax, physics in zip(axes, rows):
        for k, (name, marker) in enumerate((("gaussian", "o"), ("hertz", "s"), ("default", "x"))):
            if name not in rows[physics][0]["fits"]:
                continue
            pts = [(r["a_true"], (r["fits"][name]["a"] - r["a_true"]) / r["a_true"]) for r in rows[physics]
                   if r["fits"][name]["status"] == "ok" and r["fits"][name].get("a") is not None]
            if pts:
                x, y = np.array(pts).T
                ax.plot(1e3 * x, 100 * y, marker, ms=4, alpha=0.7, label=f"{name} window")
        ax.axhline(0, color="0.5", lw=0.8)
        ax.set_xlabel("true contact radius a (mm)")
        ax.set_title(f"{physics} contact", fontsize=10)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("a error (%)")
    axes[0].legend(fontsize=8)
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    save_figure(fig, path)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=50, help="scenes per physics")
    ap.add_argument("--physics", default=",".join(PHYSICS))
    ap.add_argument("--out", type=Path, default=Path("benchmarks/out"))
    ap.add_argument("--cache", type=Path, default=None, help="folder to keep the simulated recordings in (reused)")
    ap.add_argument("--fits", default=",".join(ALL_FITS), help="which fits to run, of " + ", ".join(ALL_FITS) + " (default: all)")
    ap.add_argument("--summarize", type=Path, default=None, metavar="JSON",
                    help="print the table of an earlier run's windows.json instead of fitting")
    args = ap.parse_args(argv)
    if args.summarize is not None:
        saved = json.loads(args.summarize.read_text())
        summary = {p: {name: summarize(r, name) for name in r[0]["fits"]} for p, r in saved["rows"].items()}
        print(f"machine: {saved['machine']}\n\n{table(summary)}")
        cost = saved.get("core_cost")
        if cost:
            print(f"\none joint solve, warm (median): Gaussian {cost['gaussian']:.3f} s, Hertz {cost['hertz']:.3f} s, "
                  f"ratio {cost['ratio']:.2f}")
        return
    global _CACHE
    _CACHE = args.cache
    if _CACHE is not None:
        _CACHE.mkdir(parents=True, exist_ok=True)
    physics = [p.strip() for p in args.physics.split(",") if p.strip()]
    args.out.mkdir(parents=True, exist_ok=True)
    fits = [f.strip() for f in args.fits.split(",") if f.strip()]
    unknown = sorted(set(fits) - set(ALL_FITS))
    if unknown or not fits:
        ap.error(f"--fits: unknown fit(s) {', '.join(unknown)}; choose from {', '.join(ALL_FITS)}")
    rows = {p: run_physics(p, args.scenes, fits=fits) for p in physics}
    summary = {p: {name: summarize(r, name) for name in r[0]["fits"]} for p, r in rows.items()}
    import jaxlib

    machine = (f"{platform.machine()}, {platform.system()}, Python {platform.python_version()}, jax {jax.__version__} "
               f"(jaxlib {jaxlib.__version__}), numpy {np.__version__}")
    cost = core_cost() if set(fits) == set(ALL_FITS) else None
    print(f"\nmachine: {machine}\n\n{table(summary)}")
    if cost:
        print(f"\none joint solve, warm (median): Gaussian {cost['gaussian']:.3f} s, Hertz {cost['hertz']:.3f} s, "
              f"ratio {cost['ratio']:.2f}")
    (args.out / "windows.json").write_text(json.dumps({"machine": machine, "summary": summary, "rows": rows, "core_cost": cost},
                                                      indent=1, default=str))
    figure(rows, args.out / "windows.png")
    print(f"\nwrote {args.out / 'windows.json'} and {args.out / 'windows.png'}")


if __name__ == "__main__":
    main()
