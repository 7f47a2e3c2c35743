"""What one Hertz-window model evaluation costs, piece by piece, against the Gaussian window's.

At the joint fit's shapes (4 channels x 119 half bins x 144 line nodes for the
Hertz window; 62 integer bins x 72 nodes for the Gaussian) and a typical record
(a Hertz scene of ``benchmarks/windows.py``: 16 s at 1 kHz, 45 dB), warm, the
median of ``--repeats`` calls:

- lookup: ``model.hertz.hertz_factors`` at the fit's nodes, with the table
  lookup in chunks of ``hertz.CHUNK`` nodes (the package) and in one chunk (every
  node's gathered 4 x 4 blocks at once), the ratio of the two;
- residuals and Jacobian: ``inference.residuals.residuals_and_model`` and its
  ``jax.jacfwd`` (what each Levenberg-Marquardt iteration evaluates), per window,
  with the ratio Hertz / Gaussian;
- core: one record's whole joint fit (``inference.run.fit_one``), per window.

    python benchmarks/hertz_lookup.py            # about 2 min on 2 cores
"""

from __future__ import annotations

import argparse
import platform
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import tactile_jax as tj  # noqa: E402
from tactile_jax.inference import run  # noqa: E402
from tactile_jax.inference.core import prepare  # noqa: E402
from tactile_jax.inference.fit import record_of  # noqa: E402
from tactile_jax.inference.options import settings_of  # noqa: E402
from tactile_jax.inference.residuals import residuals_and_model  # noqa: E402
from tactile_jax.model import hertz, lines  # noqa: E402


def median_ms(fn, *args, repeats: int) -> float:
    jax.block_until_ready(fn(*args))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=20)
    args = ap.parse_args(argv)
    print(f"machine: {platform.processor() or platform.machine()}, {jax.device_count()} device(s) "
          f"({jax.default_backend()}), python {platform.python_version()}, jax {jax.__version__}, "
          f"numpy {np.__version__}, tactile_jax {tj.__version__}")
    scene = tj.Scene(texture=tj.RandomTexture(), velocity=(0.03, 0.012), contact_radius=1.6e-3, window="hertz",
                     snr_db=45.0, duration=16.0, fs=1000.0, seed=7)
    one = tj.simulate(scene).record(0)
    options = tj.FitOptions(window="hertz")
    rec = record_of(one.signals, one.fs, one.depths, options)
    hertz_settings = settings_of(options)
    gauss_settings = hertz_settings._replace(hertz=None)
    rows = []
    for name, settings in (("gaussian", gauss_settings), ("hertz", hertz_settings)):
        prep = jax.jit(prepare)(run._as_jnp(rec), settings)
        theta, data = prep.starts[0], (prep.data, settings.hertz)
        res = jax.jit(lambda t, a: residuals_and_model(t, a)[0])
        jac = jax.jit(jax.jacfwd(lambda t, a: residuals_and_model(t, a)[0]))
        run.fit_one(rec, settings)
        t0 = time.perf_counter()
        core = [run.fit_one(rec, settings) for _ in range(3)]
        core_s = (time.perf_counter() - t0) / len(core)
        rows.append((name, median_ms(res, theta, data, repeats=args.repeats),
                     median_ms(jac, theta, data, repeats=args.repeats), 1e3 * core_s))
        if name == "hertz":
            p = jnp.exp(theta[:3])
            d = prep.data.depths

            def nodes(p, c, grid=prep.data.grid_abs, d=d):   # traced anew by each jax.jit (CHUNK is read then)
                return lines._nodes(p, grid, d[0], d[1], 1, c)

            n_nodes = int(np.prod(nodes(p, settings.hertz)[2].shape))
            chunked = median_ms(jax.jit(nodes), p, settings.hertz, repeats=args.repeats)
            default = hertz.CHUNK
            try:
                hertz.CHUNK = n_nodes
                whole = median_ms(jax.jit(lambda p, c: nodes(p, c)), p, settings.hertz, repeats=args.repeats)
            finally:
                hertz.CHUNK = default
    print(f"\nHertz line nodes with their factors ({n_nodes} channel nodes), warm median of {args.repeats}:")
    print(f"  lookup in chunks of {hertz.CHUNK}: {chunked:.1f} ms; in one chunk: {whole:.1f} ms "
          f"(x{whole / chunked:.1f})")
    print("\n| window | residuals (ms) | Jacobian (ms) | whole core, one record (ms) |")
    print("|---|---|---|---|")
    for name, r, j, c in rows:
        print(f"| {name} | {r:.1f} | {j:.1f} | {c:.0f} |")
    g, h = rows
    print(f"| Hertz / Gaussian | x{h[1] / g[1]:.1f} | x{h[2] / g[2]:.1f} | x{h[3] / g[3]:.1f} |")


if __name__ == "__main__":
    main()
