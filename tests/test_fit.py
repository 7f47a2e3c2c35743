"""The joint fit of simulated scenes: recovery with honest error bars, one compiled program, failure as data.

A small seeded version of benchmarks/coverage.py; every fit shares the one compiled program of
``inference.core`` (its inputs have one shape whatever the recording's length or band).
"""

import dataclasses

import numpy as np
import pytest

from conftest import GAUSS, compilations
from tactile_jax.errors import TactileInputError
from tactile_jax.inference.options import FitOptions
from tactile_jax.inference.fit import fit_recording, fit_spectra
from tactile_jax.inference.forward import ANISO, INDEX
from tactile_jax.inference.select import lobe_of
from tactile_jax.io.files import read_spectra, write_recording
from tactile_jax.inference import run
from tactile_jax.io.recording import Recording
from tactile_jax.simulation.scene import Scene, simulate
from tactile_jax.simulation.texture import DirectionalTexture, Grating, ModeTexture, RandomTexture, StretchedTexture


def _scene(vx, vy, a, seed, snr=50.0, duration=16.0):
    return Scene(texture=RandomTexture(), velocity=(vx, vy), contact_radius=a, snr_db=snr, seed=seed,
                 duration=duration)


@pytest.fixture(scope="module")
def oblique():
    scene = _scene(0.036, 0.022, 1.5e-3, seed=11)
    rec = simulate(scene)
    return scene, rec, fit_recording(rec, FitOptions(**GAUSS))


def test_oblique_slip_small_contact_recovered(oblique):
    scene, _, res = oblique
    assert res.status == "ok" and res.converged, res.message
    speed = float(np.hypot(*scene.velocity))
    for got, err, true in ((res.vx, res.vx_err, scene.velocity[0]), (res.vy, res.vy_err, scene.velocity[1])):
        assert abs(got - true) < 0.03 * speed
        assert abs(got - true) < 4 * err
    assert abs(res.a - scene.a) < 0.05 * scene.a and abs(res.a - scene.a) < 4 * res.a_err
    assert res.contact_depth == pytest.approx(res.a ** 2 / 0.03)
    assert res.contact_depth_err == pytest.approx(2 * res.a * res.a_err / 0.03)
    assert res.model == "window" and res.window == "gaussian" and res.texture == "isotropic"
    assert res.problem.precision == "float32"          # the Gaussian window's model may be sampled in float32
    # texture cross-sections with error bars, on k = omega / |v|
    assert res.texture_x is not None and np.all(np.isfinite(res.texture_x.log_power_err))
    assert np.all(res.texture_x.power > 0) and np.all(np.diff(res.texture_x.k) > 0)
    row = res.to_record()
    for key in ("vx", "vx_err", "vy", "vy_err", "a", "a_err", "contact_depth", "model", "window", "status"):
        assert key in row
    # error bars scaled by the recording's delete-one-segment jackknife: vx, vy and a each their own
    assert res.error_method.startswith("laplace x jackknife") and row["error_scale"] == res.error_scale
    assert set(res.error_scales) == {"vx", "vy", "a"}
    assert all(res.redchi * (1 - 1e-9) <= s < 5 for s in res.error_scales.values())
    assert np.ptp(list(res.error_scales.values())) > 0.01


def test_fit_and_batch_run_the_same_program(oblique, tmp_path):
    """One program: a chunk gives the single record's values and errors, and a batch's row equals the fit's,
    row by row."""
    from tactile_jax.batch.run import run_batch
    from tactile_jax.inference.fit import record_of
    from tactile_jax.inference.options import analysis_settings, choices_of
    from tactile_jax.io.results import read_results

    _, rec, res = oblique
    options = FitOptions(**GAUSS)
    r = record_of(np.asarray(rec.signals, float), rec.fs, rec.depths, options)
    settings, choices = analysis_settings(options), choices_of(options)
    one = run.analyse_one(r, settings, choices)
    for a in run.analyse_many([r] * 2, settings, choices, vmapped=False):
        assert np.allclose(a.summary.theta, one.summary.theta, rtol=0, atol=1e-6 * np.abs(one.summary.sd).max())
        assert np.allclose(a.summary.sd, one.summary.sd, rtol=1e-6)
        assert int(a.summary.status) == int(one.summary.status) and int(a.texture) == int(one.texture)
    write_recording(tmp_path / "rec.h5", rec)
    run_batch([tmp_path / "rec.h5"], tmp_path / "rows.json", progress=False, options=options)
    row, mine = read_results(tmp_path / "rows.json")[0], res.to_record()
    for key in ("vx", "vx_err", "vy", "vy_err", "a", "a_err", "contact_depth", "redchi", "window_margin",
                "texture_margin"):
        assert (row[key] is None) == (mine[key] is None), key
        if mine[key] is not None:
            assert row[key] == pytest.approx(mine[key], rel=1e-9), key
    for key in ("status", "window", "texture", "direction", "model"):
        assert row[key] == mine[key], key


def test_new_recording_shapes_do_not_compile_again(oblique):
    """Another length, another Welch segment, another band: the same compiled program."""
    short = simulate(_scene(0.03, 0.01, 1.5e-3, seed=5, duration=8.0, snr=45.0))
    with compilations() as events:
        res = fit_recording(short, FitOptions(nperseg=512, **GAUSS))
        res2 = fit_recording(short, FitOptions(**GAUSS))
    assert res.status in ("ok", "poor_fit") and res2.status in ("ok", "poor_fit")
    assert events == []


def test_minor_component_gets_a_profile_interval():
    scene = _scene(0.02, 0.0012, 1.5e-3, seed=4)
    res = fit_recording(simulate(scene), FitOptions(**GAUSS))
    assert res.status == "ok", res.message
    assert res.vy_lo is not None and res.vy_hi is not None and res.vy_lo < res.vy < res.vy_hi
    assert res.vy_lo2 <= res.vy_lo and (res.vy_hi2 is None or res.vy_hi2 >= res.vy_hi)
    assert "minor component" in res.message
    assert res.vy_lo2 <= scene.velocity[1] <= (res.vy_hi2 or np.inf)


def test_known_velocity_is_held_fixed():
    scene = _scene(0.03, 0.0, 2e-3, seed=2, duration=8.0)
    res = fit_recording(simulate(scene), FitOptions(velocity=(0.03, 0.0), **GAUSS))
    assert res.vx == 0.03 and res.vx_err is None and res.vy == 0.0 and res.vy_err is None
    assert res.status == "ok" and abs(res.a - scene.a) < 4 * res.a_err
    assert res.model == "window+v_known"


def test_no_band_is_reported_not_raised():
    rng = np.random.default_rng(0)
    rec = Recording(rng.standard_normal((4, 16000)), 1000.0, (0.265e-3, 0.925e-3), source="noise.h5")
    res = fit_recording(rec, FitOptions(**GAUSS))
    assert res.status == "no_band" and "usable bins" in res.message and res.vx is None
    assert "no coherent texture line or band" in res.message


@pytest.mark.slow
def test_a_grating_gives_its_normal_speed_and_leaves_the_ridge_component_undetermined():
    """A grating heard by both pairs: the smooth models find no band; the line model gives the speed along
    the lines' normal, the normal's angle and a, and vx, vy undetermined (the aperture problem)."""
    scene = Scene(texture=Grating(pitch=2e-3, angle=0.5), velocity=(0.03, 0.02), contact_radius=1.5e-3,
                  duration=4.0, snr_db=50.0, seed=1)
    res = fit_recording(simulate(scene), FitOptions(**GAUSS))
    v_n = 0.03 * np.cos(0.5) + 0.02 * np.sin(0.5)
    assert res.status == "undetermined" and res.texture == "grating" and res.model == "lines"
    assert res.vx is None and res.vy is None and "aperture" in res.message
    assert abs(res.v_normal - v_n) < min(3 * res.v_normal_err, 0.03 * v_n)
    assert abs(res.normal_angle - np.degrees(0.5)) < max(3 * res.normal_angle_err, 1.0)
    assert abs(res.a - 1.5e-3) < 3 * res.a_err
    row = res.to_record()
    assert row["status"] == "undetermined" and row["vx"] is None and row["v_normal"] == res.v_normal


@pytest.mark.slow
def test_a_lumpy_spectrum_of_few_modes_is_named_and_its_errors_hold_the_lumps():
    """300 plane waves: the same lumps in every segment, which the segment jackknife cannot see. The misfit is
    far above the noise but has no trend across frequency: the fit says poor_fit with texture "lumpy", and the
    spread of its misfit across frequency sets the speeds' errors, so they hold the truth."""
    scene = Scene(texture=ModeTexture(n_modes=300, seed=4), velocity=(0.03, 0.02), contact_radius=1.5e-3,
                  duration=16.0, snr_db=45.0, seed=4)
    res = fit_recording(simulate(scene), FitOptions(**GAUSS))
    assert res.status == "poor_fit" and res.texture.endswith("lumpy") and "lumpy texture" in res.message
    assert "spread across frequency" in res.error_method
    for name, truth in (("vx", 0.03), ("vy", 0.02)):
        assert abs(res[name].value - truth) < 3 * res[name].err


@pytest.mark.slow
def test_a_wrong_window_leaves_a_trend_and_stays_a_poor_fit():
    """The control of the lumpy rule: a smooth texture under a Hertz disk fitted with the Gaussian window misfits
    with a trend across frequency, so it stays poor_fit, not lumpy."""
    scene = Scene(texture=RandomTexture(), velocity=(0.0367, 0.0058), contact_radius=2.5e-3, window="hertz",
                  duration=16.0, snr_db=42.0, seed=11)
    res = fit_recording(simulate(scene), FitOptions(**GAUSS))
    assert res.status == "poor_fit" and not bool(res.summary.lumpy)
    assert res.summary.roughness > 3.0 and "trend ratio" in res.message and res.texture == "isotropic"


def test_bad_input_raises_one_line_naming_the_source():
    sig = np.ones((4, 16000))
    sig[1, 7] = np.nan
    with pytest.raises(TactileInputError, match="rec.h5.*NaN"):
        fit_recording(Recording(sig, 1000.0, (0.265e-3, 0.925e-3), source="rec.h5"))
    with pytest.raises(TactileInputError, match="rec.h5.*nperseg"):
        fit_recording(Recording(np.ones((4, 1000)), 1000.0, (0.265e-3, 0.925e-3), source="rec.h5"),
                      FitOptions(nperseg=4096))


def test_float32_input_gives_the_same_fit(oblique):
    scene, rec, res = oblique
    rec32 = Recording(np.asarray(rec.signals, np.float32), rec.fs, rec.depths)
    res32 = fit_recording(rec32, FitOptions(**GAUSS))
    assert res32.status == "ok"
    assert abs(res32.vx - res.vx) < 0.1 * res.vx_err and abs(res32.a - res.a) < 0.1 * res.a_err


def test_spectra_files_fit_like_their_recording(oblique, tmp_path):
    """A file from ``tactile-jax spectra`` holds the x-y spectra and the segment groups: the recording's fit."""
    from click.testing import CliRunner

    from tactile_jax.cli import main

    scene, rec, res = oblique
    write_recording(tmp_path / "r.h5", rec)
    out = CliRunner().invoke(main, ["spectra", str(tmp_path / "r.h5"), "--out", str(tmp_path / "s.npz")])
    assert out.exit_code == 0, out.output
    got = fit_spectra(read_spectra(tmp_path / "s.npz"), FitOptions(**GAUSS))
    assert got.status == res.status and got.error_method == res.error_method
    for name in ("vx", "vx_err", "vy", "vy_err", "a", "a_err"):
        assert getattr(got, name) == pytest.approx(getattr(res, name), rel=1e-9), name


def test_large_contact_radius_is_measured_or_bounded():
    scene = dataclasses.replace(_scene(0.03, 0.01, 6e-3, seed=6, duration=8.0), grid_spacing=60e-6)
    res = fit_recording(simulate(scene), FitOptions(**GAUSS))
    assert res.status == "ok", res.message
    speed = float(np.hypot(*scene.velocity))
    assert abs(res.vx - scene.velocity[0]) < 0.05 * speed
    if res.a is None:
        assert res.a_lower is not None and res.a_lower < scene.a and "too weak" in res.message
    else:
        assert abs(res.a - scene.a) < 4 * res.a_err


def test_the_slip_model_holds_a_window_negligible(oblique):
    _, rec, _ = oblique
    res = fit_recording(rec, FitOptions(model="slip", **GAUSS))
    assert res.model == "slip" and res.a is None and res.a_lower == pytest.approx(0.1)
    assert "held negligible" in res.message


def test_directional_texture_is_modelled_and_reported():
    """Power 3:1 along 120 deg: the isotropic model puts vx about 6 sigma off with status ok; the directional
    model is chosen per record, its lobe found, and the speeds covered by their error bars."""
    scene = Scene(texture=DirectionalTexture(anisotropy=3.0, angle=np.radians(120.0)), velocity=(0.0371, 0.0217),
                  contact_radius=1.2e-3, snr_db=45.0, seed=305, duration=16.0)
    rec = simulate(scene)
    iso = fit_recording(rec, FitOptions(texture="isotropic", **GAUSS))
    res = fit_recording(rec, FitOptions(**GAUSS))
    assert res.status == "ok" and res.texture == "directional" and res.texture_margin > 0, res.message
    assert "directional texture" in res.message and iso.texture == "isotropic"
    assert abs(iso.vx - scene.velocity[0]) > 4 * iso.vx_err              # what the isotropic model reports
    along, _ = lobe_of(res.summary.theta[[INDEX[name] for name in ANISO]])
    assert abs((along - 120.0 + 90.0) % 180.0 - 90.0) < 20.0
    speed = float(np.hypot(*scene.velocity))
    for name, true in (("vx", scene.velocity[0]), ("vy", scene.velocity[1])):
        assert abs(res[name].value - true) < min(3 * res[name].err, 0.03 * speed), name
    assert res.to_record()["texture"] == "directional"


@pytest.mark.slow
def test_a_brushed_surface_gets_honest_speeds():
    """Ridges 2.9x longer than wide: a lobe sharpening with |k|, not the cos 2theta lobe. A lobe to the second
    harmonic alone put vx 7.7 and vy 18 sigma off here at a reduced chi-square of 1.35, status ok; the fourth
    harmonic covers both."""
    scene = Scene(texture=StretchedTexture(aspect=2.853, angle=1.0674), velocity=(0.05493, 0.02557),
                  contact_radius=1.146e-3, snr_db=43.1, seed=528537910, duration=16.0)
    res = fit_recording(simulate(scene), FitOptions(**GAUSS))
    assert res.status == "ok" and res.texture == "directional", res.message
    speed = float(np.hypot(*scene.velocity))
    for name, true in (("vx", scene.velocity[0]), ("vy", scene.velocity[1])):
        assert abs(res[name].value - true) < min(3 * res[name].err, 0.03 * speed), name
