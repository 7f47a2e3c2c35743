"""Speed against error for every estimator of |v| and a, against the Cramer-Rao bound (issue 5).

Seeded scenes (random texture, slip along x so every single-pair method is a
valid model; Gaussian window, and a Hertz-window subset) over SNR 10-60 dB,
speeds and contact radii. Each recording's x pair goes through:

  slope        Eq. 6 line (closed_form.slope_speed); a from its Eq. 26 offset
  rough LS     least squares of the rough R (Eq. 26): pair_fit's rough-curve residuals
  exact LS     pair_fit.fit_pair: exact R (Eq. 23), optimistix LM        <- the time reference
               (its spectral-window average weighted by the prewhitened shallow spectrum, plus the
               realised centroid term and noise-only bin errors, pair_fit.Leakage; "exact LS window
               average" leaves the Leakage out, session 7's model)
  exact LS jaxopt / exact LS float32 (x64 off, in a subprocess)
  hertz LS     least squares of the Hertz-window R (r_curve.log_r_hertz), written here
  lmfit peer   benchmarks/peer_lmfit.py: scipy Welch + numpy exact R + lmfit leastsq (+ lmfit emcee)
and, on a subset (they cost seconds per recording): the joint 2-D fit
(fit.fit_recording, optimistix / jaxopt / float32) and the emcee posterior
mean of the joint fit (posterior.run_emcee).

Times are per recording after compilation (medians; compile time apart),
the estimator alone unless said (spectra are timed once, apart); batched:
one vmapped call over all recordings. Errors: bias and RMSE of |v| and a
relative to the truth; efficiency = CRB / MSE pooled as 1 / mean(err^2 / CRB),
with the pair CRB (crb.pair_crb) at the truth of the cell's noise: each bin's
error of noise alone (pair_fit.noise_err) averaged in variance over the cell's
recordings, neighbouring bins correlated as the estimator's white-noise
estimates are (CrossSpectra.bin_corr, Hann 0.444 / 0.028; 200 realisations of
the 30 dB cell measured 0.408 / 0.027 after the centroid term). The JSON also
has eff_*_indep, each recording's own noise-alone errors with bins independent
(session 8's bound); eff_*_bp, with the Bendat-Piersol errors as they are, the
bound of sessions 5-7; eff_*_white, with the white-noise bin_factor 1.94; and
eff_*_jk, with the neighbour correlation the recording's jackknife measures.
Writes speed_vs_error.json and speed_vs_error.png (Pareto: time vs RMSE).

    python benchmarks/speed_vs_error.py --out benchmarks/out                 # ~10-15 min on 2 cores
    python benchmarks/speed_vs_error.py --seeds 1 --snr 30 --quick           # a smoke run
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import warnings
import time
from pathlib import Path

import jax

if "--float32-worker" not in sys.argv:
    jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import peer_lmfit  # noqa: E402

from tactile_jax.closed_form import radius_from_offset, slope_speed  # noqa: E402
from tactile_jax.crb import joint_crb, pair_crb  # noqa: E402
from tactile_jax.jackknife import bin_correlation  # noqa: E402
from tactile_jax.fit import _A_BOUNDS, FitOptions, fit_recording  # noqa: E402
from tactile_jax.lsq import least_squares  # noqa: E402
from tactile_jax.pair_fit import _residuals as exact_residuals  # noqa: E402
from tactile_jax.pair_fit import _residuals_rough as rough_residuals  # noqa: E402
from tactile_jax.pair_fit import fit_pair, kernel_log_weights, noise_err, pair_leakage  # noqa: E402
from tactile_jax.r_curve import log_r_hertz  # noqa: E402
from tactile_jax.recording import Recording  # noqa: E402
from tactile_jax.scene import Scene, simulate  # noqa: E402
from tactile_jax.spectra import amplitude_ratio, default_nperseg, estimate_spectra, usable_band, whitened_psd  # noqa: E402
from tactile_jax.texture import RandomTexture  # noqa: E402

PREWHITEN = 8
REFERENCE = "exact LS"


# ----------------------------------------------------------------------------- models written here


def _weighted(model, args):
    omega, y, err, mask = args[:4]
    safe = jnp.where(mask, err, 1.0)
    return jnp.where(mask, (jnp.where(mask, y, 0.0) - model) / safe, 0.0)


def hertz_residuals(theta, args):
    """pair_fit's residuals with the Hertz-window R (r_curve.log_r_hertz); no kernel average (cost)."""
    omega, _, _, _, d1, d2, _, _ = args
    model = log_r_hertz(jnp.abs(omega) / jnp.exp(theta[0]), d1, d2, jnp.exp(theta[1]), n=12, panels=8) + theta[2]
    return _weighted(jnp.where(jnp.isfinite(model), model, 0.0), args)


# ----------------------------------------------------------------------------- scenes and spectra


def scene_grid(seeds, snrs, speeds, radii, duration, hertz):
    rows = []
    for window in ("gaussian",) + (("hertz",) if hertz else ()):
        for snr in snrs:
            if window == "hertz" and snr != max(s_ for s_ in snrs if s_ <= 45):
                continue
            for v in speeds:
                for a in radii:
                    for s in range(seeds if window == "gaussian" else 1):
                        seed = 1000 * s + int(snr) * 7 + int(v * 1e3) * 13 + int(a * 1e5)
                        rows.append({"window": window, "snr_db": snr, "speed": v, "a": a, "seed": seed, "rep": s,
                                     "scene": Scene(texture=RandomTexture(), velocity=(v, 0.0), contact_radius=a,
                                                    window=window, snr_db=snr, duration=duration, seed=seed)})
    return rows


def pair_data(signals, fs, nperseg=None):
    kw = {"nperseg": nperseg} if nperseg else {}
    spec = estimate_spectra(signals, fs, method="welch", prewhiten=PREWHITEN, **kw)
    ratio = amplitude_ratio(spec)
    band = usable_band(ratio, neighbours=3)      # as the fits' default (FitOptions.band_neighbours)
    return spec, ratio, band


def cell_noise_err(noise_vars):
    """Each recording's bound errors from a cell's (R, M) noise-alone variances (NaN where a recording leaves
    a bin out): each bin's variance averaged over the cell's recordings, a recording's own where none uses it.

    One recording's noise-alone error is an estimate with ~K degrees of freedom, and a bound built from its
    1 / var over-counts the information (benchmarks/README.md, "Session 9"). Returns (R, M) errors.
    """
    noise_vars = np.asarray(noise_vars, float)
    with warnings.catch_warnings():      # a bin no recording of the cell uses: NaN, its own used below
        warnings.simplefilter("ignore", RuntimeWarning)
        var = np.nanmean(noise_vars, axis=0)
    return np.sqrt(np.where(np.isfinite(var), var, noise_vars))


def shallow_seen(spec):
    """The x pair's shallow spectrum as the Welch average saw it (``fit_pair(spectrum=...)``)."""
    return np.asarray(whitened_psd(spec)[..., 0, :])


def resolution_nperseg(signals, fs, depths):
    """The Welch segment for a pair fit (``fit._resolution_nperseg`` with the pair fits' bin count)."""
    from tactile_jax.fit import MIN_PAIR_BAND_BINS, _resolution_nperseg

    spec = estimate_spectra(signals, fs, method="welch", prewhiten=PREWHITEN)
    return (_resolution_nperseg(spec, depths, signals.shape[-1], FitOptions(), min_band_bins=MIN_PAIR_BAND_BINS)
            or default_nperseg(signals.shape[-1]))


def _timed(fn, *a, **kw):
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*a, **kw))
    return out, time.perf_counter() - t0


# ----------------------------------------------------------------------------- estimators (one recording)


def _lsq_pair(residuals, omega, lr, err, mask, d1, d2, kernel, start, spectrum, solver="optimistix"):
    offsets, log_w = kernel_log_weights(omega, kernel, spectrum)
    args = (jnp.asarray(omega), jnp.asarray(np.where(mask, lr, 0.0)), jnp.asarray(np.where(mask, err, 1.0)),
            jnp.asarray(mask), d1, d2, jnp.asarray(offsets), jnp.asarray(log_w))
    theta0 = jnp.log(jnp.asarray([start[0], start[1], 1.0]))
    res = least_squares(residuals, theta0, args, jnp.array([True, True, False]), solver=solver)
    th = np.exp(np.asarray(res.theta))
    ok = bool(res.converged)
    return float(th[0]), float(th[1]), ok


A_MAX = _A_BOUNDS[1]          # the joint fit's upper bound on a (m): beyond it a is "not measured"


def _a_or_nan(a, a_err):
    """The radius, or NaN when the window is too weak to measure it (a_err > a / 2: the joint fit's rule)."""
    return a if (a_err is not None and np.isfinite(a_err) and a_err <= 0.5 * a) else np.nan


def pair_methods(x, d1, d2, kernel, bin_factor, spectrum, leakage, slow=True):
    """All single-pair estimators on one x pair: {method: (v, a, ok, seconds)}; ``slow``: also jaxopt and Hertz.

    spectrum: the shallow spectrum that weights the spectral window (``shallow_seen``).
    leakage: the pair's ``pair_fit.Leakage`` (``pair_leakage``).
    """
    omega, lr, err, mask = x
    out = {}
    line, t = _timed(slope_speed, omega, lr, err, mask, d1, d2, bin_factor)
    a_line = float(radius_from_offset(float(line.intercept), d1, d2))
    out["slope (Eq. 6)"] = (float(line.speed), a_line, bool(line.ok), t)
    start = (float(line.speed) if bool(line.ok) else 0.01, a_line if np.isfinite(a_line) else 2e-3)
    t0 = time.perf_counter()
    f = fit_pair(omega, lr, err, mask, d1, d2, kernel=kernel, bin_factor=bin_factor, spectrum=spectrum,
                 leakage=leakage)
    out["exact LS"] = (f.speed, _a_or_nan(f.a, f.a_err), f.converged, time.perf_counter() - t0)
    t0 = time.perf_counter()
    f = fit_pair(omega, lr, err, mask, d1, d2, kernel=kernel, bin_factor=bin_factor, spectrum=spectrum)
    out["exact LS window average"] = (f.speed, _a_or_nan(f.a, f.a_err), f.converged, time.perf_counter() - t0)
    t0 = time.perf_counter()
    v_r, a_r, ok_r = _lsq_pair(rough_residuals, omega, lr, err, mask, d1, d2, kernel, start, spectrum)
    # the rough curve's offset 3 (d2^2 - d1^2) / (2 a^2) can fit to ~0: a runs off to metres, i.e. not measured
    out["rough LS (Eq. 26)"] = (v_r, a_r if a_r <= A_MAX else np.nan, ok_r, time.perf_counter() - t0)
    if slow:
        t0 = time.perf_counter()
        f = fit_pair(omega, lr, err, mask, d1, d2, kernel=kernel, bin_factor=bin_factor, spectrum=spectrum,
                     leakage=leakage, solver="jaxopt")
        out["exact LS jaxopt"] = (f.speed, _a_or_nan(f.a, f.a_err), f.converged, time.perf_counter() - t0)
        t0 = time.perf_counter()
        r = _lsq_pair(hertz_residuals, omega, lr, err, mask, d1, d2, kernel, start, spectrum)
        out["hertz LS"] = (*r, time.perf_counter() - t0)
    return out


# ----------------------------------------------------------------------------- float32 worker (x64 off)


def float32_worker(npz_path, out_path):
    data = np.load(npz_path)
    signals, fs, depths = data["signals"].astype(np.float32), float(data["fs"]), tuple(data["depths"])
    joint_idx = set(int(i) for i in data["joint"])
    npersegs = data["nperseg"]
    d1, d2 = depths
    rows = []
    for i in range(signals.shape[0]):
        spec, ratio, band = pair_data(signals[i], fs, int(npersegs[i]))
        x = (np.asarray(ratio.omega), np.asarray(ratio.log_ratio[0]), np.asarray(ratio.log_ratio_err[0]),
             np.asarray(band[0]))
        t0 = time.perf_counter()
        f = fit_pair(*x, d1, d2, kernel=spec.kernel, bin_factor=spec.bin_factor, spectrum=shallow_seen(spec),
                     leakage=pair_leakage(spec, 0))
        row = {"i": i, "exact LS float32": [f.speed, _a_or_nan(f.a, f.a_err), f.converged, time.perf_counter() - t0]}
        if i in joint_idx:
            rec = Recording(signals[i], fs, depths)
            t0 = time.perf_counter()
            res = fit_recording(rec, FitOptions())
            row["joint float32"] = [res.vx, res.a, res.status == "ok", time.perf_counter() - t0, res.precision]
        rows.append(row)
        print(f"float32 worker: {i + 1}/{signals.shape[0]}", file=sys.stderr, flush=True)
    Path(out_path).write_text(json.dumps(rows))


# ----------------------------------------------------------------------------- the run


def run(args):
    grid = scene_grid(args.seeds, args.snr, args.speeds, args.radii, args.duration, not args.no_hertz)
    print(f"{len(grid)} recordings of {args.duration:g} s at 1 kHz", flush=True)
    recs = []
    t0 = time.perf_counter()
    for g in grid:
        recs.append(simulate(g["scene"]))
    sim_s = time.perf_counter() - t0
    print(f"simulated in {sim_s:.0f} s", flush=True)
    fs, (d1, d2) = recs[0].fs, recs[0].depths
    signals = np.stack([np.asarray(r.signals, float) for r in recs])
    npersegs = [resolution_nperseg(signals[i], fs, (d1, d2)) for i in range(len(recs))]

    # joint-fit subset: Gaussian scenes, first seed, SNR >= 30 (and one 10-20 dB scene per speed)
    joint = [i for i, g in enumerate(grid) if g["window"] == "gaussian" and g["rep"] == 0
             and (g["snr_db"] >= 30 or g["a"] == args.radii[0])]
    joint = joint[:: max(1, len(joint) // args.joint_max)][: args.joint_max] if args.joint_max else []
    mcmc = joint[: args.mcmc_max]

    # float32 subprocess first (it runs while nothing else of ours does)
    f32 = {}
    if not args.no_float32:
        npz = args.out / "speed_vs_error_signals.npz"
        np.savez(npz, signals=signals.astype(np.float32), fs=fs, depths=np.array([d1, d2]), nperseg=np.array(npersegs),
                 joint=np.array(joint[: args.joint32_max], int))
        res_path = args.out / "speed_vs_error_float32.json"
        t0 = time.perf_counter()
        subprocess.run([sys.executable, str(Path(__file__).resolve()), "--float32-worker", str(npz), str(res_path)],
                       check=True)
        print(f"float32 worker done in {time.perf_counter() - t0:.0f} s", flush=True)
        f32 = {r["i"]: r for r in json.loads(res_path.read_text())}
        npz.unlink()

    # spectra: single (timed per recording) and batched
    rows = []
    spectra_s = []
    for n in sorted(set(npersegs)):
        jax.block_until_ready(pair_data(signals[0], fs, n)[2])             # compile each segment length
    for i, g in enumerate(grid):
        t0 = time.perf_counter()
        spec, ratio, band = pair_data(signals[i], fs, npersegs[i])
        jax.block_until_ready(band)
        spectra_s.append(time.perf_counter() - t0)
        x = (np.asarray(ratio.omega), np.asarray(ratio.log_ratio[0]), np.asarray(ratio.log_ratio_err[0]),
             np.asarray(band[0]))
        rows.append({"grid": g, "x": x, "kernel": spec.kernel, "bin_factor": float(spec.bin_factor), "est": {},
                     "bin_corr_white": spec.bin_corr,
                     "spectrum": shallow_seen(spec), "leakage": pair_leakage(spec, 0),
                     "nperseg": npersegs[i],
                     "slow": g["window"] == "hertz"})
    batch_spectra_s = 0.0
    for n in sorted(set(npersegs)):
        sub = signals[[i for i in range(len(rows)) if npersegs[i] == n]]
        _timed(pair_data, sub, fs, n)                                       # compile + run
        batch_spectra_s += _timed(pair_data, sub, fs, n)[1]

    # single-pair methods (first recording twice: compile, then timed)
    compile_s = {}
    seen = set()
    for r in rows:
        if r["nperseg"] not in seen:                                        # compile for this shape
            seen.add(r["nperseg"])
            slow = any(q["slow"] and q["nperseg"] == r["nperseg"] for q in rows)
            first = pair_methods(r["x"], d1, d2, r["kernel"], r["bin_factor"], r["spectrum"], r["leakage"], slow=slow)
            done = pair_methods(r["x"], d1, d2, r["kernel"], r["bin_factor"], r["spectrum"], r["leakage"], slow=slow)
            for name, val in first.items():
                compile_s[f"{name} (nperseg {r['nperseg']})"] = val[3] - done[name][3]
        r["est"].update(pair_methods(r["x"], d1, d2, r["kernel"], r["bin_factor"], r["spectrum"], r["leakage"],
                                     slow=r["slow"]))
    print("single-pair methods done", flush=True)

    # lmfit peer (its own spectra: scipy), and lmfit emcee on a subset
    for i, r in enumerate(rows):
        fit, ts, tf = peer_lmfit.run(signals[i], fs, d1, d2, r["nperseg"])
        r["est"]["lmfit peer"] = (fit.speed, _a_or_nan(fit.a, fit.a_err), fit.success, tf)
        r["peer_spectra_s"] = ts
        if i in mcmc:
            t0 = time.perf_counter()
            vm, am = peer_lmfit.emcee_mean(fit, steps=args.lmfit_emcee_steps, burn=args.lmfit_emcee_steps // 3)
            r["est"]["lmfit emcee mean"] = (vm, am, True, time.perf_counter() - t0)

    # batched exact LS: one vmapped least_squares over all recordings
    batch_exact_s = sum(_batched_exact([r for r in rows if r["nperseg"] == n], d1, d2) for n in seen)

    # joint fit and its variants on the subset
    for k, i in enumerate(joint):
        r, rec = rows[i], recs[i]
        for name, opts in (("joint 2-D", FitOptions()), ("joint 2-D jaxopt", FitOptions(solver="jaxopt"))):
            if name.endswith("jaxopt") and k >= args.jaxopt_max:
                continue
            t0 = time.perf_counter()
            res = fit_recording(rec, opts)
            dt = time.perf_counter() - t0
            if k == 0:                                                   # compile: refit for the timing
                compile_s[name] = dt
                t0 = time.perf_counter()
                res = fit_recording(rec, opts)
                dt = time.perf_counter() - t0
                compile_s[name] -= dt
            r["est"][name] = (res.vx, res.a if res.a is not None else np.nan, res.status == "ok", dt)
            r.setdefault("status", {})[name] = res.status
            if name == "joint 2-D" and res.problem is not None:
                # joint-model bound at the true |vx| and a (|vy| = 0 and the texture knots at their fit)
                th = np.asarray(res.problem.theta, float).copy()
                th[0], th[2] = np.log(r["grid"]["speed"]), np.log(r["grid"]["a"])
                jb = joint_crb(th, res.data, np.asarray(res.problem.free), bin_factor=r["bin_factor"])
                r["crb_joint_v"], r["crb_joint_a"] = float(jb.speed_sd[0]), float(jb.a_sd)
            if name == "joint 2-D" and i in mcmc and res.problem is not None:
                from tactile_jax.posterior import run_emcee

                n_walkers = 2 * int(np.sum(res.problem.free)) + 2
                t0 = time.perf_counter()
                post = run_emcee(res.problem, n_walkers=n_walkers, n_steps=args.emcee_steps, seed=0)
                dt = time.perf_counter() - t0
                s = post.summary()
                r["est"]["joint emcee mean"] = (float(s["vx"]["mean"]), float(s["a"]["mean"]), True, dt)
        print(f"joint {k + 1}/{len(joint)}", flush=True)
    for i, r in enumerate(rows):
        if i in f32:
            r["est"]["exact LS float32"] = tuple(f32[i]["exact LS float32"])
            if "joint float32" in f32[i]:
                v, a, ok, dt, _ = f32[i]["joint float32"]
                r["est"]["joint 2-D float32"] = (v, a if a is not None else np.nan, ok, dt)

    # Cramer-Rao bounds at the truth (Gaussian model), for comparison: per recording from its per-bin errors
    # of noise alone (the Bendat-Piersol error less the slope of R's share, pair_fit.noise_err, with the
    # centroid term in the model), bins taken as independent ("_indep", session 8's); with the Bendat-Piersol
    # errors as they are and no centroid term ("_bp", sessions 5-7); with the white-noise bin_factor (1.94:
    # "_white"); with the neighbour correlation each recording's jackknife measures ("_jk"). The main one,
    # the cell's noise, follows
    for i, r in enumerate(rows):
        g = r["grid"]
        omega, _, err, mask = r["x"]
        loo = estimate_spectra(signals[i], fs, method="welch", prewhiten=PREWHITEN, nperseg=npersegs[i],
                               leave_one_out=True)
        rho = bin_correlation(np.asarray(amplitude_ratio(loo).log_ratio[:, 0]), mask, max_lag=2)
        r["bin_corr"] = [float(x) for x in rho]
        lk = {"leakage": r["leakage"]}
        for suffix, kw in (("_indep", lk), ("_bp", {}), ("_white", {"bin_factor": r["bin_factor"], **lk}),
                           ("_jk", {"bin_corr": np.nan_to_num(rho), **lk})):
            b = pair_crb(omega, err, mask, d1, d2, g["speed"], g["a"], kernel=r["kernel"], spectrum=r["spectrum"], **kw)
            r["crb_v" + suffix], r["crb_a" + suffix] = float(b.speed_sd[0]), float(b.a_sd)
        r["noise_var"] = np.where(mask, noise_err(omega, err, mask, g["speed"], g["a"], d1, d2, r["leakage"]) ** 2,
                                  np.nan)
    # the bound of each cell's noise: the noise-alone variance of each bin averaged over the cell's
    # recordings (one recording's estimate has ~K degrees of freedom, and 1 / var over-counts information),
    # neighbouring bins correlated as the estimator's white-noise estimates are (CrossSpectra.bin_corr)
    cells = {}
    for i, r in enumerate(rows):
        g = r["grid"]
        cells.setdefault((g["window"], g["snr_db"], g["speed"], g["a"], npersegs[i]), []).append(r)
    for members in cells.values():
        errs = cell_noise_err([r.pop("noise_var") for r in members])
        for r, err in zip(members, errs):
            g = r["grid"]
            omega, _, _, mask = r["x"]
            b = pair_crb(omega, np.where(mask, err, 1.0), mask, d1, d2, g["speed"], g["a"], kernel=r["kernel"],
                         spectrum=r["spectrum"], leakage=r["leakage"], noise_alone=True, bin_corr=r["bin_corr_white"])
            r["crb_v"], r["crb_a"] = float(b.speed_sd[0]), float(b.a_sd)
    rho = np.array([r["bin_corr"] for r in rows], float)
    print("log-ratio error correlation between bins (jackknife), median [p10, p90]: "
          + ", ".join(f"lag {j + 1}: {np.nanmedian(rho[:, j]):+.2f} [{np.nanpercentile(rho[:, j], 10):+.2f}, "
                      f"{np.nanpercentile(rho[:, j], 90):+.2f}]" for j in range(rho.shape[1])), flush=True)
    timing = {"simulate_s": sim_s, "spectra_single_ms": 1e3 * float(np.median(spectra_s)),
              "spectra_batched_ms_per_rec": 1e3 * batch_spectra_s / len(rows),
              "peer_spectra_ms": 1e3 * float(np.median([r["peer_spectra_s"] for r in rows])),
              "exact_LS_batched_ms_per_rec": 1e3 * batch_exact_s / len(rows),
              "slope_batched_ms_per_rec": 1e3 * sum(_batched_slope([r for r in rows if r["nperseg"] == n], d1, d2)
                                                    for n in set(npersegs)) / len(rows),
              "nperseg_counts": {str(n): npersegs.count(n) for n in sorted(set(npersegs))},
              "compile_s": compile_s}
    return rows, timing


def _batched_exact(rows, d1, d2):
    weighted = [kernel_log_weights(r["x"][0], r["kernel"], r["spectrum"]) for r in rows]
    offsets = jnp.asarray(weighted[0][0])
    log_w = jnp.asarray(np.stack([w[1] for w in weighted]))

    def one(theta0, y, err, mask, omega, lw):
        args = (omega, y, err, mask, d1, d2, offsets, lw)
        return least_squares(exact_residuals, theta0, args, jnp.array([True, True, False]))

    batched = jax.jit(jax.vmap(one))
    x = [r["x"] for r in rows]
    omega = jnp.asarray(np.stack([a[0] for a in x]))
    y = jnp.asarray(np.stack([np.where(a[3], a[1], 0.0) for a in x]))
    err = jnp.asarray(np.stack([np.where(a[3], a[2], 1.0) for a in x]))
    mask = jnp.asarray(np.stack([a[3] for a in x]))
    starts = np.array([[r["est"]["slope (Eq. 6)"][0], r["est"]["slope (Eq. 6)"][1], 1.0] for r in rows])
    starts = np.where(np.isfinite(starts) & (starts > 0), starts, [[0.01, 2e-3, 1.0]])
    theta0 = jnp.log(jnp.asarray(starts))
    _timed(batched, theta0, y, err, mask, omega, log_w)                     # compile
    res, dt = _timed(batched, theta0, y, err, mask, omega, log_w)
    sd_log_a = np.sqrt(np.clip(np.asarray(res.cov)[:, 1, 1] * np.maximum(1.0, 1.0 / np.asarray(res.redchi))
                               * rows[0]["bin_factor"], 0, None))
    for r, th, ok, sa in zip(rows, np.exp(np.asarray(res.theta)), np.asarray(res.converged), sd_log_a):
        r["est"]["exact LS batched"] = (float(th[0]), _a_or_nan(float(th[1]), float(th[1] * sa)), bool(ok),
                                        dt / len(rows))
    return dt


def _batched_slope(rows, d1, d2):
    x = [r["x"] for r in rows]
    arrs = [jnp.asarray(np.stack([a[k] for a in x])) for k in range(4)]
    _timed(slope_speed, arrs[0][0], arrs[1], arrs[2], arrs[3], d1, d2)
    _, dt = _timed(slope_speed, arrs[0][0], arrs[1], arrs[2], arrs[3], d1, d2)
    return dt


# ----------------------------------------------------------------------------- summaries


def summarise(rows, timing, snr_groups):
    methods = sorted({m for r in rows for m in r["est"]}, key=lambda m: list(METHOD_ORDER).index(m)
                     if m in METHOD_ORDER else 99)
    ref_t = np.median([r["est"][REFERENCE][3] for r in rows if REFERENCE in r["est"]])
    out = []
    for window in ("gaussian", "hertz"):
        for label, (lo, hi) in snr_groups.items():
            sel = [r for r in rows if r["grid"]["window"] == window and lo <= r["grid"]["snr_db"] <= hi]
            if not sel:
                continue
            for m in methods:
                have = [r for r in sel if m in r["est"]]
                if not have:
                    continue
                v = np.array([r["est"][m][0] if r["est"][m][0] is not None else np.nan for r in have], float)
                a = np.array([r["est"][m][1] if r["est"][m][1] is not None else np.nan for r in have], float)
                vt = np.array([r["grid"]["speed"] for r in have])
                at = np.array([r["grid"]["a"] for r in have])
                ok = np.array([bool(r["est"][m][2]) for r in have]) & np.isfinite(v)
                t = np.array([r["est"][m][3] for r in have])
                ev, ea = (v - vt) / vt, (a - at) / at
                fv, fa = np.isfinite(ev) & ok, np.isfinite(ea) & ok           # errors of converged estimates
                row = {"window": window, "snr": label, "method": m, "n": len(have), "n_ok": int(ok.sum()),
                       "time_ms": 1e3 * float(np.median(t)), "x_ref": float(np.median(t) / ref_t),
                       "v_bias_pct": 100 * float(np.mean(ev[fv])) if fv.any() else np.nan,
                       "v_rmse_pct": 100 * float(np.sqrt(np.mean(ev[fv] ** 2))) if fv.any() else np.nan,
                       "a_bias_pct": 100 * float(np.mean(ea[fa])) if fa.any() else np.nan,
                       "a_rmse_pct": 100 * float(np.sqrt(np.mean(ea[fa] ** 2))) if fa.any() else np.nan,
                       "n_v": int(fv.sum()), "n_a": int(fa.sum())}
                if window == "gaussian":
                    cv = np.array([r["crb_v"] for r in have])
                    ca = np.array([r["crb_a"] for r in have])
                    zv = np.where(ok, ((v - vt) / cv) ** 2, np.nan)
                    za = np.where(ok, ((a - at) / ca) ** 2, np.nan)
                    row["eff_v"] = float(1 / np.mean(zv[np.isfinite(zv)])) if np.isfinite(zv).any() else np.nan
                    row["eff_a"] = float(1 / np.mean(za[np.isfinite(za)])) if np.isfinite(za).any() else np.nan
                    for suffix in ("_indep", "_bp", "_white", "_jk"):
                        for q, est, true in (("v", v, vt), ("a", a, at)):
                            crb = np.array([r[f"crb_{q}{suffix}"] for r in have])
                            z = np.where(ok, ((est - true) / crb) ** 2, np.nan)
                            row[f"eff_{q}{suffix}"] = float(1 / np.mean(z[np.isfinite(z)])) if np.isfinite(z).any() else np.nan
                    row["crb_v_pct"] = 100 * float(np.median(cv / vt))
                    row["crb_a_pct"] = 100 * float(np.median(ca / at))
                    if m.startswith("joint") and all("crb_joint_v" in r for r in have):
                        jv = ((v - vt) / np.array([r["crb_joint_v"] for r in have])) ** 2
                        ja = ((a - at) / np.array([r["crb_joint_a"] for r in have])) ** 2
                        jv, ja = jv[ok & np.isfinite(jv)], ja[ok & np.isfinite(ja)]
                        row["eff_v_joint_crb"] = float(1 / np.mean(jv)) if jv.size else np.nan
                        row["eff_a_joint_crb"] = float(1 / np.mean(ja)) if ja.size else np.nan
                        row["crb_joint_v_pct"] = 100 * float(np.median([r["crb_joint_v"] for r in have] / vt))
                        row["crb_joint_a_pct"] = 100 * float(np.median([r["crb_joint_a"] for r in have] / at))
                out.append(row)
    return out


METHOD_ORDER = ("slope (Eq. 6)", "rough LS (Eq. 26)", "exact LS", "exact LS window average", "exact LS batched",
                "exact LS jaxopt", "exact LS float32", "hertz LS", "lmfit peer", "lmfit emcee mean", "joint 2-D", "joint 2-D jaxopt",
                "joint 2-D float32", "joint emcee mean")


def print_table(summary):
    hdr = (f"{'window':8s} {'SNR':9s} {'method':20s} {'n':>3s} {'ok':>3s} {'ms/rec':>9s} {'x ref':>7s} "
           f"{'|v| bias%':>9s} {'|v| rmse%':>9s} {'a bias%':>8s} {'a rmse%':>8s} {'eff v':>6s} {'eff a':>6s}")
    print(hdr)
    for s in summary:
        print(f"{s['window']:8s} {s['snr']:9s} {s['method']:20s} {s['n']:3d} {s['n_ok']:3d} {s['time_ms']:9.2f} "
              f"{s['x_ref']:7.2f} {s['v_bias_pct']:+9.2f} {s['v_rmse_pct']:9.2f} {s['a_bias_pct']:+8.1f} "
              f"{s['a_rmse_pct']:8.1f} {s.get('eff_v', np.nan):6.2f} {s.get('eff_a', np.nan):6.2f}")


def markdown_table(summary, snr_label):
    """The README table: one SNR group, Gaussian and Hertz windows."""
    lines = ["| window | method | n (converged, a given) | ms / recording | x exact LS | \\|v\\| bias % | \\|v\\| RMSE % "
             "| a bias % | a RMSE % | CRB/MSE \\|v\\| | CRB/MSE a |", "|" + "---|" * 11]
    for s in summary:
        if s["snr"] != snr_label:
            continue
        def f(x, fmt):
            return "-" if x is None or not np.isfinite(x) else format(x, fmt)
        lines.append(f"| {s['window']} | {s['method']} | {s['n']} ({s['n_ok']}, {s['n_a']}) | {f(s['time_ms'], '.3g')} | "
                     f"{f(s['x_ref'], '.2g')} | {f(s['v_bias_pct'], '+.2f')} | {f(s['v_rmse_pct'], '.2f')} | "
                     f"{f(s['a_bias_pct'], '+.1f')} | {f(s['a_rmse_pct'], '.1f')} | {f(s.get('eff_v'), '.2f')} | "
                     f"{f(s.get('eff_a'), '.2f')} |")
    return "\n".join(lines)


def pareto_figure(summary, path, label, timing):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tactile_jax.plotting import provenance

    sel = [s for s in summary if s["window"] == "gaussian" and s["snr"] == label]
    colours = {m: plt.cm.tab20(i % 20) for i, m in enumerate(METHOD_ORDER)}
    fig, axes = plt.subplots(1, 2, figsize=(12, 5.2))
    cap = 300.0                                                              # % : beyond, drawn at the edge
    for ax, key, name in ((axes[0], "v_rmse_pct", "|v|"), (axes[1], "a_rmse_pct", "a")):
        for s in sel:
            if not np.isfinite(s[key]):
                continue
            y, off = min(s[key], cap), s[key] > cap
            ax.scatter(s["time_ms"], y, s=36, color=colours.get(s["method"], "k"), marker="^" if off else "o")
            ax.annotate(s["method"] + (f" ({s[key]:.2g} %)" if off else ""), (s["time_ms"], y), fontsize=7,
                        xytext=(3, 3), textcoords="offset points")
        crb = np.median([s["crb_v_pct" if name == "|v|" else "crb_a_pct"] for s in sel])
        ax.axhline(crb, color="k", ls=":", lw=1, label=f"Cramer-Rao bound (median) {crb:.2g} %")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("time per recording after compilation, ms (estimator only; median)")
        ax.set_ylabel(f"RMSE of {name}, % of truth")
        ax.set_title(f"{name}: Gaussian window, SNR {label} dB")
        ax.legend(fontsize=8)
        ax.grid(True, which="both", alpha=0.3)
    fig.suptitle(f"Speed vs error (spectra: {timing['spectra_single_ms']:.1f} ms per recording, not included)")
    fig.text(0.01, 0.01, provenance(), fontsize=7)
    fig.tight_layout(rect=(0, 0.03, 1, 0.97))
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--float32-worker":
        float32_worker(argv[1], argv[2])
        return
    if argv and argv[0] == "--table-from":                 # re-render tables and figure from a saved run
        saved = json.loads(Path(argv[1]).read_text())
        for label in ("10-20", ">=30"):
            print(f"\nSNR {label} dB\n" + markdown_table(saved["summary"], label))
        if len(argv) > 2:
            pareto_figure(saved["summary"], Path(argv[2]), ">=30", saved["timing"])
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--snr", type=float, nargs="+", default=[10.0, 20.0, 30.0, 45.0, 60.0])
    ap.add_argument("--speeds", type=float, nargs="+", default=[0.015, 0.04], help="m/s")
    ap.add_argument("--radii", type=float, nargs="+", default=[1.5e-3, 4e-3], help="m")
    ap.add_argument("--duration", type=float, default=8.0)
    ap.add_argument("--joint-max", type=int, default=4, help="recordings fitted with the joint model")
    ap.add_argument("--jaxopt-max", type=int, default=1)
    ap.add_argument("--joint32-max", type=int, default=1)
    ap.add_argument("--mcmc-max", type=int, default=2)
    ap.add_argument("--emcee-steps", type=int, default=200)
    ap.add_argument("--lmfit-emcee-steps", type=int, default=600)
    ap.add_argument("--no-hertz", action="store_true")
    ap.add_argument("--no-float32", action="store_true")
    ap.add_argument("--quick", action="store_true", help="no joint fits, no float32 subprocess")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/out"))
    args = ap.parse_args(argv)
    if args.quick:
        args.joint_max, args.no_float32 = 0, True
    args.out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    rows, timing = run(args)
    groups = {"10-20": (0, 25), ">=30": (29, 100)}
    groups.update({f"{s:g}": (s, s) for s in args.snr})
    summary = summarise(rows, timing, groups)
    print_table(summary)
    print(json.dumps(timing, indent=1))
    from tactile_jax.plotting import provenance

    png = args.out / "speed_vs_error.png"
    label = ">=30" if any(s["snr"] == ">=30" for s in summary) else next(iter(groups))
    pareto_figure(summary, png, label, timing)
    for lab in ("10-20", ">=30"):
        print(f"\nSNR {lab} dB\n" + markdown_table(summary, lab))
    per_rec = [{**{k: v for k, v in r["grid"].items() if k != "scene"}, "crb_v": r["crb_v"], "crb_a": r["crb_a"],
                "bin_corr": r["bin_corr"], "crb_v_bp": r["crb_v_bp"], "crb_a_bp": r["crb_a_bp"], "crb_v_white": r["crb_v_white"], "crb_a_white": r["crb_a_white"],
                "crb_v_jk": r["crb_v_jk"], "crb_a_jk": r["crb_a_jk"],
                "crb_joint_v": r.get("crb_joint_v"), "crb_joint_a": r.get("crb_joint_a"), "nperseg": r["nperseg"],
                "est": {m: [None if (isinstance(x, float) and not np.isfinite(x)) else x for x in e]
                        for m, e in r["est"].items()}, "status": r.get("status", {})} for r in rows]
    (args.out / "speed_vs_error.json").write_text(json.dumps(
        {"provenance": provenance(), "args": {k: str(v) for k, v in vars(args).items()}, "timing": timing,
         "summary": summary, "recordings": per_rec, "wall_s": time.perf_counter() - t_start},
        indent=1, default=float))
    print(f"wrote {png} and speed_vs_error.json; wall {time.perf_counter() - t_start:.0f} s")


if __name__ == "__main__":
    main()
