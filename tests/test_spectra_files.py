"""Spectra files: a file written from a recording fits like the recording, a file without the x-y
cross-spectra still fits (and says what that costs), and Welch segments too short to give a band are refused."""

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import GAUSS
from tactile_jax.cli import main
from tactile_jax.errors import TactileInputError
from tactile_jax.inference.fit import NO_XY_MESSAGE, fit_recording, fit_spectra
from tactile_jax.inference.options import FitOptions
from tactile_jax.io.files import SpectraData, read_recording, read_spectra, write_recording, write_spectra
from tactile_jax.inference import core
from tactile_jax.spectral.segments import N_GROUPS, Segments, from_spectra, min_nperseg, segments, to_spectra
from tactile_jax.io.recording import Recording
from tactile_jax.simulation.scene import Scene, simulate

#: what a fit reports, compared between a recording and its spectra file
COMPARED = ("vx", "vx_err", "vy", "vy_err", "a", "a_err", "redchi", "error_scale")


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory):
    rec = simulate(Scene(velocity=(0.03, 0.02), contact_radius=2e-3, duration=8.0, seed=3))
    return write_recording(tmp_path_factory.mktemp("spectra_files") / "scene.h5", rec)


@pytest.fixture(scope="module")
def spectra_file(scene_file):
    path = scene_file.with_name("scene_spectra.npz")
    res = CliRunner().invoke(main, ["spectra", str(scene_file), "--out", str(path)])
    assert res.exit_code == 0, res.output
    return path


def _back(data: SpectraData) -> Segments:
    groups = (data.group_count, data.group_psd, data.group_csd, data.group_xy)
    return from_spectra(data.omega, data.psd, data.csd, data.xy, dof=data.n_segments, groups=groups,
                        kernel=data.kernel, bin_factor=data.bin_factor, whitening=data.whitening, fs=data.fs)


@pytest.mark.parametrize("kw", [{}, {"nperseg": 256}, {"method": "multitaper"}])
def test_segments_come_back_from_a_spectra_file(scene_file, tmp_path, kw):
    """Every input of the fit's program that a spectra file carries comes back (the segment length is
    not one the program reads)."""
    rec = read_recording(scene_file)
    seg = segments(rec.signals, rec.fs, **kw)
    data = read_spectra(write_spectra(tmp_path / "s.h5", SpectraData(**to_spectra(seg), depths=rec.depths)))
    assert data.xy.shape == (4, data.omega.size) and data.group_count.sum() == seg.count.sum()
    back = _back(data)
    for name in Segments._fields:
        if name == "nperseg":
            continue
        got, want = np.asarray(getattr(back, name)), np.asarray(getattr(seg, name))
        assert got.shape == want.shape and got.dtype == want.dtype, name
        np.testing.assert_allclose(got, want, rtol=1e-15, atol=0, err_msg=name)


def test_groups_beyond_the_grid_merge_consecutively():
    """Per-segment spectra from elsewhere: more groups than ``N_GROUPS`` are merged, none is lost."""
    rng = np.random.default_rng(0)
    g, m = 45, 40
    count = np.ones(g)
    gpsd = rng.uniform(0.5, 1.0, (g, 4, m))
    gcsd = gpsd[:, 0::2] * 0.5 + 0j
    seg = from_spectra(np.arange(m) * 2.0, gpsd.mean(0), gcsd.mean(0), dof=g, groups=(count, gpsd, gcsd, None))
    assert seg.count.sum() == g and np.all(seg.count >= 1) and seg.count.size == N_GROUPS
    np.testing.assert_allclose(seg.auto.sum(0)[:, :m] / g, gpsd.mean(0), rtol=1e-13)
    np.testing.assert_array_equal(seg.auto[0, :, :m], gpsd[0] + gpsd[1])
    assert not seg.xy.any() and float(seg.overlap) == 1.0


def test_spectra_file_fits_like_its_recording(scene_file, spectra_file):
    direct = fit_recording(read_recording(scene_file), FitOptions(**GAUSS))
    got = fit_spectra(read_spectra(spectra_file), FitOptions(**GAUSS))
    assert direct.status == got.status == "ok", (direct.message, got.message)
    for name in COMPARED:
        assert getattr(got, name) == pytest.approx(getattr(direct, name), rel=1e-9, abs=0), name
    assert got.error_method == direct.error_method and got.error_method.startswith("laplace x jackknife")
    assert got.cross_pairs == direct.cross_pairs > 0
    assert got.message == direct.message and got.file == str(spectra_file)


def test_spectra_file_without_cross_pair_spectra_fits_and_says_so(scene_file, spectra_file, tmp_path):
    """x-y cross-spectra absent (an older file): no x-y chain, said in the message; without groups the
    errors are the bin-correlation fallback."""
    full = read_spectra(spectra_file)
    direct = fit_spectra(full, FitOptions(**GAUSS))
    for drop, method in ((("xy", "group_xy"), "laplace x jackknife"),
                         (("xy", "group_count", "group_psd", "group_csd", "group_xy"), "laplace x max(redchi, 1)")):
        path = write_spectra(tmp_path / "old.npz", full._replace(**dict.fromkeys(drop)))
        res = fit_spectra(read_spectra(path), FitOptions(**GAUSS))
        assert res.status == "ok" and res.cross_pairs == 0 and res.error_method.startswith(method), res.message
        assert NO_XY_MESSAGE in res.message and "x-y chain is off" in res.message
        for name in ("vx", "vy", "a"):
            assert abs(getattr(res, name) - getattr(direct, name)) < 3 * getattr(direct, name + "_err"), name
    assert NO_XY_MESSAGE not in direct.message


# --------------------------------------------------------------------------- segment length


def test_shortest_segment_holds_the_fewest_bins_a_fit_takes():
    n = min_nperseg()
    x = np.random.default_rng(0).standard_normal((4, 2000))
    seg = segments(x, 1000.0, nperseg=n, prewhiten=0)
    assert int(seg.n_valid) - 2 == core.MIN_BINS                 # band.select never uses DC or the top bin
    for short, needle in ((n - 1, f"nperseg={n - 1} is too short to give a band"), (3, f"at least {n} samples"),
                          (3.5, "whole number")):
        with pytest.raises(TactileInputError) as info:
            segments(x, 1000.0, nperseg=short, source="rec.h5")
        assert info.value.code == "bad_setting" and str(info.value).startswith("rec.h5: ") and needle in str(info.value)


def test_fit_refuses_a_segment_too_short_naming_the_file():
    rec = Recording(np.random.default_rng(0).standard_normal((4, 1000)), 1000.0, (0.265e-3, 0.925e-3),
                    source="rec.h5")
    with pytest.raises(TactileInputError, match=rf"^rec\.h5: nperseg=3 is too short .* at least {min_nperseg()} "):
        fit_recording(rec, FitOptions(nperseg=3))


def test_spectra_command_refuses_a_segment_too_short(scene_file, tmp_path):
    out = tmp_path / "s.npz"
    res = CliRunner().invoke(main, ["spectra", str(scene_file), "--out", str(out), "--nperseg", "3"])
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert res.exit_code == 2 and len(lines) == 1, res.output
    assert lines[0].startswith(f"error: {scene_file}: nperseg=3 is too short") and f"at least {min_nperseg()}" in lines[0]
    assert not out.exists()
