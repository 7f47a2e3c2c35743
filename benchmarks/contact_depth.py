"""The paper's contact-depth experiments (Figs. 7 and 8): a from a texture's lines at a known slip.

The paper (section 4.3) slides a 0.5 mm wire net along x at a known 4.7 cm/s
and reads the contact radius from the deep/shallow ratio at the net's
wavenumber. Here: ``WireNet(pitch=0.5 mm, wire_width=0.1 mm)``, slip
(4.7, 0) cm/s, Gaussian contact window of a = 0.85 and 2.2 mm, 16 s at
1 kHz, 40, 45 and 50 dB, seeds 0 .. n-1, each fitted by ``fit_recording`` with
``velocity=(0.047, 0)`` (``tactile-jax fit --velocity 0.047,0``; ``--window gaussian`` gives the fit the
paper's window). With the
slip along x, a line heard by the x pair has |kx| = omega / vx whatever its ky,
so its ratio gives a through the exact R curve.

Reported per radius and SNR: statuses, how many rows give a, how many within
5 % of the truth, the pulls (a - truth) / a_err, and the rows beyond 3 sigma
(confident wrong). The machine and versions head the table.

    python benchmarks/contact_depth.py --seeds 6          # 36 fits: ~3 min on 2 cores

``--fig8``: the paper's Fig. 8 instead. Three objects pressed to five depths
d = 0.03-0.2 mm on a 30 mm sphere (a = sqrt(R d) = 0.95-2.45 mm) under the
Hertz disk: a 0.5 mm wire net, a lattice of pipes at 1.5 mm pitch
(``Grating(profile="pipes")``) and a random surface; 4.7 cm/s along x, 45 dB,
fs 2 kHz, 16 s, the velocity given and the window left to the tool. One row per
file: status, window, a and its pull.

    python benchmarks/contact_depth.py --fig8 --seeds 1   # 15 fits: ~4 min on 2 cores
"""

from __future__ import annotations

import argparse
import collections
import platform

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from tactile_jax.inference.fit import fit_recording  # noqa: E402
from tactile_jax.inference.options import FitOptions  # noqa: E402
from tactile_jax.simulation.scene import Scene, simulate  # noqa: E402
from tactile_jax.simulation.texture import Grating, RandomTexture, WireNet  # noqa: E402

VELOCITY = (0.047, 0.0)
RADII = (0.85e-3, 2.2e-3)
SNRS = (40.0, 45.0, 50.0)


def run(seeds: int, window: str | None = None) -> list[dict]:
    rows = []
    for a in RADII:
        for snr in SNRS:
            for seed in range(seeds):
                rec = simulate(Scene(texture=WireNet(pitch=0.5e-3, wire_width=0.1e-3), velocity=VELOCITY,
                                     contact_radius=a, window="gaussian", snr_db=snr, seed=seed))
                res = fit_recording(rec, FitOptions(velocity=VELOCITY, window=window))
                pull = (res.a - a) / res.a_err if res.a is not None and res.a_err else float("nan")
                rows.append(dict(a=a, snr=snr, seed=seed, status=res.status, fit_a=res.a, a_err=res.a_err,
                                 pull=pull, message=res.message))
    return rows


def table(rows: list[dict]) -> str:
    out = ["| a (mm) | SNR (dB) | statuses | a given | within 5 % | pulls (median, max abs) | beyond 3 sigma |",
           "|---|---|---|---|---|---|---|"]
    for a in RADII:
        for snr in SNRS:
            sel = [r for r in rows if r["a"] == a and r["snr"] == snr]
            st = collections.Counter(r["status"] for r in sel)
            given = [r for r in sel if r["fit_a"] is not None]
            near = sum(abs(r["fit_a"] / a - 1.0) <= 0.05 for r in given)
            pulls = np.array([r["pull"] for r in given if np.isfinite(r["pull"])])
            wrong = int(np.sum(np.abs(pulls) > 3.0))
            p = f"{np.median(pulls):+.2f}, {np.max(np.abs(pulls)):.2f}" if pulls.size else "-"
            out.append(f"| {a * 1e3:g} | {snr:g} | {', '.join(f'{k} {v}' for k, v in st.most_common())} | "
                       f"{len(given)} of {len(sel)} | {near} | {p} | {wrong} |")
    return "\n".join(out)


#: the paper's Fig. 8: the sphere's radius (m), the depths (m) and the objects
SPHERE_RADIUS = 30e-3
DEPTHS = (0.03e-3, 0.06e-3, 0.10e-3, 0.15e-3, 0.20e-3)
OBJECTS = {"wire net 0.5 mm": lambda: WireNet(pitch=0.5e-3, wire_width=0.1e-3),
           "pipes 1.5 mm": lambda: Grating(pitch=1.5e-3, profile="pipes"),
           "random surface": lambda: RandomTexture()}


def run_fig8(seeds: int) -> list[dict]:
    rows = []
    for name, make in OBJECTS.items():
        for d in DEPTHS:
            a = (SPHERE_RADIUS * d) ** 0.5
            for seed in range(seeds):
                rec = simulate(Scene(texture=make(), velocity=VELOCITY, contact_radius=a, window="hertz", snr_db=45.0,
                                     fs=2000.0, seed=seed))
                res = fit_recording(rec, FitOptions(velocity=VELOCITY))
                pull = (res.a - a) / res.a_err if res.a is not None and res.a_err else float("nan")
                rows.append(dict(object=name, d=d, a=a, seed=seed, status=res.status, window=res.window,
                                 model=res.model, fit_a=res.a, a_err=res.a_err, pull=pull, message=res.message))
    return rows


def table_fig8(rows: list[dict]) -> str:
    out = ["| object | d (mm) | a (mm) | status | model, window | a fitted (mm) | within 5 % | pull |",
           "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        fit = "-" if r["fit_a"] is None else f"{r['fit_a'] * 1e3:.4g} +/- {r['a_err'] * 1e3:.2g}"
        near = "-" if r["fit_a"] is None else ("yes" if abs(r["fit_a"] / r["a"] - 1.0) <= 0.05 else "no")
        pull = f"{r['pull']:+.1f}" if np.isfinite(r["pull"]) else "-"
        out.append(f"| {r['object']} | {r['d'] * 1e3:g} | {r['a'] * 1e3:.3g} | {r['status']} | {r['model']}, "
                   f"{r['window']} | {fit} | {near} | {pull} |")
    return "\n".join(out)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--fig8", action="store_true", help="the paper's Fig. 8 (Hertz disk, three objects, five depths)")
    ap.add_argument("--window", choices=("gaussian", "hertz"), default=None,
                    help="Fig. 7: the contact window given to the fit (default: chosen by the tool)")
    args = ap.parse_args(argv)
    print(f"machine: {platform.processor() or platform.machine()}, jax {jax.__version__} ({jax.default_backend()}), "
          f"python {platform.python_version()}")
    if args.fig8:
        rows = run_fig8(args.seeds)
        print(table_fig8(rows))
        for r in rows:
            print(f"  {r['object']}, d {r['d'] * 1e3:g} mm: {r['message'][:160]}")
        return
    rows = run(args.seeds, args.window)
    print(table(rows))


if __name__ == "__main__":
    main()
