"""Joint fit on simulated scenes: recovery with honest error bars, fixed parameters, failure as data.

A small seeded version of benchmarks/coverage.py; every scene shares the
compiled programs (16 s at 1 kHz, default options).
"""

import dataclasses
import os

import numpy as np
import pytest

from tactile_jax import joint_model as jm
from tactile_jax.fit import FitOptions, FitResult, _settled_physics, fit_cross_spectra, fit_recording
from tactile_jax.lsq import LsqResult
from tactile_jax.scene import Scene, simulate
from tactile_jax.spectra import estimate_spectra
from tactile_jax.texture import RandomTexture


def _scene(vx, vy, a, seed, snr=50.0):
    return Scene(texture=RandomTexture(), velocity=(vx, vy), contact_radius=a, snr_db=snr, seed=seed)


@pytest.fixture(scope="module")
def oblique():
    scene = _scene(0.036, 0.022, 1.5e-3, seed=11)
    return scene, fit_recording(simulate(scene))


@pytest.fixture(scope="module")
def oblique_pairs(oblique):
    """The same recording without the cross-pair chain (``cross_pairs=0``): each pair's own spectra, the
    model the conditioned PSD's tests study (with the chain, the y pair's S22.1 is the chain's)."""
    scene, _ = oblique
    return scene, fit_recording(simulate(scene), FitOptions(cross_pairs=0))


def test_oblique_slip_small_contact_recovered(oblique):
    scene, res = oblique
    assert res.status == "ok" and res.converged, res.message
    speed = float(np.hypot(*scene.velocity))
    for got, err, true in ((res.vx, res.vx_err, scene.velocity[0]), (res.vy, res.vy_err, scene.velocity[1])):
        assert abs(got - true) < 0.03 * speed            # target 2 % of |v|; see the issue note for the tail
        assert abs(got - true) < 4 * err
    assert abs(res.a - scene.a) < 0.05 * scene.a and abs(res.a - scene.a) < 4 * res.a_err
    assert res.contact_depth == pytest.approx(res.a ** 2 / 0.03)
    assert res.contact_depth_err == pytest.approx(2 * res.a * res.a_err / 0.03)
    # texture cross-sections with error bars, on k = omega / |v|
    assert res.texture_x is not None and np.all(np.isfinite(res.texture_x.log_power_err))
    assert np.all(res.texture_x.power > 0)
    row = res.to_record()
    for key in ("vx", "vx_err", "vy", "vy_err", "a", "a_err", "contact_depth", "model", "window", "status"):
        assert key in row
    # error bars scaled by the recording's own delete-one-segment jackknife
    jk = res.jackknife
    assert res.error_method.startswith("laplace x jackknife") and row["error_scale"] == res.error_scale
    assert set(jk["variance_ratio"]) == {"vx", "vy", "a"} and 0.2 < jk["pooled"] < 5
    assert res.error_scale == pytest.approx(max(jk["pooled"], res.redchi))
    # vx, vy and a each take their own jackknife ratio (test_joint_bound_counts_the_conditioned_psd checks
    # that the errors are the unit Laplace ones times these); the texture and gains the pooled one
    for name in ("vx", "vy", "a"):
        assert res.error_scales[name] == pytest.approx(max(jk["variance_ratio"][name], res.redchi)), name
    assert np.ptp(list(res.error_scales.values())) > 0.01


def test_the_joint_model_carries_the_realised_window_term(oblique):
    """Welch centroids enter the joint fit with ``FitOptions(window_term=True)``: the ratio moves by R' x shift,
    with R' the model's own slope across the bin (``joint_model.ratio_slope``, which the noise-alone
    errors take), and the ratio is weighted by those errors (``pair_fit.noise_err_from_slope``).
    The same compiled model as the default fit's (a zero shift there)."""
    scene, plain = oblique
    assert not np.any(np.asarray(plain.problem.args.centroid_shift))
    res = fit_recording(simulate(scene), FitOptions(window_term=True))
    assert res.status == "ok", res.message
    speed = float(np.hypot(*scene.velocity))
    assert abs(res.vx - plain.vx) < 0.01 * speed and abs(res.a - plain.a) < 2 * res.a_err
    data, theta = res.problem.args, np.asarray(res.problem.theta)
    used = np.asarray(data.mask_h)
    shift = np.asarray(data.centroid_shift)
    assert np.all(np.abs(shift[used]) < 1.0) and 0.03 < np.std(shift[used]) < 0.5    # bins
    slope = np.asarray(jm.ratio_slope(theta, data))
    assert np.mean(slope[used] < 0) > 0.9     # deep / shallow falls with omega (2-D: the y pair's rises at DC)
    _, with_term = jm.log_spectra(theta, data)
    _, without = jm.log_spectra(theta, data._replace(centroid_shift=None))
    np.testing.assert_allclose(np.asarray(with_term - without)[used], np.log1p(slope * shift)[used], atol=1e-9)
    ratio = np.asarray(data.h_err)[used] / np.asarray(res.spectrum["log_ratio_err"])[used]
    assert np.all(ratio >= np.sqrt(0.05) - 1e-9) and np.median(ratio) < 1.0   # floored; the slope's share out


def test_the_conditioned_deep_psd_is_fitted(oblique_pairs):
    """``FitOptions.conditioned``: each pair's S22.1 = S22 - |S12|^2 / S11, the deep power the shallow
    probe does not explain, joins the residuals. Under oblique slip through a 1.5 mm contact it is the 2-D
    incoherence of the modes on k . v = omega, far above the noise's share, and the model describes it.
    The default; ``conditioned=False`` runs the same compiled model with it masked out."""
    scene, res = oblique_pairs
    plain = fit_recording(simulate(scene), FitOptions(conditioned=False, cross_pairs=0))
    assert not np.any(np.asarray(plain.problem.args.mask_c22))
    assert res.status == "ok", res.message
    data, theta = res.problem.args, np.asarray(res.problem.theta)
    used = np.asarray(data.mask_c22)
    assert used.sum() >= 0.8 * np.asarray(data.mask_h).sum()
    n_l = data.omega.shape[0]
    r = np.asarray(jm.residuals(theta, data))[4 * n_l:6 * n_l].reshape(2, n_l)[used]
    assert abs(r.mean()) < 0.5 and np.mean(r ** 2) < 2.5, (r.mean(), np.mean(r ** 2))   # in sd of log S22.1
    # the model's incoherent power against white noise alone, in the used bins
    noise = np.exp(np.asarray(data.log_noise_c22)[:, 1:])
    model = np.exp(np.asarray(jm.log_conditioned(theta, data)))
    assert np.median((model / noise)[used]) > 10
    speed = float(np.hypot(*scene.velocity))
    for name, true in (("vx", scene.velocity[0]), ("vy", scene.velocity[1]), ("a", scene.a)):
        got, err = getattr(res, name), getattr(res, name + "_err")
        assert abs(got - true) < 4 * err, (name, got, err, true)
        # the Laplace errors before the jackknife's scale: information the ratio alone lacks
        unit = err / np.sqrt(res.error_scales[name])
        unit_plain = getattr(plain, name + "_err") / np.sqrt(plain.error_scales[name])
        assert unit < 0.95 * unit_plain, (name, unit / unit_plain)
    assert abs(res.vx - scene.velocity[0]) < 0.02 * speed and abs(res.vy - scene.velocity[1]) < 0.02 * speed


def test_joint_bound_counts_the_conditioned_psd(oblique_pairs):
    """``crb.joint_crb`` with the priors and no bin correlation, at the fitted parameters, is the fit's own
    unit Laplace covariance (J^T J)^-1, S22.1 block included; leaving S22.1 out loosens the bound."""
    from tactile_jax.crb import joint_crb
    _, res = oblique_pairs
    data, theta, free = res.problem.args, np.asarray(res.problem.theta), np.asarray(res.problem.free)
    bound = joint_crb(theta, data, free, include_priors=True)
    unit = np.array([getattr(res, n + "_err") / np.sqrt(res.error_scales[n]) for n in ("vx", "vy", "a")])
    got = np.concatenate([np.asarray(bound.speed_sd), [float(bound.a_sd)]])
    np.testing.assert_allclose(got, unit, rtol=0.02)
    ratio_only = joint_crb(theta, data._replace(log_c22=None), free, include_priors=True)
    assert np.all(np.asarray(ratio_only.speed_sd) > 1.05 * np.asarray(bound.speed_sd)), (ratio_only.speed_sd, got)


def test_the_cross_pair_spectra_hold_more_information(oblique_pairs):
    """``spectral_matrix``: its pair entries are ``joint_model``'s line integrals; its x-y entries make the
    lowest bins of the two pairs coherent, and ``crb.whittle_crb`` counts that information: the full 4 x 4
    bound is tighter than the pairs' 2 x 2 blocks alone (benchmarks/information.py has the figures)."""
    from tactile_jax.crb import whittle_crb
    from tactile_jax.spectral_matrix import spectral_matrix
    scene, res = oblique_pairs
    data, free = res.problem.args, np.asarray(res.problem.free)
    theta = np.asarray(res.problem.theta, float).copy()
    theta[:3] = np.log([scene.velocity[0], scene.velocity[1], scene.a])
    om = data.omega[2:20]
    s = np.asarray(spectral_matrix(theta, om, data.depths, data.log_k_knots, np.full(4, -300.0)))
    _, _, s22 = jm._pair_log_densities(om, *np.exp(theta[:3]), data.depths[0], data.depths[1], data.log_k_knots,
                                       theta[jm.N_FIXED_PARAMS:], True)
    np.testing.assert_allclose(np.log(s[:, [1, 3], [1, 3]]).T, np.asarray(s22) + [[0.0], [theta[5]]], atol=5e-3)
    assert s[0, 0, 2] ** 2 / (s[0, 0, 0] * s[0, 2, 2]) > 0.5                  # x1 and y1 near DC
    full, pairs = (whittle_crb(theta, data, free, cross=c, include_priors=True, n_s=3001) for c in (True, False))
    sd_full = np.append(np.asarray(full.speed_sd), float(full.a_sd))
    sd_pairs = np.append(np.asarray(pairs.speed_sd), float(pairs.a_sd))
    assert np.all(np.isfinite(sd_full)) and np.all(sd_full < 0.95 * sd_pairs), (sd_full, sd_pairs)
    # correlated bins (Welch's Hann bin_factor) divide the data's information: sd x sqrt(bin_factor), priors aside
    plain, shared = (whittle_crb(theta, data, free, bin_factor=b, n_s=3001) for b in (1.0, 1.94))
    np.testing.assert_allclose(np.asarray(shared.speed_sd), np.sqrt(1.94) * np.asarray(plain.speed_sd), rtol=1e-3)


def test_minor_component_gets_a_skewed_profile_interval():
    # slip 8.5 deg off x: the spectra depend on vy only through vy^2 (the line k.v = omega tilts
    # symmetrically), so vy's likelihood is skewed toward 0 and the Laplace error is too narrow
    scene = _scene(0.04, 0.006, 1.2e-3, seed=21)
    # the ratio alone: the deep probe's conditioned PSD and the x-y cross-spectra (the default chain) depend
    # on vy otherwise and even the profile out (with the chain, vy = 5.83 -0.24 / +0.25 mm/s on this scene)
    res = fit_recording(simulate(scene), FitOptions(conditioned=False, cross_pairs=0))
    assert res.status == "ok", res.message
    lo, hi, lo2, hi2 = res.vy_lo, res.vy_hi, res.vy_lo2, res.vy_hi2
    assert res.vx_lo is None and (res.vy_upper == hi2 if lo2 == 0 else res.vy_upper is None)
    assert 0 <= lo2 < lo < res.vy < hi < hi2
    assert res.vy - lo > hi - res.vy                        # the long side points to 0
    assert lo2 <= scene.velocity[1] <= hi2
    row = res.to_record()
    assert row["vy_lo"] == lo and row["vx_hi2"] is None
    assert "profile-likelihood" in res.message


@pytest.mark.skipif(not os.environ.get("TACTILE_JAX_SLOW"),
                    reason="its own bin-count bucket compiles (~55 s beside another worker): set TACTILE_JAX_SLOW=1")
def test_slow_slip_on_a_short_recording_gets_enough_bins():
    """8 s, 30 dB, 1.5 cm/s along x: the slope rule's segment left the joint fit 6 usable bins (5 + 1)
    and a poor_fit at vx = 1.45 +/- 0.10 cm/s; the band floor (FitOptions.min_band_bins) takes 18."""
    scene = dataclasses.replace(_scene(0.015, 0.0, 1.5e-3, seed=555, snr=30.0), duration=8.0)
    res = fit_recording(simulate(scene))
    assert res.status == "ok", res.message
    assert res.n_bins >= 12
    assert abs(res.vx - 0.015) < min(3 * res.vx_err, 0.02 * 0.015)
    assert res.vx_err < 0.03 * 0.015
    assert res.vy < 3 * res.vy_err or (res.vy_upper is not None and res.vy_upper > 0)
    assert abs(res.a - scene.a) < 3 * res.a_err


def test_known_velocity_is_held_fixed():
    scene = _scene(0.047, 0.0, 2.2e-3, seed=5)
    res = fit_recording(simulate(scene), FitOptions(velocity=(0.047, 0.0)))
    assert res.vx == 0.047 and res.vx_err is None and res.vy == 0.0 and res.vy_err is None
    assert res.a == pytest.approx(2.2e-3, rel=0.05)


def test_large_contact_speeds_hold_and_radius_is_bounded_or_measured():
    # 8 s: 64 bins, the oblique scene's compiled programs (16 s takes 128 bins and its own compilation)
    scene = dataclasses.replace(_scene(0.02, 0.0, 6e-3, seed=3), duration=8.0)
    res = fit_recording(simulate(scene))
    assert res.vx == pytest.approx(0.02, rel=0.02)
    if res.a is None:
        assert res.a_lower is not None and res.a_lower <= scene.a * 1.5
        assert "lower bound" in res.message
    else:
        assert abs(res.a - scene.a) < 3 * res.a_err


def test_no_band_is_reported_not_raised():
    scene = dataclasses.replace(_scene(0.03, 0.0, 2e-3, seed=1), snr_db=-20.0, duration=4.0)
    res = fit_recording(simulate(scene))
    assert res.status == "no_band" and res.vx is None and "usable bins" in res.message


def test_hertz_window_is_unsupported_status():
    rec = simulate(dataclasses.replace(_scene(0.03, 0.0, 2e-3, seed=1), duration=4.0))
    spec = estimate_spectra(rec.signals, rec.fs)
    res = fit_cross_spectra(spec, rec.depths, FitOptions(window="hertz"))
    assert res.status == "unsupported" and not res.converged


def test_resolution_segment_rules():
    from tactile_jax.fit import resolution_segment

    d = np.array([0.265e-3, 0.925e-3])
    # 2 pi x 1 kHz x 0.66 mm / (0.15 v) = 27.6 / v samples
    assert resolution_segment(0.2, 1000.0, d, 16000) == 256
    assert resolution_segment(0.015, 1000.0, d, 16000) == 2048                       # 1843 -> 2048
    # capped so that 6 half-overlapping segments remain: 2 N / 7
    assert resolution_segment(0.001, 1000.0, d, 8000) == 2048
    assert resolution_segment(0.001, 1000.0, d, 16000) == 4096
    # a narrow band: 12 bins at 1024 -> 24 wanted -> 2048, whatever the speed says
    assert resolution_segment(0.2, 1000.0, d, 16000, n_band=12, nperseg=1024) == 2048
    assert resolution_segment(0.2, 1000.0, d, 16000, n_band=24, nperseg=1024) == 256
    assert resolution_segment(0.2, 1000.0, d, 16000, n_band=0, nperseg=1024) == 4096  # capped


def test_the_chain_model_is_the_schur_complement_of_the_spectral_matrix(oblique):
    """``joint_model.chain_model`` (the y pair given the x pair, ``cross_pair``) with a one-point spectral
    window is the regression and residual PSD of ``spectral_matrix``'s 4 x 4 matrix: the x-y line integrals,
    the gains and the y level assembled as the independent Riemann-sum module has them."""
    from tactile_jax.spectral_matrix import spectral_matrix
    scene, res = oblique
    data, theta = res.problem.args, np.array(res.problem.theta, float)
    n_l = data.omega.shape[0]
    om, grid = np.asarray(data.omega), np.asarray(data.grid_omega)
    point = np.array([np.flatnonzero(np.abs(grid - w) < 1e-6 * (om[1] - om[0]))[-1] for w in om])
    index = np.zeros_like(np.asarray(data.kernel_index))
    index[:, 0] = point
    log_w = np.full(index.shape, -2e4)
    log_w[:, 0] = 0.0
    noise = np.full((2, 2), -300.0)
    d = data._replace(kernel_index=index, kernel_log_w=log_w, log_white_grid=np.zeros_like(data.log_white_grid),
                      log_white_bin=np.zeros_like(data.log_white_bin), log_noise_c22=noise,
                      mask_xy=np.ones((2, n_l), bool))
    theta[6] = -300.0
    beta1, beta2, log_c = (np.asarray(v) for v in jm.chain_model(theta, d))
    s = np.asarray(spectral_matrix(theta, data.omega, data.depths, data.log_k_knots, np.full(4, -300.0), n_s=20001))
    rows = slice(1, 12)                                                    # bins where the pairs share modes
    want1 = np.linalg.solve(s[rows, :2, :2], s[rows, :2, 2:3])[..., 0]
    want2 = np.linalg.solve(s[rows, :3, :3], s[rows, :3, 3:4])[..., 0]
    c1 = s[rows, 2, 2] - np.sum(s[rows, :2, 2] * want1, axis=-1)
    assert np.max(np.abs(want1)) > 0.1                                      # the chain has something to fit
    np.testing.assert_allclose(beta1[rows], want1, rtol=0.02, atol=0.01 * np.max(np.abs(want1)))
    np.testing.assert_allclose(log_c[0, rows], np.log(c1), atol=0.02)
    # y2 on (x1, x2, y1), three nearly collinear regressors: its coefficients amplify the quadratures' 1e-3
    # differences, so compare what they imply, the cross-spectra S_uu beta2, and the residual PSD
    m, ref = (np.asarray(v) for v in jm._bin_matrix(theta, d))
    m = m * np.exp(ref)[:, None, None]
    np.testing.assert_allclose(np.log(np.abs(m[rows])), np.log(s[rows]), atol=0.01)
    implied = np.einsum("lij,lj->li", s[rows, :3, :3], beta2[rows])
    np.testing.assert_allclose(implied, s[rows, :3, 3], rtol=0.02)
    c2 = s[rows, 3, 3] - np.sum(s[rows, :3, 3] * want2, axis=-1)
    np.testing.assert_allclose(log_c[1, rows], np.log(c2), atol=0.05)


def test_the_cross_pair_chain_sharpens_the_fit(oblique, oblique_pairs):
    """The default fit of a recording (``FitOptions.cross_pairs`` None: 2 here) fits the y pair conditioned on
    the x pair (``cross_pair``), with the x-y cross-spectra. Its blocks replace the y pair's own (one bin of
    those is left, below the chain's band), its whitened residuals are about unit at the solution, and the same
    recording gives tighter errors than the fit without the chain (``cross_pairs=0``) for vx, vy and a (on this
    scene 0.195 / 0.322 / 0.0135 -> 0.154 / 0.249 / 0.0094, unit Laplace errors in mm/s and mm), still covering
    the truth."""
    scene, res = oblique
    _, plain = oblique_pairs
    assert res.status == "ok" and res.cross_pairs == 2 and plain.cross_pairs == 0, res.message
    assert res.error_method.startswith("laplace x jackknife")
    data, theta = res.problem.args, res.problem.theta
    used = np.asarray(data.mask_xy)
    assert used.sum(axis=1).min() >= 10
    assert not np.any(np.asarray(data.mask_s11)[1] & used[0]) and not np.any(np.asarray(data.mask_h)[1] & used[1])
    z1, z2, zc = (np.asarray(b) for b in jm._chain_residuals(theta, data))
    for z, n in ((z1, 4), (z2, 6)):
        ms = np.mean(z.reshape(-1, n)[used[int(n == 6)]] ** 2)
        assert 0.6 < ms < 1.6, ms
    assert 0.5 < np.mean(zc.reshape(2, -1)[used] ** 2) < 2.0
    for name, true in (("vx", scene.velocity[0]), ("vy", scene.velocity[1]), ("a", scene.a)):
        got, err = getattr(res, name), getattr(res, name + "_err")
        assert abs(got - true) < 3 * err, (name, got, err, true)
        unit = err / np.sqrt(res.error_scales[name])
        unit_plain = getattr(plain, name + "_err") / np.sqrt(plain.error_scales[name])
        assert unit < 0.9 * unit_plain, (name, unit / unit_plain)
    assert "cross_pairs" in res.to_record()


def _stopped(step_sigma):
    """An LsqResult stopped at max_steps (only ``step_sigma`` matters to ``_settled_physics``)."""
    p = len(step_sigma)
    return LsqResult(np.zeros(p), np.eye(p), 1.0, 10, 5, 0.2, 256, False, 1.0, 4.7, step_sigma=np.asarray(step_sigma))


def test_a_stop_with_only_texture_knots_moving_keeps_the_physics():
    """Session 18, coverage scene 4 (1.2 deg off x) redrawn: vx 0.02, vy 0.08 sigma from the optimum,
    log_phi_8..11 1.4-2.1 sigma: the speeds stand; the warning names the knots that were moving."""
    names = jm.param_names(4)
    free = np.ones(len(names), bool)
    free[[3, 4, 6]] = False                                   # gains known, no noise floor
    steps = [0.023, -0.076, -0.003, 0.0, 0.0, -0.055, 0.0, 0.05, -0.08, 1.4, 2.1]
    res = FitResult()
    assert _settled_physics(res, _stopped(steps), names, free)
    assert "log_phi_2, log_phi_3: up to 2.1 sigma" in res.warnings[0] and "log_phi_1" not in res.warnings[0]


@pytest.mark.parametrize("moving", [1, 2, 5])
def test_a_stop_with_a_physical_parameter_moving_is_not_converged(moving):
    names = jm.param_names(2)
    steps = np.zeros(len(names))
    steps[moving] = 0.15
    res = FitResult()
    assert not _settled_physics(res, _stopped(steps), names, np.ones(len(names), bool)) and not res.warnings
    assert not _settled_physics(res, _stopped(steps)._replace(step_sigma=None), names, np.ones(len(names), bool))
