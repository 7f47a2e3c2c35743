"""What the line integrals' 3-tangent JVP (``joint_model._few_inputs_jvp``) saves, and what it costs.

The joint model's Jacobian is taken by forward mode over all P parameters
(P = 19: vx, vy, a, two gain ratios, the y level, the noise floor, 12 texture
knots). The quadrature nodes and the window-depth responses log G at them
depend on (vx, vy, a) only; ``_pair_nodes`` and ``_matrix_nodes`` carry those 3
tangents and map them onto the P. This script fits the same recordings with
that rule and, as the reference in the same run, with forward mode through the
undecorated nodes (the session-13 code path), and prints per scene and model:
the first fit (compilation included), the median of the warm fits, their
ratio, and the largest difference in the fitted values and errors.

    python benchmarks/nodes_jvp.py                 # 3 scenes x (cross_pairs=0, the default chain), 3 warm fits each
    python benchmarks/nodes_jvp.py --repeats 5
"""

from __future__ import annotations

import argparse
import platform
import time

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from tactile_jax import joint_model as jm  # noqa: E402
from tactile_jax.fit import FitOptions, fit_recording  # noqa: E402
from tactile_jax.scene import Scene, simulate  # noqa: E402
from tactile_jax.texture import RandomTexture  # noqa: E402

SCENES = {  # label: (|v| m/s, direction deg, a m)
    "oblique 4.2 cm/s, 31 deg, 1.5 mm": (0.042, 31.4, 1.5e-3),
    "slow 1.2 cm/s, 45 deg, 1.2 mm": (0.012, 45.0, 1.2e-3),
    "near an axis 3 cm/s, 86 deg, 1.6 mm": (0.030, 86.0, 1.6e-3),
}
MODELS = {"cross_pairs=0": FitOptions(cross_pairs=0), "default (chain)": FitOptions()}
FIELDS = ("vx", "vy", "a", "vx_err", "vy_err", "a_err")
_RULE = {name: getattr(jm, name) for name in ("_pair_nodes", "_matrix_nodes")}


def use_rule(on: bool):
    """Switch the nodes between the 3-tangent rule and plain forward mode; drop compiled programs."""
    for name, f in _RULE.items():
        setattr(jm, name, f if on else f.fun)
    jax.clear_caches()


def timed_fits(rec, options, repeats):
    t0 = time.perf_counter()
    res = fit_recording(rec, options)
    first = time.perf_counter() - t0
    warm = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fit_recording(rec, options)
        warm.append(time.perf_counter() - t0)
    return first, float(np.median(warm)), res


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=3, help="warm fits per scene, model and code path")
    p.add_argument("--snr", type=float, default=50.0)
    a = p.parse_args()
    print(f"# 3-tangent nodes JVP against forward mode through the plain nodes; 16 s at 1 kHz, {a.snr:.0f} dB; "
          f"{platform.machine()} {platform.processor()}, {jax.device_count()} {jax.default_backend()} device(s), "
          f"jax {jax.__version__}, numpy {np.__version__}")
    print("| scene | model | first fit: rule / plain | warm fit (median): rule / plain | warm ratio | "
          "max rel. difference of vx, vy, a and errors | status |")
    print("|---|---|---|---|---|---|---|")
    for label, (speed, angle, radius) in SCENES.items():
        th = np.radians(angle)
        rec = simulate(Scene(texture=RandomTexture(), velocity=(speed * np.cos(th), speed * np.sin(th)),
                             contact_radius=radius, snr_db=a.snr, duration=16.0, seed=11))
        for model, options in MODELS.items():
            out = {}
            for on in (True, False):
                use_rule(on)
                out[on] = timed_fits(rec, options, a.repeats)
            use_rule(True)
            r1, r0 = out[True][2], out[False][2]
            diff = max(abs(getattr(r1, f) - getattr(r0, f)) / abs(getattr(r0, f)) for f in FIELDS
                       if getattr(r0, f) is not None and getattr(r1, f) is not None)
            print(f"| {label} | {model} | {out[True][0]:.1f} / {out[False][0]:.1f} s | "
                  f"{out[True][1]:.2f} / {out[False][1]:.2f} s | {out[False][1] / out[True][1]:.2f}x | "
                  f"{diff:.1e} | {r1.status} / {r0.status} |", flush=True)


if __name__ == "__main__":
    main()
