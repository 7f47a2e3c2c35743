"""Fit recorded spectra (not signals) and get slip speeds and contact radius with error bars.

Some users have spectra from their own analyser rather than probe signals. This
example simulates an oblique slip, writes its spectra to a spectra file of the
data contract (PSD, CSD, number of averages), reads it back and fits it two ways:

- PSD + CSD: the joint 2-D model (``fit.fit_spectra``), both pairs together;
- amplitude ratios |P2/P1| with their errors only (the usable band): each pair alone
  (exact R curve), which under oblique slip with a small contact pulls the smaller
  speed toward the larger.

    python examples/fit_spectra_with_errors.py [--duration 16] [--out scene_spectra.npz]
"""

import argparse

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np

import tactile_jax as tj
from tactile_jax.inference.options import FitOptions
from tactile_jax.inference.fit import fit_spectra
from tactile_jax.io.files import SpectraData


def _line(name, res, truth):
    def pm(v, e, s):
        return "n/d" if v is None else (f"{s * v:.3f}" + ("" if e is None else f" +/- {s * e:.3f}"))
    print(f"{name:10s} |vx| = {pm(res.vx, res.vx_err, 100)} cm/s, |vy| = {pm(res.vy, res.vy_err, 100)} cm/s, "
          f"a = {pm(res.a, res.a_err, 1e3)} mm   (truth {100 * abs(truth['vx']):.2f}, {100 * abs(truth['vy']):.2f} cm/s, "
          f"{1e3 * truth['a']:.2f} mm; status {res.status})")


def main(duration: float = 16.0, out: str = "scene_spectra.npz"):
    scene = tj.Scene(texture=tj.RandomTexture(), velocity=(0.03, 0.012), contact_radius=2.5e-3,
                     duration=duration, snr_db=50.0, seed=11)
    rec = tj.simulate(scene)
    spec = tj.estimate_spectra(rec.signals, rec.fs, prewhiten=8)
    ratio = tj.amplitude_ratio(spec)
    keep = slice(1, None)                               # DC carries no ratio
    tj.write_spectra(out, SpectraData(
        omega=np.asarray(spec.omega)[keep], psd=np.asarray(spec.psd)[:, keep], csd=np.asarray(spec.csd)[:, keep],
        n_segments=float(spec.dof), ratio=np.exp(np.asarray(ratio.log_ratio))[:, keep],
        ratio_err=np.asarray(ratio.log_ratio_err)[:, keep], depths=rec.depths,
        curvature_radius=rec.curvature_radius, kernel=np.asarray(spec.kernel, float),
        bin_factor=float(spec.bin_factor), whitening=np.asarray(spec.whitening), fs=float(rec.fs)))
    data = tj.read_spectra(out)
    joint = fit_spectra(data, FitOptions())
    # ratios only: keep each pair's usable band (coherent bins, deep probe above the noise); the other
    # bins get an error above FitOptions.max_err, which leaves them out of the fit
    band = np.asarray(tj.usable_band(ratio))[:, keep]
    ratio_only = data._replace(psd=None, csd=None, ratio_err=np.where(band, data.ratio_err, 1e3))
    pairs = fit_spectra(ratio_only, FitOptions())
    _line("joint", joint, rec.truth)
    _line("per pair", pairs, rec.truth)
    return joint, pairs, rec.truth


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=16.0)
    p.add_argument("--out", default="scene_spectra.npz")
    a = p.parse_args()
    main(a.duration, a.out)
