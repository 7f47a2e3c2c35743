"""Paths of pieces: boundaries in the truth, one noise process, smooth joins, truth_at, bad pieces.

Short pieces (0.5-1 s at 1 kHz, small contacts) keep every simulation in the
tens of milliseconds.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from tactile_jax.errors import TactileInputError
from tactile_jax.io.recording import validate_recording
from tactile_jax.model.sensor import PAPER_SENSOR
from tactile_jax.simulation.path import Piece, simulate_path, standard_paths, truth_at
from tactile_jax.simulation.path import _ramp
from tactile_jax.simulation.scene import Scene, simulate

A = 1.5e-3
FS = 1000.0
PIECES = [
    Piece(0.5, (0.0, 0.0), contact_radius=A),
    Piece(0.8, (0.03, 0.0), contact_radius=A),
    Piece(0.6, (0.02, 0.02), contact_depth=0.1e-3),
    Piece(0.7, (0.01, 0.04), contact_radius=A),
]


@pytest.fixture(scope="module")
def noisy():
    return simulate_path(PIECES, fs=FS, snr_db=40.0, seed=3)


@pytest.fixture(scope="module")
def clean():
    return simulate_path(PIECES, fs=FS, snr_db=None, seed=3)


def _bounds(rec):
    return [(int(round(p["start"] * FS)), int(round(p["end"] * FS))) for p in rec.truth["path"]]


def test_truth_holds_the_pieces(noisy):
    truth = noisy.truth
    json.dumps(truth)
    validate_recording(noisy)
    path = truth["path"]
    assert [(p["start"], p["end"]) for p in path] == pytest.approx([(0.0, 0.5), (0.5, 1.3), (1.3, 1.9), (1.9, 2.6)])
    assert noisy.signals.shape == (4, 2600) and truth["n_samples"] == 2600
    assert truth["duration"] == pytest.approx(2.6)
    assert [(p["vx"], p["vy"]) for p in path] == [(0.0, 0.0), (0.03, 0.0), (0.02, 0.02), (0.01, 0.04)]
    assert path[2]["a"] == pytest.approx(math.sqrt(PAPER_SENSOR.curvature_radius * 0.1e-3))
    assert path[2]["contact_depth"] == pytest.approx(0.1e-3)
    assert path[0]["a"] == path[1]["a"] == A
    assert all(p["window"] == "hertz" for p in path)
    assert [p["moving"] for p in path] == [False, True, True, True]
    seeds = [p["seed"] for p in path]
    assert seeds[0] is None and len(set(seeds[1:])) == 3
    assert truth["texture"]["name"] == "RandomTexture"
    assert truth["snr_db"] == 40.0 and truth["seed"] == 3 and truth["crossfade"] == pytest.approx(0.005)
    assert noisy.velocity is None and noisy.fs == FS


def test_one_noise_process_of_constant_std(noisy, clean):
    """sigma from the moving pieces' shallow power; the same std in every piece, the still one included."""
    bounds = _bounds(clean)
    moving = np.concatenate([np.arange(b0, b1) for (b0, b1), p in zip(bounds, PIECES) if p.moving])
    p_ref = max(np.mean(clean.signals[0, moving] ** 2), np.mean(clean.signals[2, moving] ** 2))
    sigma = math.sqrt(p_ref) * 10 ** (-40.0 / 20)
    assert noisy.truth["noise_std"] == pytest.approx(sigma, rel=1e-12)
    noise = noisy.signals - clean.signals
    for b0, b1 in bounds:
        assert np.std(noise[:, b0:b1]) == pytest.approx(sigma, rel=0.06)
    b0, b1 = bounds[0]
    assert np.all(clean.signals[:, b0:b1] == 0.0)                 # a still piece: no signal ...
    assert np.std(noisy.signals[:, b0:b1]) == pytest.approx(sigma, rel=0.06)   # ... only the noise


def test_pieces_are_scenes_joined_by_complementary_ramps():
    """Two moving pieces: each is scene.simulate of its seed, crossfaded over 5 samples centred on the join."""
    pieces = [Piece(0.5, (0.03, 0.0), contact_radius=A), Piece(0.4, (0.0, -0.02), contact_radius=A)]
    rec = simulate_path(pieces, fs=FS, snr_db=None, seed=7, crossfade=0.005)
    s0, s1 = (p["seed"] for p in rec.truth["path"])
    b, hl, hr = 500, 2, 3
    first = simulate(Scene(velocity=(0.03, 0.0), contact_radius=A, window="hertz", fs=FS,
                           duration=(b + hr) / FS, snr_db=None, seed=s0)).signals
    second = simulate(Scene(velocity=(0.0, -0.02), contact_radius=A, window="hertz", fs=FS,
                            duration=(900 - b + hl) / FS, snr_db=None, seed=s1)).signals
    fade_in = _ramp(5)
    expect = np.empty((4, 900))
    expect[:, :b - hl] = first[:, :b - hl]
    expect[:, b - hl:b + hr] = first[:, b - hl:] * (1 - fade_in) + second[:, :hl + hr] * fade_in
    expect[:, b + hr:] = second[:, hl + hr:]
    np.testing.assert_allclose(rec.signals, expect, rtol=0, atol=1e-12 * np.abs(expect).max())


def test_still_to_moving_fades_in_without_a_step(clean):
    (_, b), _ = _bounds(clean)[:2]
    sig = clean.signals
    assert np.all(sig[:, :b] == 0.0)
    scale = np.abs(sig[:, b:b + 800]).max(axis=1)
    assert np.all(np.abs(sig[:, b]) <= _ramp(5)[0] * scale + 1e-30)
    assert np.all(np.abs(sig[:, b + 5:b + 200]).max(axis=1) > 0.2 * scale)   # full strength after the fade


@pytest.mark.parametrize("crossfade, bound", [(0.005, "signal"), (0.05, "smooth")])
def test_joins_are_continuous(noisy, crossfade, bound):
    """No jump at a join beyond a few noise sigmas plus the signal's scale (5 ms); as smooth as the
    pieces themselves with a 50 ms crossfade."""
    rec = noisy if crossfade == 0.005 else simulate_path(PIECES, fs=FS, snr_db=40.0, seed=3, crossfade=crossfade)
    sigma = rec.truth["noise_std"]
    jumps = np.abs(np.diff(rec.signals, axis=1))
    near = np.zeros(jumps.shape[1], dtype=bool)
    for b0, _ in _bounds(rec)[1:]:
        near[b0 - 40:b0 + 40] = True
    rms = np.sqrt(np.mean(rec.signals ** 2, axis=1))
    at_joins, inside = jumps[:, near].max(axis=1), jumps[:, ~near].max(axis=1)
    if bound == "signal":
        assert np.all(at_joins <= 4 * sigma + rms)           # a cut (crossfade 0) reaches 1.5-1.9x this
    else:
        assert np.all(at_joins <= 1.5 * inside)


def test_crossfade_zero_cuts_and_seed_reproduces(clean):
    again = simulate_path(PIECES, fs=FS, snr_db=None, seed=3)
    np.testing.assert_array_equal(again.signals, clean.signals)
    other = simulate_path(PIECES, fs=FS, snr_db=None, seed=4)
    assert not np.allclose(other.signals, clean.signals)
    cut = simulate_path(PIECES, fs=FS, snr_db=None, seed=3, crossfade=0.0)
    (_, b) = _bounds(cut)[0]
    assert np.all(cut.signals[:, :b] == 0.0) and np.all(cut.signals[:, b] != 0.0)


def test_truth_at(noisy):
    path = noisy.truth["path"]
    assert truth_at(noisy.truth, 0.6, 1.2) == path[1]
    assert truth_at(noisy, 0.5, 1.3) == path[1]                    # a Recording works too
    assert truth_at(noisy.truth, 0.497, 1.303) == path[1]          # within the crossfade
    assert truth_at(noisy.truth, 0.4, 1.2) is None                 # across a join
    assert truth_at(noisy.truth, 1.0, 2.0) is None
    assert truth_at(noisy.truth, 2.0, 2.6) == path[3]
    assert truth_at(noisy.truth, 0.0, 0.5) == path[0]
    assert truth_at(noisy.truth, 3.0, 4.0) is None                 # after the recording
    got = truth_at(noisy.truth, 0.1, 0.2)
    got["vx"] = 1.0
    assert path[0]["vx"] == 0.0                                    # a copy
    with pytest.raises(TactileInputError):
        truth_at(noisy.truth, 1.0, 0.5)
    with pytest.raises(TactileInputError):
        truth_at({"vx": 0.0}, 0.0, 1.0)


@pytest.mark.parametrize("make", [
    lambda: Piece(-1.0, (0.03, 0.0), contact_radius=A),
    lambda: Piece(0.0, (0.0, 0.0)),
    lambda: Piece(1.0, (0.03, 0.0), contact_radius=A, contact_depth=0.1e-3),
    lambda: Piece(1.0, (0.0, 0.0), contact_radius=A, contact_depth=0.1e-3),
    lambda: Piece(1.0, (0.03, 0.0)),
    lambda: Piece(1.0, (0.03, float("nan")), contact_radius=A),
    lambda: Piece(1.0, (0.03,), contact_radius=A),
    lambda: Piece(1.0, (0.03, 0.0), contact_radius=-A),
    lambda: simulate_path([]),
    lambda: simulate_path([Piece(1.0, (0.03, 0.0), contact_radius=A), (1.0, 0.0)]),
    lambda: simulate_path([Piece(0.5, (0.0, 0.0))]),                          # no moving piece sets sigma
    lambda: simulate_path([Piece(0.5, (0.03, 0.0), contact_radius=A)], window="disk"),
    lambda: simulate_path([Piece(0.5, (0.0, 0.0)), Piece(0.003, (0.03, 0.0), contact_radius=A)]),
    lambda: simulate_path([Piece(0.5, (0.03, 0.0), contact_radius=A)], crossfade=-0.01),
    lambda: simulate_path([Piece(0.5, (0.03, 0.0), contact_radius=A)], seed=-1),
])
def test_bad_pieces_raise_one_line(make):
    with pytest.raises(TactileInputError) as info:
        make()
    assert "\n" not in str(info.value) and info.value.code == "bad_setting"


def test_still_pieces_need_no_contact_and_are_silent_without_noise():
    rec = simulate_path([Piece(0.2, (0.0, 0.0)), Piece(0.3, (0.0, 0.0), contact_depth=0.1e-3)], snr_db=None)
    assert rec.signals.shape == (4, 500) and not rec.signals.any()
    assert rec.truth["path"][0]["a"] is None and rec.truth["path"][1]["a"] == pytest.approx(math.sqrt(3e-6))


def test_standard_paths():
    paths = standard_paths()
    assert {"still_then_slide", "axis_oblique_y", "press_deeper"} <= set(paths)
    for pieces in paths.values():
        assert all(isinstance(p, Piece) for p in pieces)
        assert 4.0 <= sum(p.duration for p in pieces) <= 20.0
    still, slide = paths["still_then_slide"]
    assert not still.moving and still.duration == 2.0 and slide.velocity == (0.03, 0.0) and slide.duration == 4.0
    assert [p.velocity for p in paths["axis_oblique_y"]] == [(0.03, 0.0), (0.02, 0.02), (0.01, 0.04)]
    shallow, deep = paths["press_deeper"]
    assert shallow.radius(PAPER_SENSOR) == pytest.approx(math.sqrt(0.03 * 0.05e-3))
    assert deep.radius(PAPER_SENSOR) == pytest.approx(math.sqrt(0.03 * 0.15e-3))
