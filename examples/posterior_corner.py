"""Posterior of |vx|, |vy| and a by emcee around a joint fit, drawn as a corner plot.

Fits a simulated oblique slip with the joint 2-D model, samples the posterior of
all free parameters (speeds, radius, y level, texture-spectrum knots) with emcee
(``posterior.run_emcee``), prints the posterior means and sds next to the
Laplace error bars with the sampler's diagnostics, and writes
``corner_<name>_0.png`` (``plotting.plot_posterior_corner``).

    python examples/posterior_corner.py [--duration 16] [--steps 2000] [--walkers 48] [--out-dir figures]
"""

import argparse

import jax

jax.config.update("jax_enable_x64", True)

import tactile_jax as tj
from tactile_jax.inference.options import FitOptions
from tactile_jax.inference.fit import fit_recording
from tactile_jax.viz.figures import plot_posterior_corner
from tactile_jax.uncertainty.posterior import run_emcee


def main(duration: float = 16.0, steps: int = 2000, walkers: int = 48, out_dir: str = "figures"):
    scene = tj.Scene(texture=tj.RandomTexture(), velocity=(0.025, 0.01), contact_radius=2e-3, duration=duration,
                     snr_db=50.0, seed=3)
    rec = tj.simulate(scene)
    res = fit_recording(rec, FitOptions())
    n_free = sum(res.problem.free)
    res.posterior = run_emcee(res.problem, n_walkers=max(walkers, 2 * n_free + 2), n_steps=steps, seed=0)
    post = res.posterior.summary()
    t = rec.truth
    for name, scale, unit, laplace in (("vx", 100, "cm/s", res.vx_err), ("vy", 100, "cm/s", res.vy_err),
                                       ("a", 1e3, "mm", res.a_err)):
        s = post[name]
        truth = abs(t[name])
        lap = "n/d" if laplace is None else f"{scale * laplace:.3f}"
        print(f"{name}: posterior {scale * s['mean']:.3f} +/- {scale * s['sd']:.3f} {unit} (Laplace sd {lap}; "
              f"truth {scale * truth:.3f})")
    p = res.posterior
    print(f"acceptance {p.acceptance_fraction:.2f}, max tau {p.max_tau:.1f} steps, ESS {p.ess:.0f}"
          + ("".join(f"\n  warning: {w}" for w in p.warnings)))
    paths = plot_posterior_corner(res, out_dir, truth=t)
    print("wrote", *paths)
    return res, paths


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=16.0)
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--walkers", type=int, default=48)
    ap.add_argument("--out-dir", default="figures")
    a = ap.parse_args()
    main(a.duration, a.steps, a.walkers, a.out_dir)
