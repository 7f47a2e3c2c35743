"""Reprocess a folder of recordings in one call: one result row per record, bad files as status rows.

Simulates a few recordings of different slips into a folder (one of them a
multi-record file, one of them broken on purpose), runs
``tactile_jax.batch.run_batch`` over the folder (compiled once per recording
length and chunk; resumable: a second run skips rows already written) and
prints the rows read back from the results file. The same from the shell:

    tactile-jax batch FOLDER --out results.csv

    python examples/batch_folder.py [--files 4] [--duration 8] [--folder batch_data] [--out batch_results.csv]
"""

import argparse
import dataclasses
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np

import tactile_jax as tj
from tactile_jax.batch.run import run_batch
from tactile_jax.inference.options import FitOptions
from tactile_jax.io.results import read_results


def make_folder(folder, n_files: int = 4, duration: float = 8.0) -> Path:
    """Recordings of slips along x at 3-4.5 cm/s (the last file holds two records) and one broken file."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    base = tj.Scene(texture=tj.RandomTexture(), contact_radius=3e-3, duration=duration, snr_db=50.0)
    speeds = np.linspace(0.03, 0.045, n_files)
    for i, v in enumerate(speeds):
        recs = [tj.simulate(dataclasses.replace(base, velocity=(float(v), 0.0), seed=100 + i + 10 * j))
                for j in range(2 if i == n_files - 1 else 1)]
        rec = recs[0] if len(recs) == 1 else dataclasses.replace(
            recs[0], signals=np.stack([r.signals for r in recs]), truth={})
        tj.write_recording(folder / f"run_{i:02d}.h5", rec)
    bad = tj.simulate(dataclasses.replace(base, velocity=(0.02, 0.0), duration=min(duration, 2.0), seed=99))
    bad.signals[1, 10] = np.nan                                   # a broken sample: becomes a status row
    np.savez(folder / "broken.npz", signals=bad.signals, fs=bad.fs, depths=np.asarray(bad.depths))
    return folder


def main(files: int = 4, duration: float = 8.0, folder: str = "batch_data", out: str = "batch_results.csv"):
    make_folder(folder, files, duration)
    summary = run_batch([folder], out, options=FitOptions(), chunk_size=8, progress=False, resume=False)
    rows = read_results(out)
    print(f"{summary.n_rows} rows ({summary.n_failed} failed) in {summary.timings.get('total', float('nan')):.1f} s "
          f"-> {summary.out}")
    for r in rows:
        vx = "" if r.get("vx") is None else f"{100 * r['vx']:.3f}"
        vx_err = "" if r.get("vx_err") is None else f"{100 * r['vx_err']:.3f}"
        print(f"  {Path(str(r['file'])).name:14s} [{int(r['index'])}]  |vx| = {vx:>7s} +/- {vx_err:>6s} cm/s  "
              f"status {r['status']}  {r.get('message') or ''}"[:140])
    return summary, rows


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--files", type=int, default=4)
    p.add_argument("--duration", type=float, default=8.0)
    p.add_argument("--folder", default="batch_data")
    p.add_argument("--out", default="batch_results.csv")
    a = p.parse_args()
    main(a.files, a.duration, a.folder, a.out)
