"""Where the time of a warm ``fit`` goes: the analysis program's stages, the model's Jacobian, the extras.

For each of a few seeded 16 s records (random texture, Gaussian and Hertz
contacts, 40 dB) and each program (the default, both windows; ``--window
gaussian``, the Gaussian window's alone), in this process:

- spectra: ``fit.record_of`` (numpy segments, the compiled band location);
- analysis: the whole analysis program on one record (``run.analyse_one``),
  warm, median of ``--repeats``; with its stages (``analysis.STAGES``): which
  ran and how many iterations (evaluations of the residuals and their
  Jacobian) each took;
- the cost of one iteration: the joint residuals' Jacobian under each window,
  and one ``core.errors`` (jackknife and spread), each jitted alone;
- fit_recording: the whole warm ``fit`` (the analysis, then the extras: profile
  intervals where a speed is minor, the row);
- a chunk of 4 records: ``run.analyse_many`` one after another and vmapped.

Compilation: the analysis program's trace + lowering and backend compile
seconds, per program, in this process (no persistent cache). The first
``tactile-jax fit`` with a fresh cache is timed in a subprocess.

    python benchmarks/joint_speed.py                 # ~8 min on 2 cores
    python benchmarks/joint_speed.py --repeats 3 --no-cli
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

#: (vx, vy) m/s, a m, window, seed
SCENES = (((0.030, 0.006), 1.5e-3, "gaussian", 11), ((0.023, 0.0), 3.0e-3, "gaussian", 12),
          ((0.020, 0.020), 1.0e-3, "hertz", 13), ((0.050, 0.015), 2.0e-3, "hertz", 14))


def _median_time(f, repeats):
    out, times = None, []
    for _ in range(repeats):
        t = time.perf_counter()
        out = jax.block_until_ready(f())
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def machine() -> str:
    import jaxlib

    return (f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, {jax.default_backend()}, "
            f"python {platform.python_version()}, jax {jax.__version__}, jaxlib {jaxlib.__version__}, float64")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--no-cli", action="store_true", help="skip the fresh-cache CLI timing")
    args = p.parse_args(argv)

    import tactile_jax as tj
    from tactile_jax.inference import analysis as an, run
    from tactile_jax.inference.core import errors, prepare
    from tactile_jax.inference.fit import record_of
    from tactile_jax.inference.options import FitOptions, analysis_settings, choices_of, settings_of
    from tactile_jax.inference.residuals import residuals_and_model
    from tactile_jax.simulation.scene import Scene, simulate

    print(f"machine: {machine()}")
    recs = [simulate(Scene(velocity=v, contact_radius=a, window=w, snr_db=40.0, seed=seed)) for v, a, w, seed in SCENES]
    for label, options in (("default (both windows)", FitOptions()), ("--window gaussian", FitOptions(window="gaussian"))):
        settings, choices = analysis_settings(options), choices_of(options)
        print(f"\n== {label}")
        records = [record_of(np.asarray(r.signals, float), r.fs, r.depths, options) for r in recs]
        program = jax.jit(an.analyse)
        args0 = run._as_jnp((records[0], settings, choices))
        t = time.perf_counter()
        lowered = program.lower(*args0)
        t_lower = time.perf_counter() - t
        t = time.perf_counter()
        lowered.compile()
        t_compile = time.perf_counter() - t
        print(f"analysis program: trace + lowering {t_lower:.1f} s, backend compile {t_compile:.1f} s")
        t, _ = _median_time(lambda: [record_of(np.asarray(r.signals, float), r.fs, r.depths, options) for r in recs],
                            3)
        print(f"spectra (record_of): {1e3 * t / len(recs):.0f} ms a record, warm")
        print(f"{'scene':<28} {'analysis':>9} {'fit':>7}  stages (iterations)")
        run.analyse_one(records[0], settings, choices)
        for (v, a, w, _), rec, r in zip(SCENES, recs, records):
            t_an, out = _median_time(lambda: run.analyse_one(r, settings, choices), args.repeats)
            tj.fit_recording(rec, options)
            t_fit, _ = _median_time(lambda: tj.fit_recording(rec, options), max(1, args.repeats // 2))
            ran = ", ".join(f"{name} {int(n)}" for name, n, on in zip(an.STAGES, out.stages.iterations,
                                                                     out.stages.active) if on)
            name = f"{w} {100 * v[0]:.1f},{100 * v[1]:.1f} cm/s {1e3 * a:.1f} mm"
            print(f"{name:<28} {1e3 * t_an:7.0f}ms {1e3 * t_fit:5.0f}ms  {ran}")
        # the cost of one iteration of each window, and of one error analysis
        r0 = run._as_jnp(records[0])
        preps = {}
        for window in ("gaussian", "hertz") if options.window is None else ("gaussian",):
            s = run._as_jnp(settings_of(options, window=window))
            prep = preps[window] = jax.jit(lambda r, s: prepare(r, s))(r0, s)
            coef = None if window == "gaussian" else s.hertz
            jac = jax.jit(jax.jacfwd(lambda t: residuals_and_model(t, (prep.data, coef))[0]))
            res = jax.jit(lambda t: residuals_and_model(t, (prep.data, coef))[0])
            theta = prep.starts[0]
            jac(theta), res(theta)
            t_jac, j = _median_time(lambda: jac(theta), 20)
            t_res, r = _median_time(lambda: res(theta), 20)
            print(f"one iteration, {window}: Jacobian {1e3 * t_jac:.1f} ms, residuals {1e3 * t_res:.1f} ms "
                  f"({r.shape[0]} residuals, {theta.shape[0]} parameters)")
        prep = preps["gaussian"]            # the errors read the data blocks, which the windows share
        theta = prep.starts[0]
        j, (r, _) = jax.jacfwd(lambda t: (lambda o: (o[0], o))(residuals_and_model(t, (prep.data, None))),
                               has_aux=True)(theta)
        err = jax.jit(lambda r_, th, res_, j_: errors(r_, prep.data, prep.free, prep.band.i0, th, res_, j_))
        err(r0, theta, r, j)
        t_err, _ = _median_time(lambda: err(r0, theta, r, j), 20)
        print(f"one error analysis (jackknife, spread): {1e3 * t_err:.1f} ms")
        # a chunk: one after another, and vmapped
        chunk = records[:4]
        run.analyse_many(chunk, settings, choices, vmapped=False)
        t_serial, _ = _median_time(lambda: run.analyse_many(chunk, settings, choices, vmapped=False), 3)
        t = time.perf_counter()
        run.analyse_many(chunk, settings, choices, size=4, vmapped=True)
        t_first = time.perf_counter() - t
        t_vmap, _ = _median_time(lambda: run.analyse_many(chunk, settings, choices, size=4, vmapped=True), 3)
        print(f"chunk of 4: one after another {t_serial:.2f} s ({4 / t_serial:.2f} rec/s on one core), vmapped "
              f"{t_vmap:.2f} s ({4 / t_vmap:.2f} rec/s; first call with compile {t_first:.0f} s); ratio "
              f"{t_vmap / t_serial:.2f}")
    if not args.no_cli:
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "scene.h5")
            from tactile_jax.io.files import write_recording

            write_recording(path, recs[0])
            env = {**os.environ, "TACTILE_JAX_CACHE": os.path.join(tmp, "cache")}
            for label, extra in (("fresh cache", []), ("warm cache", []), ("fresh cache, --window gaussian",
                                                                             ["--window", "gaussian"])):
                if label.startswith("fresh"):
                    env["TACTILE_JAX_CACHE"] = os.path.join(tmp, f"cache{len(extra)}")
                t = time.perf_counter()
                subprocess.run([sys.executable, "-m", "tactile_jax.cli.app", "fit", path, "--quiet", *extra],
                               env=env, check=True, capture_output=True)
                print(f"tactile-jax fit, {label}: {time.perf_counter() - t:.1f} s (process start included)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
