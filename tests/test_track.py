"""The sliding-window tracker: the moving-texture test, the stream's bookkeeping, rows and the ``track`` command."""

import numpy as np
import pytest
from click.testing import CliRunner

from tactile_jax.cli import main
from tactile_jax.errors import TactileInputError
from tactile_jax.io.files import write_recording
from tactile_jax.simulation.path import Piece, simulate_path, truth_at
from tactile_jax.track import Tracker, track_recording
from tactile_jax.track.tracker import activity, default_nperseg

from conftest import GAUSS

FS = 1000.0


def _texture_burst(n, rng):
    """Four channels of a low-frequency random signal (a texture heard at a slow slip), unit power."""
    white = rng.standard_normal((4, n + 64))
    kernel = np.hanning(64)
    return np.stack([np.convolve(w, kernel, mode="valid")[:n] for w in white]) / 10.0


@pytest.fixture
def rng():
    return np.random.default_rng(3)


def test_activity_tells_still_from_moving_and_finds_the_start(rng):
    n, nper = 2000, default_nperseg(2000)
    noise = 1e-3 * rng.standard_normal((4, n))
    assert activity(noise, nper).verdict == "still"
    moving = noise + _texture_burst(n, rng)
    act = activity(moving, nper)
    assert act.verdict == "moving" and act.moving.all() and act.excess_db.min() > 20
    start = noise.copy()
    start[:, n // 2:] += _texture_burst(n - n // 2, rng)
    assert activity(start, nper).verdict == "start"
    stop = noise.copy()
    stop[:, :n // 2] += _texture_burst(n // 2, rng)
    assert activity(stop, nper).verdict == "stop"


def test_a_still_contact_gives_no_slip_rows_and_no_speed(rng):
    tracker = Tracker(FS, window=1.0, hop=0.25)
    rows = []
    for block in np.array_split(1e-3 * rng.standard_normal((4, 3000)), 7, axis=1):
        rows += tracker.push(block)
    # windows end at 1.0, 1.25, ..., 3.0 s: nine of them, centred 0.5 s before their ends
    assert [r["t"] for r in rows] == pytest.approx(np.arange(0.5, 2.51, 0.25))
    assert {r["status"] for r in rows} == {"no_slip"}
    assert all(r["vx"] is None and r["vy"] is None and r["a"] is None for r in rows)
    assert all(r["sensor"] == "paper (default)" and "paper's sensor assumed" in r["message"] for r in rows)
    assert tracker.rows == rows


def test_a_moving_window_with_no_band_is_no_band_without_an_analysis(rng, monkeypatch):
    """Texture heard by each probe alone (no coherent pair): the moving-texture test passes, the band holds no
    usable bin, and the row says ``no_band`` with no analysis run."""
    from tactile_jax.inference import run

    def no_analysis(*args, **kwargs):
        raise AssertionError("analysed a window with no band")

    monkeypatch.setattr(run, "analyse_one", no_analysis)
    tracker = Tracker(FS, window=1.0, hop=0.5, source="rub.h5")
    rows = tracker.push(_texture_burst(2000, rng) + 1e-3 * rng.standard_normal((4, 2000)))
    assert len(rows) == 3 and {r["status"] for r in rows} == {"no_band"}
    assert all(r["update"] == "none" and r["vx"] is None and r["message"].startswith("only ") for r in rows)
    assert all(r["n_bins"] < 6 for r in rows)


@pytest.mark.parametrize("kwargs, words", [
    (dict(fs=0.0), "sample rate"),
    (dict(fs=FS, hop=3.0), "--hop"),
    (dict(fs=FS, window=-1.0), "--window"),
    (dict(fs=FS, window=0.02, hop=0.01), "too short"),
    (dict(fs=FS, method="fft"), "method"),
])
def test_bad_settings_are_one_line_errors(kwargs, words):
    with pytest.raises(TactileInputError, match=words) as err:
        Tracker(**kwargs)
    assert "\n" not in str(err.value)


def _pairs(rng, n, speed, level=1.0):
    """Two pairs of probes 0.66 mm apart in depth under a texture sliding at ``speed`` (m/s): the deep probe hears
    each frequency f damped by exp(-2 pi f depth / speed) (paper Eq. 5); ``level`` scales the texture."""
    kernel = np.hanning(16)
    shallow = level * np.stack([np.convolve(w, kernel / kernel.sum(), mode="valid")[:n]
                                for w in rng.standard_normal((2, n + 64))])
    f = np.fft.rfftfreq(n, 1.0 / FS)
    deep = np.fft.irfft(np.fft.rfft(shallow) * np.exp(-2 * np.pi * f * 0.66e-3 / speed), n)
    out = np.empty((4, n))
    out[0::2], out[1::2] = shallow, deep + 1e-7 * rng.standard_normal((2, n))
    return out


def test_change_point_places_a_change_of_slip_and_not_one_of_texture():
    """A slip at 4 cm/s, then 1.5 cm/s from 1.7 s: placed within 0.1 s and sharp. The same slip throughout over a
    texture whose relief triples at 1.5 s (another patch of the surface), heard by the deep probes over their
    noise: the deep/shallow ratios do not change, and a split sharp enough to place a change is rare."""
    from tactile_jax.track.tracker import CHANGE_SHARP, change_point

    patches = []
    for seed in range(6):
        rng = np.random.default_rng(seed)
        at, sharp = change_point(np.concatenate([_pairs(rng, 1700, 0.04), _pairs(rng, 1300, 0.015)], 1), FS)
        assert abs(at - 1.7) < 0.1 and sharp > CHANGE_SHARP
        patches.append(change_point(np.concatenate([_pairs(rng, 1500, 0.04), _pairs(rng, 1500, 0.04, 3.0)], 1), FS)[1])
    assert sum(p >= CHANGE_SHARP for p in patches) <= 1                  # a split of noise may pass by chance
    assert change_point(np.zeros((4, 300)), FS)[1] < CHANGE_SHARP         # too short to split


def test_errors_widen_to_the_scatter_of_windows_that_share_no_sample():
    """Rows every 0.1 s of 2 s windows: where windows 2 s apart differ by 3 of their errors the errors widen about
    3x (vx's alone: vy and a do not move); where they agree within their errors, not at all; windows that overlap
    are never compared, and before any two share no sample the errors are widened by the measured default."""
    from tactile_jax.inference.result import FitResult
    from tactile_jax.track.tracker import UNCALIBRATED_WIDEN, _Held, _widened

    def row(vx):
        res = FitResult()
        for name, value in (("vx", vx), ("vy", 0.01), ("a", 2e-3)):
            res.set(name, value=value, err=0.01 * value)
        return res

    for wander, expected in ((0.03, (2.0, 4.0)), (0.003, (1.0, 1.0))):
        held = _Held(None, None, "hertz", "isotropic", "oblique")
        ends = np.arange(2.0, 8.0, 0.1)
        out = [held.widen(end, row(0.04 * (1 + wander * np.sin(np.pi * end / 2))), 2.0) for end in ends]
        factors, measured = np.array([f for f, _ in out]), np.array([m for _, m in out])
        # nothing 2 s earlier yet
        assert not measured[:20].any() and np.all(factors[:20] == np.maximum(UNCALIBRATED_WIDEN, 1.0))
        assert measured[20:].all()
        assert expected[0] <= factors[-1, 0] <= expected[1] and np.all(factors[-1, 1:] == 1.0)
    res = row(0.04)
    _widened(res, np.array([1.5, 1.0, 1.0]), np.array([False, True, True]))
    assert res["vx"].err == pytest.approx(1.5 * 0.01 * 0.04) and res["vy"].err == pytest.approx(0.01 * 0.01)
    assert "errors widened (vx 1.50x) until windows that share no sample can be compared" in res.message


def test_a_steady_misfit_is_no_reason_to_analyse_again_and_a_rise_is():
    """A lumpy window's steady misfit (reduced chi-square 2-3 throughout) does not call for a new analysis;
    a misfit that rises well above the held level does, and an acquisition that misfits (one across a change)
    does not lift the level that later updates are judged by."""
    from tactile_jax.track.tracker import misfit_rose

    steady = [2.4, 2.1, 2.9, 2.6, 2.2]
    assert not misfit_rose(3.1, steady) and not misfit_rose(3.9, steady)
    assert misfit_rose(7.9, steady) and misfit_rose(4.5, [1.1, 1.3, 0.9])
    assert misfit_rose(20.0, [11.3, 23.8, 22.2])            # the level is at most core.POOR_FIT_REDCHI
    assert not misfit_rose(1.9, []) and misfit_rose(2.1, [])


def _update(lump_sd):
    """An update of a slip (3, 1) cm/s, a 1.5 mm, as numpy arrays (nothing compiled)."""
    from tactile_jax.inference.core import N_KNOTS, N_PHYS, Errors
    from tactile_jax.inference.forward import INDEX
    from tactile_jax.track.step import TrackState, Update

    p = N_PHYS + N_KNOTS
    theta = np.zeros(p)
    theta[[INDEX["log_vx"], INDEX["log_vy"], INDEX["log_a"]]] = np.log([0.03, 0.01, 1.5e-3])
    free = np.zeros(p, bool)
    free[[INDEX["log_vx"], INDEX["log_vy"], INDEX["log_a"]]] = True
    sd = np.where(free, 0.02, 0.0)
    e = Errors(np.diag(sd ** 2), sd, np.ones(p), np.array(1.0), np.array(500.0), np.array(1.2), np.array(420.0),
               np.array(1e3), np.array(1e-4), np.zeros(p), np.array(True), np.array(False), np.array(0), np.array(30),
               np.array(True), np.zeros(p, bool), np.array(1.0), np.array(False))
    state = TrackState(theta, free, np.zeros(N_KNOTS), theta, np.zeros((10, p)), np.array(3), np.ones((2, 48), bool),
                       np.array(1), np.array(0.2), np.asarray(lump_sd, float))
    return Update(e, theta, np.array(0.2), np.array(False), np.array(True), state, np.array([30, 30]),
                  np.array([0.03, 0.01]))


@pytest.mark.parametrize("lump_sd", [(0.0, 0.0, 0.0), (0.4, 0.2, 0.45)])
def test_an_update_becomes_a_row(lump_sd):
    """An update's arrays make the row ``fit`` would write: its values, and the random effects where the
    acquisition fitted a lumpy texture with them."""
    from tactile_jax.inference.result import result_from_summary
    from tactile_jax.track.tracker import step_summary

    res = result_from_summary(step_summary(_update(lump_sd)))
    assert res.status == "ok" and res.vx == pytest.approx(0.03) and res.vy_err == pytest.approx(0.01 * 0.02)
    assert res.cross_pairs == 2
    assert ("random effects" in res.message) == any(lump_sd)


def test_a_poor_fit_says_whether_its_misfit_could_be_tested_for_a_trend():
    """A window whose band is too narrow for the trend test (no series of ``core.ROUGHNESS_MIN_ROWS`` bins: a
    slow oblique slip in 2 s) says so, instead of a trend ratio of nan read as a model that does not fit."""
    from tactile_jax.inference.result import result_from_summary
    from tactile_jax.track.tracker import step_summary

    u = _update((0.0, 0.0, 0.0))
    for roughness, said in ((4.0, "trend ratio 4.0 across frequency"), (np.nan, "the band is too narrow to test")):
        e = u.errors._replace(status=np.array(3), redchi=np.array(3.0), roughness=np.array(roughness))
        res = result_from_summary(step_summary(u._replace(errors=e)))
        assert res.status == "poor_fit" and said in res.message and "nan" not in res.message


def test_bad_blocks_are_one_line_errors():
    tracker = Tracker(FS, source="arm.h5")
    with pytest.raises(TactileInputError, match=r"arm.h5.*shape \(4, n\)"):
        tracker.push(np.zeros((3, 10)))
    block = np.zeros((4, 10))
    block[2, 5] = np.nan
    with pytest.raises(TactileInputError, match="NaN"):
        tracker.push(block)


def test_track_command_on_a_still_recording_writes_its_rows(tmp_path, rng):
    rec = _with_signals(simulate_path([Piece(3.0)], snr_db=None, seed=0), 1e-4 * rng.standard_normal((4, 3000)))
    path = write_recording(tmp_path / "still.h5", rec)
    out = tmp_path / "track.csv"
    result = CliRunner().invoke(main, ["track", str(path), "--out", str(out), "--quiet"])
    assert result.exit_code == 0, result.output
    assert "11 updates" in result.output and "no_slip 11" in result.output
    text = out.read_text().splitlines()
    header = text[0].split(",")
    assert {"t", "window_s", "vx", "vx_err", "vy", "vy_err", "a", "a_err", "status", "message"} <= set(header)
    assert len(text) == 12


def test_track_command_bad_settings_exit_2(tmp_path, rng):
    rec = _with_signals(simulate_path([Piece(3.0)], snr_db=None, seed=0), 1e-4 * rng.standard_normal((4, 3000)))
    path = write_recording(tmp_path / "still.h5", rec)
    result = CliRunner().invoke(main, ["track", str(path), "--hop", "5"])
    assert result.exit_code == 2
    assert result.output.strip().startswith("error:") and "--hop" in result.output
    result = CliRunner().invoke(main, ["track", str(path), "--window", "10"])
    assert result.exit_code == 2 and "less than one window" in result.output


def _with_signals(rec, signals):
    import dataclasses

    return dataclasses.replace(rec, signals=signals)


@pytest.mark.slow
def test_tracking_a_slip_on_the_gaussian_program():
    """Still, then a slide: no speed while still, then right values from the first window inside the slide;
    the rows do not depend on how the stream is cut into blocks."""
    rec = simulate_path([Piece(2.0), Piece(4.5, (0.04, 0.0), contact_radius=1.5e-3)], window="gaussian",
                        snr_db=45.0, seed=2, crossfade=0.03)
    from tactile_jax.inference.options import FitOptions

    options = FitOptions(**GAUSS)
    rows = track_recording(rec, window=2.0, hop=0.25, options=options)
    statuses = [r["status"] for r in rows]
    assert statuses[0] == "no_slip" and "slip_start" in statuses
    inside = [r for r in rows if (lambda p: p is not None and p["moving"])(truth_at(rec.truth, r["t"] - 1.0,
                                                                                      r["t"] + 1.0))]
    assert len(inside) >= 8
    # every window inside the slide has values, right to 1 %. At 45 dB each window's tapers hear the same few
    # texture modes (a lumpy spectrum), which the smooth texture model misfits with no trend across frequency:
    # such a step is ok with errors from that scatter, and says so
    assert all(r["status"] in ("ok", "poor_fit", "not_converged") for r in inside)
    assert any(r["status"] == "ok" for r in inside)
    for r in inside:
        assert abs(r["vx"] - 0.04) < 0.01 * 0.04 and abs(r["a"] - 1.5e-3) < 0.02 * 1.5e-3
    lumpy = [r for r in inside if "lumpy texture: the spectra scatter" in r["message"]]
    assert lumpy and all(r["status"] == "ok" and abs(r["vx"] - 0.04) < 3 * r["vx_err"] for r in lumpy)
    # one analysis acquires the slide (its window may reach into the crossfade); updates follow it
    assert {r["update"] for r in rows if r["vx"] is not None} == {"analysis", "step"}
    assert sum(r["update"] == "step" for r in inside) >= len(inside) - 1
    tracker = Tracker(rec.fs, window=2.0, hop=0.25, options=options)
    again = []
    for block in np.array_split(rec.signals, 13, axis=1):
        again += tracker.push(block)
    assert [r["status"] for r in again] == statuses
    for a, b in zip(rows, again):
        for q in ("vx", "vy", "a", "vx_err"):
            assert (a[q] is None and b[q] is None) or a[q] == pytest.approx(b[q], rel=1e-9)
