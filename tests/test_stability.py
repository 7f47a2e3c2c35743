"""Numerical stability on hard cases: honest numbers or a clear status, never a silent NaN.

Every case is a short (4 s) seeded recording through the full pipeline
(``fit_recording``), sharing one compiled shape where possible. A result is
acceptable when each reported quantity is finite with an error bar that
contains the truth within 5 sigma, or is withheld (None) with a message and,
for a and the speeds, a bound on the right side of the truth; or the status
says why nothing was fitted. A result outside 5 sigma with status "ok" is a
confident wrong answer and fails.
"""

import dataclasses
import math
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import GAUSS
from tactile_jax.inference.options import FitOptions
from tactile_jax.inference.fit import fit_recording, fit_spectra
from tactile_jax.io.files import SpectraData
from tactile_jax.inference.pair_fit import exact_residuals as pair_residuals
from tactile_jax.inference.pair_fit import fit_pair, pair_leakage
from tactile_jax.model.r_curve import log_g, log_r_exact
from tactile_jax.io.recording import Recording
from tactile_jax.simulation.scene import Scene, simulate
from tactile_jax.spectral.estimate import amplitude_ratio, estimate_spectra, usable_band, whitened_psd
from tactile_jax.simulation.texture import Grating, RandomTexture, WireNet

#: the cases that simulate and fit a scene each: ``pytest -m slow``; the default run keeps the cheap ones
slow = pytest.mark.slow

DURATION = 4.0
N_SIGMA = 5.0
BASE = Scene(texture=RandomTexture(), velocity=(0.03, 0.0), contact_radius=2e-3, duration=DURATION, snr_db=40.0, seed=3)


def _floats(res):
    for name in ("vx", "vx_err", "vy", "vy_err", "a", "a_err", "a_lower", "vx_upper", "vy_upper", "gain_ratio",
                 "gain_ratio_err", "redchi", "contact_depth", "contact_depth_err"):
        v = getattr(res, name)
        if v is not None:
            yield name, v


def assert_honest(res, truth: dict, *, allowed=("ok", "poor_fit", "no_band", "not_converged", "undetermined")):
    """Finite numbers whose error bars hold the truth, or a withheld value with a message and a bound; a
    status of ok or undetermined (a value it could not give) vouches for every error bar it gives."""
    assert res.status in allowed, (res.status, res.message)
    for name, v in _floats(res):
        assert math.isfinite(v), f"{name} = {v} (silent non-finite value); status {res.status}: {res.message}"
    if res.status == "no_band":
        assert res.message and res.vx is None and res.a is None
        return
    if res.status != "ok":
        assert res.message, "a status other than ok must say why"
    for name, true in truth.items():
        value, err = getattr(res, name), getattr(res, name + "_err", None)
        if value is None:
            assert res.message, f"{name} withheld without a message"
            if name == "a" and res.a_lower is not None:
                assert res.a_lower <= true * 1.05, f"a_lower {res.a_lower} above the truth {true}"
            continue
        if err is None:         # a fixed parameter, or a minor speed held at 0 below its 95 % upper bound
            upper = getattr(res, name + "_upper", None) if name in ("vx", "vy") else None
            assert upper is None or true <= 2.0 * upper, f"{name} held at {value}, truth {true} above 2 x {upper}"
            continue
        assert err > 0, f"{name}_err = {err}"
        z = abs(value - true) / err
        assert z <= N_SIGMA or res.status not in ("ok", "undetermined"), (
            f"confident wrong answer: {name} = {value:.4g} +/- {err:.2g}, truth {true:.4g} ({z:.1f} sigma), "
            f"status {res.status}; message: {res.message}")


def _truth(scene, with_a=True):
    t = {"vx": abs(scene.velocity[0]), "vy": abs(scene.velocity[1])}
    if with_a:
        t["a"] = scene.a
    return t


@pytest.fixture(scope="module")
def base_rec():
    return simulate(BASE)


@pytest.fixture(scope="module")
def base_fit(base_rec):
    return fit_recording(base_rec, FitOptions())


@slow
def test_baseline_is_honest(base_fit):
    assert_honest(base_fit, _truth(BASE))
    assert base_fit.vx == pytest.approx(BASE.velocity[0], rel=0.05)


@slow
def test_plain_scene_converges(base_fit):
    assert base_fit.status == "ok", base_fit.message


@slow
def test_float32_input_with_dc_offsets(base_rec, base_fit):
    """float32 samples carrying DC offsets of 10x the signal rms: computed in float64, offsets removed."""
    x = np.asarray(base_rec.signals, float)
    x = x + 10 * x.std(axis=-1, keepdims=True) * np.array([1.0, -2.0, 3.0, 0.5])[:, None]
    res = fit_recording(dataclasses.replace(base_rec, signals=x.astype(np.float32)), FitOptions())
    assert_honest(res, _truth(BASE))
    assert res.precision == "float64"
    assert res.status == base_fit.status
    assert res.vx == pytest.approx(base_fit.vx, abs=0.5 * base_fit.vx_err)


@slow
def test_unknown_gain_mismatch_fitted(base_rec):
    """Deep probes 40 % hot and not calibrated: fit_gain must widen a, not bias it silently."""
    x = np.asarray(base_rec.signals, float) * np.array([1.0, 1.4, 1.0, 1.4])[:, None]
    res = fit_recording(dataclasses.replace(base_rec, signals=x), FitOptions(fit_gain=True))
    assert_honest(res, _truth(BASE))
    if res.gain_ratio_err is not None:
        assert abs(res.gain_ratio - 1.4) <= N_SIGMA * res.gain_ratio_err


@slow
def test_clipped_signals(base_rec):
    x = np.asarray(base_rec.signals, float)
    level = 0.5 * np.abs(x[0]).max()
    res = fit_recording(dataclasses.replace(base_rec, signals=np.clip(x, -level, level)), FitOptions())
    assert_honest(res, _truth(BASE))


SCENES = {
    # a 0.1 mm contact: R -> d1 / d2 flat; speed information only from the faint remaining slope
    "contact_0.1mm": dataclasses.replace(BASE, contact_radius=1e-4, seed=4),
    # a 50 mm contact (Eq. 5 regime): a is not measurable, expect a lower bound; 120 um grid keeps it small
    "contact_50mm": dataclasses.replace(BASE, contact_radius=50e-3, grid_spacing=120e-6, seed=5),
    # 3 mm/s: the band sits at a few Hz
    "slow_near_dc": dataclasses.replace(BASE, velocity=(0.003, 0.0), seed=6),
    # 20 cm/s: the deep probe's band reaches Nyquist (aliasing, as an unfiltered ADC would)
    "fast_near_nyquist": dataclasses.replace(BASE, velocity=(0.2, 0.0), seed=7),
    "snr_0db": dataclasses.replace(BASE, snr_db=0.0, seed=8),
    # the deep probes 60 dB down: drowned in the (shallow-referenced) noise
    "deep_drowned": dataclasses.replace(BASE, gains=(1.0, 1e-3, 1.0, 1e-3), seed=9),
}


#: cases whose fit stops early (no_band): cheap, always run
QUICK = ("snr_0db", "deep_drowned")


#: known confident wrong answers, kept visible (strict: a fix makes the test fail until this is removed)
KNOWN_BAD: dict = {}


def _hard(name):
    marks = [] if name in QUICK else [slow]
    if name in KNOWN_BAD:
        marks.append(pytest.mark.xfail(reason=KNOWN_BAD[name], strict=True))
    return pytest.param(name, marks=marks)


@pytest.mark.parametrize("name", [_hard(n) for n in SCENES if n != "contact_50mm"])
def test_hard_scenes(name):
    scene = SCENES[name]
    res = fit_recording(simulate(scene), FitOptions(**GAUSS))         # the scenes' own window
    assert_honest(res, _truth(scene))
    if name == "deep_drowned":
        assert res.status == "no_band", (res.status, res.message)


#: textures outside the model (a smooth isotropic spectrum): lines, in one or two directions
LINE_TEXTURES = {
    "grating_30deg": Grating(pitch=1e-3, angle=np.radians(30.0), profile="sine"),
    "wire_net_oblique": WireNet(pitch=1e-3),
}


@slow
@pytest.mark.parametrize("name", list(LINE_TEXTURES))
def test_line_textures_get_no_confident_number(name):
    scene = dataclasses.replace(BASE, texture=LINE_TEXTURES[name], velocity=(0.025, 0.02), contact_radius=1.5e-3,
                                seed=12)
    assert_honest(fit_recording(simulate(scene), FitOptions()), _truth(scene))


@slow
def test_a_narrow_low_snr_band_gets_finer_bins():
    """A 10 dB, 1.5 cm/s recording (8 s, seed 415): at the default 512-sample segment the band holds 3 + 1
    bins, too few for the Eq. 6 slope that sizes the segment; the band is stretched by its bin count
    (2048 samples: 15 bins)."""
    scene = Scene(texture=RandomTexture(), velocity=(0.015, 0.0), contact_radius=1.5e-3, snr_db=10.0,
                  duration=8.0, seed=415)
    res = fit_recording(simulate(scene), FitOptions())
    assert res.status == "ok" and res.n_bins >= 8, (res.status, res.n_bins, res.message)
    assert_honest(res, _truth(scene))
    assert abs(res.vx - 0.015) < 0.1 * 0.015


_FLOAT32_FIT = """
import dataclasses, json, numpy as np
from tactile_jax.inference.fit import FitOptions, fit_recording
from tactile_jax.simulation.scene import RandomTexture, Scene, simulate
scene = Scene(texture=RandomTexture(), velocity=(0.015, 0.0), contact_radius=1.5e-3, snr_db=10.0, duration=8.0, seed=415)
rec = simulate(scene)
res = fit_recording(dataclasses.replace(rec, signals=np.asarray(rec.signals, np.float32)), FitOptions())
print(json.dumps({k: getattr(res, k) for k in ("status", "message", "precision", "vx", "vx_err", "a", "a_err")}))
"""


@slow
def test_float32_joint_fit_of_a_narrow_noisy_band():
    """The 10 dB recording above with x64 off (a subprocess: the suite runs in float64): finite error bars
    that hold the truth (every floor under a log or a division is one that float32 keeps, ``_numerics.tiny``)."""
    import json
    import subprocess
    import sys
    env = {**os.environ, "JAX_ENABLE_X64": "0"}
    out = subprocess.run([sys.executable, "-c", _FLOAT32_FIT], env=env, capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-2000:]
    res = json.loads(out.stdout.strip().splitlines()[-1])
    assert res["precision"] == "float32" and res["status"] == "ok", res
    for name, true in (("vx", 0.015), ("a", 1.5e-3)):
        assert res[name + "_err"] is not None and math.isfinite(res[name + "_err"]) and res[name + "_err"] > 0, res
        assert abs(res[name] - true) < N_SIGMA * res[name + "_err"], res


@slow
def test_slip_along_an_axis_is_bounded_not_fitted_into_noise():
    """Slip exactly along y: vx (0.001 cm/s) is consistent with 0 and reported with a 95 % upper bound."""
    scene = Scene(texture=RandomTexture(), velocity=(9.538793206572115e-06, 0.05168213796369707),
                  contact_radius=0.0009255734626374513, snr_db=45.44308981288118, seed=377259081)
    res = fit_recording(simulate(scene), FitOptions())
    assert res.status == "ok" and res.converged, (res.status, res.message, res.warnings)
    assert res.vx_upper is not None and res.vx_upper > abs(scene.velocity[0])
    assert_honest(res, _truth(scene))


@slow
def test_large_contact_is_a_bound_not_a_confident_radius():
    scene = SCENES["contact_50mm"]
    res = fit_recording(simulate(scene), FitOptions())
    assert_honest(res, _truth(scene))
    assert res.a is None and res.a_lower is not None, (res.a, res.a_err, res.message)


def _zeroed_spectra(rec):
    spec = estimate_spectra(np.asarray(rec.signals, float), rec.fs)
    psd, csd = np.array(spec.psd), np.array(spec.csd)
    psd[:, 5:9] = 0.0                                  # a dead band (a notch filter)
    csd[:, 5:9] = 0.0
    csd[1, 12] = 0.0                                   # one cross-spectrum bin only
    return spec, psd, csd


@slow
def test_spectra_with_exact_zeros_joint(base_rec):
    """Zeroed PSD/CSD bins in a spectra file through the joint model: dropped, never NaN."""
    spec, psd, csd = _zeroed_spectra(base_rec)
    data = SpectraData(np.asarray(spec.omega), psd=psd, csd=csd, n_segments=spec.n_segments,
                       depths=base_rec.depths, kernel=np.asarray(spec.kernel), bin_factor=spec.bin_factor)
    assert_honest(fit_spectra(data, FitOptions()), _truth(BASE))


@pytest.mark.slow
def test_ratio_spectra_with_exact_zeros(base_rec):
    """Ratio-only spectra with exact zeros (log -inf) and an infinite error: skipped by the pair fits."""
    spec, psd, csd = _zeroed_spectra(base_rec)
    ratio = np.abs(csd) / np.where(psd[[0, 2]] > 0, psd[[0, 2]], 1.0)
    err = np.array(amplitude_ratio(spec).log_ratio_err)        # Bendat & Piersol errors of the unzeroed bins
    err[:, 20] = np.inf
    res = fit_spectra(SpectraData(np.asarray(spec.omega), ratio=ratio, ratio_err=err, depths=base_rec.depths))
    assert res.status in ("ok", "not_converged", "no_band"), (res.status, res.message)
    for name, v in _floats(res):
        assert math.isfinite(v), (name, v, res.status, res.message)
    assert abs(res.vx - BASE.velocity[0]) <= N_SIGMA * res.vx_err, (res.vx, res.vx_err)


@pytest.mark.slow
def test_extreme_alpha_d_values_and_gradients():
    """alpha d from 1e-9 to 1e5, a from 1 um to 1 m: log R and the pair model's Jacobian stay finite."""
    d1, d2 = 0.265e-3, 0.925e-3
    alpha = jnp.asarray(np.geomspace(1e-6, 1e8, 60))
    for a in (1e-6, 1e-4, 1e-2, 1.0):
        lr = log_r_exact(alpha, d1, d2, a)
        assert bool(jnp.all(jnp.isfinite(lr))), a
        assert bool(jnp.all(lr <= 1e-12)), a                       # the deep probe never hears more
        g = jax.vmap(jax.grad(lambda al: log_g(al, d2, a)))(alpha)
        assert bool(jnp.all(jnp.isfinite(g))), a
    omega = jnp.linspace(1.0, 3e3, 64)
    args = (omega, jnp.zeros(64), jnp.full(64, 0.1), jnp.ones(64, bool), d1, d2, jnp.zeros(1), jnp.zeros(1))
    for log_v, log_a in ((np.log(1e-6), np.log(1e-6)), (np.log(10.0), np.log(0.1)), (np.log(1e-6), np.log(1.0)),
                         (np.log(10.0), np.log(1e-6))):
        theta = jnp.asarray([log_v, log_a, 0.0])
        r = pair_residuals(theta, args)
        jac = jax.jacfwd(pair_residuals)(theta, args)
        assert bool(jnp.all(jnp.isfinite(r))) and bool(jnp.all(jnp.isfinite(jac))), (log_v, log_a)


def test_recording_of_zeros_is_a_status_not_nan():
    rec = Recording(np.zeros((4, int(DURATION * 1000))), 1000.0, (0.265e-3, 0.925e-3))
    res = fit_recording(rec, FitOptions(**GAUSS))
    assert res.status == "no_band" and res.message
    for name, v in _floats(res):
        assert math.isfinite(v), (name, v)


@pytest.mark.parametrize("name", list(SCENES))
@pytest.mark.slow
def test_pair_fit_with_the_window_term_on_hard_scenes(name):
    """The fast path on the same scenes (slip along x, so its model holds): |v| within 5 sigma, a within
    5 sigma or undetermined (a_err > a / 2, which callers withhold); too few bins is left to the caller.
    On the 50 mm contact's 5 bins the window average alone read |v| 1.50 +/- 0.31 cm/s (truth 3, 4.8 sigma)
    and a 0.68 +/- 0.18 mm (268 sigma): the realised window term gives 2.96 +/- 0.12 and 11 +/- 32 mm."""
    scene = SCENES[name]
    rec = simulate(scene)
    spec = estimate_spectra(rec.signals, rec.fs, prewhiten=8)
    ratio = amplitude_ratio(spec)
    band = np.asarray(usable_band(ratio)[0])
    if band.sum() < 5:
        # a 3 mm/s slip's band is a few Hz: under 5 bins of the default segment, for the pair path as for the
        # joint one (which lengthens its segments for it: test_hard_scenes)
        assert name in QUICK + ("slow_near_dc",), f"{name}: {band.sum()} usable bins"
        return
    f = fit_pair(np.asarray(ratio.omega), np.nan_to_num(np.asarray(ratio.log_ratio[0])),
                 np.asarray(ratio.log_ratio_err[0]), band, *rec.depths, kernel=spec.kernel,
                 spectrum=np.asarray(whitened_psd(spec)[0]), leakage=pair_leakage(spec, 0))
    values = (f.speed, f.speed_err, f.a, f.a_err)
    assert all(math.isfinite(v) and v > 0 for v in values), values
    assert abs(f.speed - abs(scene.velocity[0])) <= N_SIGMA * f.speed_err, (f.speed, f.speed_err)
    assert abs(f.a - scene.a) <= N_SIGMA * f.a_err or f.a_err > 0.5 * f.a, (f.a, f.a_err)
