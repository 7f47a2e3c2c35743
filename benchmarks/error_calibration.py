"""Are the pair fit's error bars the scatter it really has? (issues #3 and #5)

For a few fixed scenes (slip along x, 8 s at 1 kHz, prewhitened Welch at the
segment a pair fit gets, ``fit.resolution_segment``) this simulates R texture-and-noise
realisations and compares, for the exact-R pair fit (``pair_fit.fit_pair``):

- the stated one-sigma error of |v| and a (Bendat-Piersol per-bin errors, the
  covariance times ``CrossSpectra.bin_factor`` = 1.94 for Hann Welch);
- the scatter the estimates actually have across realisations;
- a linearised delete-one-segment jackknife of the same fit: the log ratio
  recomputed with each Welch segment left out (``estimate_spectra(...,
  leave_one_out=True)``), pushed through the fit's Gauss-Newton map at the
  estimate (``jackknife.linear_shifts``, overlap n_segments / dof put back);
- the per-bin check (log-ratio scatter over its stated error) and the
  correlation of the log ratio's errors between adjacent bins, which the
  constant 1.94 assumes to be 4/9 (white noise through a Hann window): across
  realisations (rho1, rho2), and as each recording's jackknife measures it
  (jk1, jk2: ``jackknife.bin_correlation``, median over realisations), the
  input of the Cramer-Rao bound in ``speed_vs_error``.

    python benchmarks/error_calibration.py --reps 16 --out benchmarks/out
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import NamedTuple

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from tactile_jax import jackknife  # noqa: E402
from tactile_jax.fit import MIN_PAIR_BAND_BINS, FitOptions, _resolution_nperseg  # noqa: E402
from tactile_jax.pair_fit import _residuals, fit_pair  # noqa: E402
from tactile_jax.plotting import provenance  # noqa: E402
from tactile_jax.scene import Scene, simulate  # noqa: E402
from tactile_jax.spectra import amplitude_ratio, default_nperseg, estimate_spectra, usable_band  # noqa: E402
from tactile_jax.texture import RandomTexture  # noqa: E402

D1, D2 = 0.265e-3, 0.925e-3
PREWHITEN = 8
#: (|v| m/s, a m, SNR dB)
SCENES = ((0.04, 1.5e-3, 45.0), (0.04, 1.5e-3, 30.0), (0.04, 4e-3, 45.0), (0.015, 1.5e-3, 60.0), (0.015, 4e-3, 45.0))


def pair_args(omega, err, mask, kernel):
    """``pair_fit._residuals``' data tuple without the measured ratio (``y`` goes in apart)."""
    offsets, weights = (np.asarray(k, float) for k in kernel)
    keep = weights > 0
    return _PairData(jnp.asarray(omega), jnp.zeros(np.size(omega)), jnp.asarray(err), jnp.asarray(mask),
                     jnp.asarray(offsets[keep]), jnp.asarray(np.log(weights[keep])))


class _PairData(NamedTuple):
    omega: jax.Array
    y: jax.Array
    err: jax.Array
    mask: jax.Array
    offsets: jax.Array
    log_w: jax.Array


def _pair_residuals(theta, data):
    return _residuals(theta, (data.omega, data.y, data.err, data.mask, D1, D2, data.offsets, data.log_w))


def jackknife_sd(fit, log_ratio, data, loo, overlap):
    """Linearised jackknife one-sigma errors of (|v|, a) for a converged pair fit (``jackknife``)."""
    theta = jnp.log(jnp.array([fit.speed, fit.a, 1.0]))
    y = jnp.where(data.mask, jnp.asarray(loo), 0.0)
    shifts, _ = jackknife.linear_shifts(_pair_residuals, theta, data._replace(y=jnp.asarray(log_ratio)), {"y": y},
                                        jnp.array([True, True, False]))
    cov = jackknife.covariance(shifts, overlap=overlap)
    return np.array([fit.speed, fit.a]) * np.sqrt(np.diag(cov)[:2])


def run_scene(speed, a, snr, reps, seed0=900):
    rows, ratios, errs, masks = [], [], [], []
    nperseg = None
    for r in range(reps):
        rec = simulate(Scene(texture=RandomTexture(), velocity=(speed, 0.0), contact_radius=a, duration=8.0,
                             fs=1000.0, snr_db=snr, seed=seed0 + r))
        x = np.asarray(rec.signals, float)
        if nperseg is None:              # the segment fit_recording picks for the first realisation
            spec = estimate_spectra(x, rec.fs, prewhiten=PREWHITEN)
            nperseg = (_resolution_nperseg(spec, (D1, D2), x.shape[-1], FitOptions(), min_band_bins=MIN_PAIR_BAND_BINS)
                       or default_nperseg(x.shape[-1]))
        spec = estimate_spectra(x, rec.fs, prewhiten=PREWHITEN, nperseg=nperseg)
        ratio = amplitude_ratio(spec)
        band = np.asarray(usable_band(ratio))[0]
        omega, lr, err = (np.asarray(v) for v in (ratio.omega, ratio.log_ratio[0], ratio.log_ratio_err[0]))
        fit = fit_pair(omega, lr, err, band, D1, D2, kernel=spec.kernel, bin_factor=spec.bin_factor)
        loo_spec = estimate_spectra(x, rec.fs, prewhiten=PREWHITEN, nperseg=nperseg, leave_one_out=True)
        loo = np.asarray(amplitude_ratio(loo_spec).log_ratio[:, 0])
        jk = jackknife_sd(fit, lr, pair_args(omega, err, band, spec.kernel), loo, spec.n_segments / spec.dof)
        rho_jk = jackknife.bin_correlation(loo, band, max_lag=2)
        rows.append({"v": fit.speed, "v_err": fit.speed_err, "a": fit.a, "a_err": fit.a_err, "v_jk": jk[0],
                     "a_jk": jk[1], "n_bins": int(band.sum()), "converged": fit.converged, "k": loo.shape[0],
                     "rho_jk": [float(r) for r in rho_jk]})
        ratios.append(lr)
        errs.append(err)
        masks.append(band)
    lr, err, mask = np.array(ratios), np.array(errs), np.array(masks)
    common = mask.all(axis=0)
    dev = lr[:, common] - lr[:, common].mean(axis=0)
    z = dev / dev.std(axis=0, ddof=1)
    corr = [float(np.mean(z[:, :-j] * z[:, j:])) if z.shape[1] > j else np.nan for j in (1, 2)]
    per_bin = float(np.median(dev.std(axis=0, ddof=1) / np.sqrt(np.mean(err[:, common] ** 2, axis=0))))
    out = {"speed": speed, "a": a, "snr_db": snr, "nperseg": nperseg, "reps": reps, "segments": rows[0]["k"],
           "bins_median": float(np.median([q["n_bins"] for q in rows])), "per_bin_scatter_over_stated": per_bin,
           "corr_lag1": corr[0], "corr_lag2": corr[1],
           "corr_jk_lag1": float(np.nanmedian([q["rho_jk"][0] for q in rows])),
           "corr_jk_lag2": float(np.nanmedian([q["rho_jk"][1] for q in rows])), "rows": rows}
    for name, truth in (("v", speed), ("a", a)):
        est = np.array([q[name] for q in rows])
        out[f"{name}_bias_pct"] = 100 * float(est.mean() / truth - 1)
        out[f"{name}_sd_pct"] = 100 * float(est.std(ddof=1) / truth)
        out[f"{name}_stated_pct"] = 100 * float(np.sqrt(np.mean(np.square([q[f'{name}_err'] for q in rows]))) / truth)
        out[f"{name}_jk_pct"] = 100 * float(np.sqrt(np.mean(np.square([q[f'{name}_jk'] for q in rows]))) / truth)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--reps", type=int, default=16)
    ap.add_argument("--out", type=Path, default=Path("benchmarks/out"))
    args = ap.parse_args()
    print(provenance())
    print(f"{'|v| cm/s':>8} {'a mm':>5} {'SNR':>4} {'nperseg':>7} {'K':>3} {'bins':>4} | "
          f"{'per-bin':>7} {'rho1':>6} {'rho2':>6} {'jk1':>6} {'jk2':>6} | {'v bias':>7} {'v sd':>6} {'stated':>6} {'jackkn':>6} | "
          f"{'a sd':>6} {'stated':>6} {'jackkn':>6}   (% of truth)")
    results = []
    for speed, a, snr in SCENES:
        s = run_scene(speed, a, snr, args.reps)
        results.append(s)
        print(f"{100 * speed:8.1f} {1e3 * a:5.1f} {snr:4.0f} {s['nperseg']:7d} {s['segments']:3d} "
              f"{s['bins_median']:4.0f} | {s['per_bin_scatter_over_stated']:7.2f} {s['corr_lag1']:+6.2f} "
              f"{s['corr_lag2']:+6.2f} {s['corr_jk_lag1']:+6.2f} {s['corr_jk_lag2']:+6.2f} | {s['v_bias_pct']:+7.2f} {s['v_sd_pct']:6.2f} {s['v_stated_pct']:6.2f} "
              f"{s['v_jk_pct']:6.2f} | {s['a_sd_pct']:6.2f} {s['a_stated_pct']:6.2f} {s['a_jk_pct']:6.2f}",
              flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "error_calibration.json").write_text(json.dumps({"provenance": provenance(), "reps": args.reps,
                                                                 "scenes": results}, indent=1))


if __name__ == "__main__":
    main()
