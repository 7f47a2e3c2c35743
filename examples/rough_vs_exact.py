"""Rough (Eq. 26) against exact (Eq. 23) R curve: where they differ and what the rough one does to a.

The rough curve is the large-alpha asymptote of the exact one: good only for
|alpha| >> 3 d2 / a^2. This example prints log R of both for a few contact
radii, then simulates a slip along x and fits the x pair's log amplitude ratio
with each curve (speed and radius free): the rough fit is a straight line plus
an offset (Eq. 6 slope with Eq. 26 offset), so with a small contact it
over-estimates the speed and mis-reads a.

    python examples/rough_vs_exact.py [--duration 16] [--radius 2e-3] [--out rough_vs_exact.png]
"""

import argparse

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np

import tactile_jax as tj


def main(duration: float = 16.0, radius: float = 2e-3, out: str | None = "rough_vs_exact.png"):
    d1, d2 = tj.PAPER_SENSOR.d1, tj.PAPER_SENSOR.d2
    alpha = np.array([0.0, 1e3, 3e3, 1e4, 3e4])                           # rad/m
    print("alpha (rad/m):      " + "".join(f"{x:>9.0f}" for x in alpha))
    for a in (1e-3, 3e-3, 1e-2):
        ex = np.asarray(tj.log_r_exact(alpha, d1, d2, a))
        ro = np.asarray(tj.log_r_rough(alpha, d1, d2, a))
        print(f"a = {1e3 * a:4.1f} mm  exact    " + "".join(f"{x:9.3f}" for x in ex))
        print("             rough    " + "".join(f"{x:9.3f}" for x in ro) + f"   (valid for alpha >> {3 * d2 / a**2:.0f})")

    scene = tj.Scene(texture=tj.RandomTexture(), velocity=(0.03, 0.0), contact_radius=radius, duration=duration,
                     snr_db=50.0, seed=5)
    rec = tj.simulate(scene)
    spec = tj.estimate_spectra(rec.signals, rec.fs, prewhiten=8)
    ratio = tj.amplitude_ratio(spec)
    band = np.asarray(tj.usable_band(ratio))[0]
    omega, lr, err = (np.asarray(v)[i] for v, i in ((ratio.omega, ...), (ratio.log_ratio, 0), (ratio.log_ratio_err, 0)))
    exact = tj.fit_pair(omega, lr, err, band, d1, d2, bin_factor=spec.bin_factor)
    line = tj.slope_speed(omega, lr, err, band, d1, d2, bin_factor=spec.bin_factor)
    rough_a = float(tj.radius_from_offset(float(line.intercept), d1, d2))
    v = scene.velocity[0]
    print(f"truth: |vx| = {100 * v:.3f} cm/s, a = {1e3 * radius:.3f} mm")
    print(f"exact R fit:        |vx| = {100 * exact.speed:.3f} +/- {100 * exact.speed_err:.3f} cm/s, "
          f"a = {1e3 * exact.a:.3f} +/- {1e3 * exact.a_err:.3f} mm")
    print(f"rough R (Eq. 6+26): |vx| = {100 * float(line.speed):.3f} +/- {100 * float(line.speed_err):.3f} cm/s, "
          f"a = {1e3 * rough_a:.3f} mm")
    if out:
        from tactile_jax.viz.figures import plot_ratio_figure
        om = np.linspace(1.0, omega[band].max() * 1.1, 300)
        plot_ratio_figure(out, freq=np.asarray(spec.freq), psd_shallow=np.asarray(spec.psd[0]),
                          psd_deep=np.asarray(spec.psd[1]), omega=omega, log_ratio=lr, log_ratio_err=err, band=band,
                          line=(float(line.intercept), float(line.slope)), line_label="rough R (Eq. 26) fit",
                          curves={"om": om, "exact R fit": np.asarray(tj.log_r_exact(om / exact.speed, d1, d2, exact.a)),
                                  "exact R, truth": np.asarray(tj.log_r_exact(om / v, d1, d2, radius))},
                          title=f"rough vs exact R: a = {1e3 * radius:g} mm, |vx| = {100 * v:g} cm/s (simulated)")
    return {"exact": (exact.speed, exact.a), "rough": (float(line.speed), rough_a), "truth": (v, radius)}


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=16.0)
    p.add_argument("--radius", type=float, default=2e-3, help="contact radius, m")
    p.add_argument("--out", default="rough_vs_exact.png")
    a = p.parse_args()
    main(a.duration, a.radius, a.out)
