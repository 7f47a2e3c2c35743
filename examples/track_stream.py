"""A robot hand's stream: blocks of probe samples pushed into a ``Tracker`` as they arrive.

A simulated recording whose slip changes (still, then along x, then oblique) is cut into
blocks of 50 ms, the size a sound card would hand over, and pushed one by one. Each update
that becomes due is printed as it comes, next to the truth, with the time it took: the first
window that hears a moving texture gets the full analysis, the later ones go on from it.

    python examples/track_stream.py --block 0.05
"""

from __future__ import annotations

import argparse

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import tactile_jax as tj  # noqa: E402
from tactile_jax.simulation.path import Piece, simulate_path, truth_at  # noqa: E402


def main(block: float = 0.05, still: float = 2.0, along_x: float = 4.0, oblique: float = 4.0, window: float = 2.0,
         hop: float = 0.1, options: tj.FitOptions = tj.FitOptions()):
    pieces = [Piece(still), Piece(along_x, (0.03, 0.0), contact_radius=2e-3),
              Piece(oblique, (0.03, 0.02), contact_radius=2e-3)]
    rec = simulate_path(pieces, snr_db=45.0, seed=4, crossfade=0.03)
    tracker = tj.Tracker(rec.fs, tj.PAPER_SENSOR, window=window, hop=hop, options=options)
    n = int(round(block * rec.fs))
    print("   t s  status         vx cm/s         vy cm/s         a mm         truth (vx, vy, a)   compute")
    for i in range(0, rec.n_samples, n):
        for row in tracker.push(rec.signals[:, i:i + n]):
            piece = truth_at(rec.truth, row["t"] - window / 2, row["t"] + window / 2)
            truth = ("(mixed window)" if piece is None else "(still)" if not piece["moving"] else
                     f"({100 * piece['vx']:.1f}, {100 * piece['vy']:.1f}, {1e3 * piece['a']:.1f})")

            def show(name, scale):
                v, e = row[name], row[name + "_err"]
                return "-" if v is None else f"{scale * v:6.3f} +/- {scale * e:.3f}" if e else f"{scale * v:6.3f} (held)"

            print(f"{row['t']:6.2f}  {row['status']:13s}  {show('vx', 100):15s} {show('vy', 100):15s} "
                  f"{show('a', 1e3):15s} {truth:19s} {1e3 * row['compute_s']:6.1f} ms ({row['update']})")
    steps = np.array([r["compute_s"] for r in tracker.rows if r["update"] == "step"])
    if steps.size:
        print(f"updates from the last estimate: median {1e3 * np.median(steps):.1f} ms, 95th percentile "
              f"{1e3 * np.percentile(steps, 95):.1f} ms; {hop * 1e3:.0f} ms of signal each")
    return tracker.rows, rec.truth


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--block", type=float, default=0.05, help="seconds of samples per push")
    parser.add_argument("--window", type=float, default=2.0)
    parser.add_argument("--hop", type=float, default=0.1)
    args = parser.parse_args()
    main(block=args.block, window=args.window, hop=args.hop)
