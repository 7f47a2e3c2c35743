"""Simulate a scene, save it, read it back and measure slip speed and contact radius.

    python examples/simulate_and_measure.py [--duration 16] [--out scene.h5]
"""

import argparse

import jax

jax.config.update("jax_enable_x64", True)

import tactile_jax as tj  # noqa: E402
from tactile_jax.inference.pair_fit import pair_leakage  # noqa: E402


def main(duration: float = 16.0, out: str = "scene.h5") -> tj.PairFit:
    scene = tj.Scene(texture=tj.RandomTexture(), velocity=(0.03, 0.0), contact_radius=2e-3,
                     duration=duration, snr_db=50.0, seed=7)
    tj.write_recording(out, tj.simulate(scene))
    rec = tj.read_recording(out)
    spec = tj.estimate_spectra(rec.signals, rec.fs, prewhiten=8)
    ratio = tj.amplitude_ratio(spec)
    band = tj.usable_band(ratio)
    d1, d2 = rec.depths
    # the exact R curve averaged over each bin's spectral window as this recording's texture fills it:
    # the kernel, weighted by the shallow spectrum the estimator saw, plus its realised centroid (leakage)
    fit = tj.fit_pair(ratio.omega, ratio.log_ratio[0], ratio.log_ratio_err[0], band[0], d1, d2,
                      bin_factor=spec.bin_factor, kernel=spec.kernel, spectrum=tj.whitened_psd(spec)[0],
                      leakage=pair_leakage(spec, 0))
    print(f"|vx| = {100 * fit.speed:.3f} +/- {100 * fit.speed_err:.3f} cm/s (truth {100 * rec.truth['vx']:.3f})")
    print(f"a    = {1e3 * fit.a:.3f} +/- {1e3 * fit.a_err:.3f} mm (truth {1e3 * rec.truth['a']:.3f})")
    return fit


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=16.0)
    p.add_argument("--out", default="scene.h5")
    a = p.parse_args()
    main(a.duration, a.out)
