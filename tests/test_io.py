"""File I/O of the data contract: round trips, tolerant HDF5 layouts, one-line errors, atomic writes."""

from __future__ import annotations

import json
import os

import h5py
import numpy as np
import pytest

from tactile_jax.io import files as tio
from tactile_jax.errors import TactileInputError
from tactile_jax.io.files import (
    RECORDING_SUFFIXES,
    SpectraData,
    is_recording_file,
    read_recording,
    read_recording_header,
    read_spectra,
    write_recording,
    write_spectra,
)
from tactile_jax.io.recording import Recording

DEPTHS = (0.265e-3, 0.925e-3)
SUFFIXES = [".h5", ".hdf5", ".npz"]


def _recording(shape=(4, 64), dtype=np.float32, **kw) -> Recording:
    rng = np.random.default_rng(0)
    return Recording(signals=rng.standard_normal(shape).astype(dtype), fs=2000.0, depths=DEPTHS, **kw)


def _leftovers(directory) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if p.name.endswith(".tmp"))


def _expect(path, code: str, func=read_recording) -> TactileInputError:
    with pytest.raises(TactileInputError) as info:
        func(path)
    err = info.value
    msg = str(err)
    assert "\n" not in msg
    assert str(path) in msg
    assert err.source == str(path)
    assert err.code == code, msg
    return err


def _write_raw(path, **items):
    """Write keys as they are: NPZ members, or HDF5 datasets (arrays) / root attributes (the rest)."""
    if path.suffix == ".npz":
        np.savez(path, **items)
        return
    with h5py.File(path, "w") as f:
        for k, v in items.items():
            if isinstance(v, np.ndarray) and v.ndim >= 2:
                f.create_dataset(k, data=v)
            else:
                f.attrs[k] = v


def _good_items(**over):
    items = {"signals": np.zeros((4, 32)), "fs": np.float64(1000.0), "depths": np.array(DEPTHS)}
    items.update(over)
    return {k: v for k, v in items.items() if v is not None}


# --------------------------------------------------------------------------- recordings


@pytest.mark.parametrize("suffix", SUFFIXES)
@pytest.mark.parametrize("shape", [(4, 64), (3, 4, 50)])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_recording_round_trip(tmp_path, suffix, shape, dtype):
    rec = _recording(shape, dtype)
    path = tmp_path / f"rec{suffix}"
    assert write_recording(path, rec) == path
    got = read_recording(path)
    assert got.signals.dtype == np.dtype(dtype)
    np.testing.assert_array_equal(got.signals, rec.signals)
    assert got.fs == 2000.0 and isinstance(got.fs, float)
    assert got.depths == DEPTHS
    assert got.curvature_radius is None and got.velocity is None and got.gain_ratio is None
    assert got.truth == {}
    assert got.source == str(path)
    assert _leftovers(tmp_path) == []
    assert is_recording_file(path)


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_recording_optional_fields_and_truth(tmp_path, suffix):
    truth = {"vx": 0.023, "vy": -0.001, "a": 1.5e-3, "texture": {"kind": "grating", "k": [1.0, 2.0]},
             "seed": np.int64(7), "spectrum": np.arange(3.0)}
    rec = _recording(curvature_radius=0.03, velocity=(0.023, -0.001), gain_ratio=(1.1, 0.9), truth=truth)
    path = write_recording(tmp_path / f"rec{suffix}", rec)
    got = read_recording(path)
    assert got.curvature_radius == 0.03
    assert got.velocity == (0.023, -0.001)
    assert got.gain_ratio == (1.1, 0.9)
    assert got.truth == {**truth, "seed": 7, "spectrum": [0.0, 1.0, 2.0]}

    scalar_gain = write_recording(tmp_path / f"g{suffix}", _recording(gain_ratio=1.2))
    assert read_recording(scalar_gain).gain_ratio == 1.2


def test_hdf5_layout_written(tmp_path):
    path = write_recording(tmp_path / "rec.h5", _recording(curvature_radius=0.03, truth={"vx": 0.01}))
    with h5py.File(path, "r") as f:
        assert list(f.keys()) == ["signals"]
        assert f.attrs["fs"] == 2000.0
        assert json.loads(f.attrs["truth"]) == {"vx": 0.01}
        assert "velocity" not in f.attrs and "gain_ratio" not in f.attrs


def test_large_truth_goes_to_a_dataset(tmp_path):
    truth = {"spectrum": list(np.linspace(0, 1, 20000))}
    path = write_recording(tmp_path / "rec.h5", _recording(truth=truth))
    assert read_recording(path).truth == truth


def test_hdf5_scalars_as_datasets(tmp_path):
    path = tmp_path / "ds.h5"
    sig = np.ones((2, 4, 16), dtype=np.float32)
    with h5py.File(path, "w") as f:
        f.create_dataset("signals", data=sig)
        f.create_dataset("fs", data=500.0)
        f.create_dataset("depths", data=np.array(DEPTHS))
        f.create_dataset("velocity", data=np.array([0.01, 0.0]))
        f.create_dataset("gain_ratio", data=1.05)
        f.create_dataset("truth", data=json.dumps({"a": 1}))
    got = read_recording(path)
    assert got.signals.dtype == np.float32 and got.signals.shape == (2, 4, 16)
    assert got.fs == 500.0 and got.depths == DEPTHS
    assert got.velocity == (0.01, 0.0) and got.gain_ratio == 1.05
    assert got.truth == {"a": 1}


def test_big_endian_float32_stays_float32(tmp_path):
    path = tmp_path / "be.h5"
    _write_raw(path, **_good_items(signals=np.ones((4, 8), dtype=">f4")))
    assert read_recording(path).signals.dtype == np.float32


def test_is_recording_file(tmp_path):
    write_spectra(tmp_path / "spec.npz", SpectraData(omega=np.arange(4.0), ratio=np.ones((2, 4)), depths=DEPTHS))
    (tmp_path / "junk.h5").write_bytes(b"not hdf5 at all")
    (tmp_path / "junk.npz").write_bytes(b"PK but not a zip")
    (tmp_path / "notes.txt").write_text("hello")
    write_recording(tmp_path / "rec.npz", _recording())
    assert is_recording_file(tmp_path / "rec.npz")
    for name in ("spec.npz", "junk.h5", "junk.npz", "notes.txt", "missing.h5"):
        assert not is_recording_file(tmp_path / name), name
    assert not is_recording_file(tmp_path)
    assert not is_recording_file(None)


# --------------------------------------------------------------------------- bad recordings


def test_missing_file(tmp_path):
    err = _expect(tmp_path / "nope.h5", "unreadable")
    assert "not found" in str(err)


@pytest.mark.parametrize("suffix", SUFFIXES)
@pytest.mark.parametrize("content", [b"", b"garbage bytes \x00\x01\x02" * 10, b"PK\x03\x04 truncated zip"])
def test_garbage_bytes(tmp_path, suffix, content):
    path = tmp_path / f"bad{suffix}"
    path.write_bytes(content)
    _expect(path, "unreadable")


def test_npy_saved_as_npz(tmp_path):
    path = tmp_path / "array.npz"
    with open(path, "wb") as fh:
        np.save(fh, np.zeros((4, 8)))
    _expect(path, "unreadable")


def test_unknown_suffix(tmp_path):
    path = tmp_path / "rec.mat"
    path.write_bytes(b"whatever")
    err = _expect(path, "unreadable")
    for suffix in RECORDING_SUFFIXES:
        assert suffix in str(err)
    with pytest.raises(TactileInputError) as info:
        write_recording(path, _recording())
    assert info.value.code == "unreadable"
    assert path.read_bytes() == b"whatever"


@pytest.mark.parametrize("suffix", SUFFIXES)
@pytest.mark.parametrize("key", ["signals", "fs", "depths"])
def test_missing_key(tmp_path, suffix, key):
    path = tmp_path / f"m{suffix}"
    _write_raw(path, **_good_items(**{key: None}))
    err = _expect(path, "missing_key")
    assert f"'{key}'" in str(err)


def test_spectra_file_read_as_recording_hints(tmp_path):
    path = write_spectra(tmp_path / "s.h5", SpectraData(omega=np.arange(3.0), ratio=np.ones((2, 3)), depths=DEPTHS))
    err = _expect(path, "missing_key")
    assert "read_spectra" in str(err)


@pytest.mark.parametrize("suffix", SUFFIXES)
@pytest.mark.parametrize(
    "over, code",
    [
        ({"fs": np.float64(0.0)}, "bad_fs"),
        ({"fs": np.float64(-10.0)}, "bad_fs"),
        ({"fs": np.float64(np.nan)}, "bad_fs"),
        ({"fs": np.array([1.0, 2.0])}, "bad_fs"),
        ({"depths": np.array([0.9e-3, 0.3e-3])}, "bad_depths"),
        ({"depths": np.array([0.3e-3, 0.3e-3])}, "bad_depths"),
        ({"depths": np.array([0.1e-3, 0.3e-3, 0.5e-3])}, "bad_depths"),
        ({"signals": np.zeros((3, 32))}, "bad_shape"),
        ({"signals": np.zeros((2, 5, 32))}, "bad_shape"),
        ({"signals": np.zeros((4, 1))}, "too_short"),
        ({"velocity": np.array([0.01, 0.02, 0.03])}, "bad_setting"),
        ({"gain_ratio": np.float64(-1.0)}, "bad_setting"),
        ({"curvature_radius": np.float64(0.0)}, "bad_setting"),
        ({"truth": "{not json"}, "unreadable"),
        ({"truth": "[1, 2]"}, "unreadable"),
    ],
)
def test_bad_values(tmp_path, suffix, over, code):
    path = tmp_path / f"bad{suffix}"
    _write_raw(path, **_good_items(**over))
    _expect(path, code)


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_nan_sample(tmp_path, suffix):
    sig = np.zeros((4, 32), dtype=np.float32)
    sig[2, 5] = np.nan
    path = tmp_path / f"nan{suffix}"
    _write_raw(path, **_good_items(signals=sig))
    err = _expect(path, "nonfinite")
    assert "[2, 5]" in str(err)


def test_hdf5_group_instead_of_array(tmp_path):
    path = tmp_path / "g.h5"
    with h5py.File(path, "w") as f:
        f.create_group("signals")
        f.attrs["fs"] = 1000.0
        f.attrs["depths"] = np.array(DEPTHS)
    _expect(path, "bad_shape")


def test_write_rejects_invalid_recording(tmp_path):
    bad = _recording()
    bad.signals[0, 0] = np.nan
    path = tmp_path / "out.npz"
    with pytest.raises(TactileInputError) as info:
        write_recording(path, bad)
    assert info.value.code == "nonfinite" and str(path) in str(info.value)
    assert not path.exists() and _leftovers(tmp_path) == []


# --------------------------------------------------------------------------- atomic writes


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_unserialisable_truth_does_not_clobber(tmp_path, suffix):
    path = write_recording(tmp_path / f"rec{suffix}", _recording())
    before = path.read_bytes()
    with pytest.raises(TactileInputError) as info:
        write_recording(path, _recording(truth={"obj": object()}))
    assert info.value.code == "bad_setting" and "\n" not in str(info.value)
    assert path.read_bytes() == before
    assert _leftovers(tmp_path) == []


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_failure_mid_write_does_not_clobber(tmp_path, suffix, monkeypatch):
    path = write_recording(tmp_path / f"rec{suffix}", _recording())
    before = path.read_bytes()
    real_h5, real_npz = tio._write_h5, tio._write_npz

    def partial_h5(tmp, arrays, attrs):
        real_h5(tmp, arrays, attrs)
        raise OSError("disk full")

    def partial_npz(fh, arrays, attrs):
        real_npz(fh, arrays, attrs)
        raise OSError("disk full")

    monkeypatch.setattr(tio, "_write_h5", partial_h5)
    monkeypatch.setattr(tio, "_write_npz", partial_npz)
    with pytest.raises(OSError, match="disk full"):
        write_recording(path, _recording((2, 4, 10)))
    assert path.read_bytes() == before
    assert _leftovers(tmp_path) == []
    assert read_recording(path).signals.shape == (4, 64)


def test_overwrite_replaces(tmp_path):
    path = write_recording(tmp_path / "rec.h5", _recording())
    write_recording(path, _recording((2, 4, 10), np.float64))
    assert read_recording(path).signals.shape == (2, 4, 10)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.h5"]


def test_written_file_respects_umask(tmp_path):
    path = write_recording(tmp_path / "rec.npz", _recording())
    umask = os.umask(0)
    os.umask(umask)
    assert (path.stat().st_mode & 0o777) == (0o666 & ~umask)


# --------------------------------------------------------------------------- spectra


def _spectra_psd(m=16) -> SpectraData:
    rng = np.random.default_rng(1)
    omega = np.linspace(0.0, 600.0, m)
    psd = rng.uniform(0.1, 2.0, (4, m))
    csd = rng.standard_normal((2, m)) + 1j * rng.standard_normal((2, m))
    return SpectraData(omega=omega, psd=psd, csd=csd, n_segments=12.0, depths=DEPTHS,
                       curvature_radius=0.03, velocity=(0.02, 0.0), gain_ratio=1.1,
                       kernel=np.array([[-1.0, 0.0, 1.0], [0.25, 0.5, 0.25]]), bin_factor=1.94,
                       whitening=np.array([[1.0, -0.9, 0.1], [1.0, -0.8, 0.05]]), fs=1000.0)


def _spectra_matrix(m=16, g=3) -> SpectraData:
    """The whole 4 x 4 spectral matrix with its groups of segments (what ``tactile-jax spectra`` writes)."""
    rng = np.random.default_rng(2)
    count = np.array([2.0, 1.0, 3.0])[:g]
    gpsd = rng.uniform(0.1, 2.0, (g, 4, m))
    gcsd = rng.standard_normal((g, 2, m)) + 1j * rng.standard_normal((g, 2, m))
    gxy = rng.standard_normal((g, 4, m)) + 1j * rng.standard_normal((g, 4, m))
    mean = lambda a: np.tensordot(count, a, axes=1) / count.sum()  # noqa: E731
    return _spectra_psd(m)._replace(psd=mean(gpsd), csd=mean(gcsd), xy=mean(gxy), group_count=count,
                                    group_psd=gpsd, group_csd=gcsd, group_xy=gxy)


def _spectra_ratio(m=16) -> SpectraData:
    omega = np.linspace(10.0, 600.0, m)
    ratio = np.exp(-np.outer([1.0, 2.0], omega) * 1e-3)
    return SpectraData(omega=omega, ratio=ratio, ratio_err=np.full((2, m), 0.05), depths=DEPTHS)


@pytest.mark.parametrize("suffix", SUFFIXES)
@pytest.mark.parametrize("make", [_spectra_psd, _spectra_ratio, _spectra_matrix])
def test_spectra_round_trip(tmp_path, suffix, make):
    data = make()
    path = tmp_path / f"spec{suffix}"
    assert write_spectra(path, data) == path
    got = read_spectra(path)
    assert got.source == str(path)
    for field in ("omega", "psd", "csd", "xy", "group_count", "group_psd", "group_csd", "group_xy", "ratio",
                  "ratio_err", "kernel", "whitening"):
        want, have = getattr(data, field), getattr(got, field)
        if want is None:
            assert have is None, field
        else:
            assert have.dtype == want.dtype, field
            np.testing.assert_array_equal(have, want)
    for field in ("n_segments", "depths", "curvature_radius", "velocity", "gain_ratio", "bin_factor", "fs"):
        assert getattr(got, field) == getattr(data, field), field
    assert not is_recording_file(path)
    assert _leftovers(tmp_path) == []


def _spectra_items(**over):
    m = 8
    items = {"omega": np.linspace(0, 100, m), "psd": np.ones((4, m)), "depths": np.array(DEPTHS)}
    items.update(over)
    return {k: v for k, v in items.items() if v is not None}


@pytest.mark.parametrize("suffix", [".h5", ".npz"])
@pytest.mark.parametrize(
    "over, code",
    [
        ({"omega": None}, "missing_key"),
        ({"psd": None}, "missing_key"),
        ({"depths": None}, "missing_key"),
        ({"csd": np.ones((2, 8), complex), "psd": None, "ratio": np.ones((2, 8))}, "missing_key"),
        ({"ratio_err": np.ones((2, 8))}, "missing_key"),
        ({"omega": np.linspace(-1, 100, 8)}, "bad_shape"),
        ({"omega": np.ones((2, 8))}, "bad_shape"),
        ({"omega": np.zeros(0), "psd": np.ones((4, 0))}, "too_short"),
        ({"psd": np.ones((4, 7))}, "bad_shape"),
        ({"psd": np.ones((2, 8))}, "bad_shape"),
        ({"csd": np.ones((4, 8), complex)}, "bad_shape"),
        ({"psd": np.full((4, 8), np.inf)}, "nonfinite"),
        ({"psd": None, "ratio": np.full((2, 8), np.nan)}, "nonfinite"),
        ({"psd": None, "ratio": np.zeros((2, 8))}, "bad_shape"),
        ({"psd": None, "ratio": np.ones((2, 8)), "ratio_err": np.zeros((2, 8))}, "bad_shape"),
        ({"n_segments": np.float64(0.0)}, "bad_setting"),
        ({"bin_factor": np.float64(-1.0)}, "bad_setting"),
        ({"kernel": np.ones(3)}, "bad_shape"),
        ({"kernel": np.array([[0.0, 1.0], [0.7, 0.7]])}, "bad_shape"),
        ({"whitening": np.ones((2, 3))}, "missing_key"),
        ({"whitening": np.ones((3, 3)), "fs": np.float64(1e3)}, "bad_shape"),
        ({"depths": np.array([1e-3, 0.5e-3])}, "bad_depths"),
        ({"depths": np.array([-1e-3, 0.5e-3])}, "bad_depths"),
    ],
)
def test_bad_spectra(tmp_path, suffix, over, code):
    path = tmp_path / f"bad{suffix}"
    _write_raw(path, **_spectra_items(**over))
    err = _expect(path, code, read_spectra)
    if over.get("psd", 0) is None and "ratio" not in over:
        assert "'psd'" in str(err) and "'ratio'" in str(err)


def _matrix_items(**over):
    data = _spectra_matrix(m=8)
    items = {k: getattr(data, k) for k in ("omega", "psd", "csd", "xy", "group_count", "group_psd", "group_csd",
                                           "group_xy")}
    items["depths"] = np.array(DEPTHS)
    items.update(over)
    return {k: v for k, v in items.items() if v is not None}


@pytest.mark.parametrize("suffix", [".h5", ".npz"])
@pytest.mark.parametrize(
    "over, code, needle",
    [
        ({"csd": None, "group_csd": None, "group_xy": None, "group_count": None, "group_psd": None},
         "missing_key", "'xy' given without"),
        ({"xy": np.ones((2, 8), complex)}, "bad_shape", "'xy' must have shape (4, M)"),
        ({"group_psd": None}, "missing_key", "'group_psd'"),
        ({"group_xy": None}, "missing_key", "'group_xy'"),
        ({"xy": None}, "missing_key", "'group_xy' given without 'xy'"),
        ({"group_count": np.array([2.0, 0.0, 3.0])}, "bad_shape", "must be > 0"),
        ({"group_count": np.array([2.0, 1.0])}, "bad_shape", "'group_psd' must be"),
        ({"group_psd": np.ones((3, 4, 7))}, "bad_shape", "'group_psd' must be"),
        ({"group_csd": np.full((3, 2, 8), np.nan, complex)}, "nonfinite", "'group_csd'"),
        ({"group_psd": np.ones((3, 4, 8))}, "bad_shape", "'group_psd' does not average to 'psd'"),
        ({"group_count": np.array([1.0, 1.0, 1.0])}, "bad_shape", "does not average"),
    ],
)
def test_bad_spectral_matrix(tmp_path, suffix, over, code, needle):
    """The x-y cross-spectra and the groups: complete, of matching shapes, and averaging to the spectra."""
    path = tmp_path / f"bad{suffix}"
    _write_raw(path, **_matrix_items(**over))
    err = _expect(path, code, read_spectra)
    assert needle in str(err)


def test_spectra_without_cross_pair_spectra_read_as_none(tmp_path):
    path = write_spectra(tmp_path / "s.npz", _spectra_psd())
    got = read_spectra(path)
    assert got.psd is not None and got.xy is None and got.group_count is None and got.group_xy is None


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_spectra_bad_files(tmp_path, suffix):
    _expect(tmp_path / f"missing{suffix}", "unreadable", read_spectra)
    garbage = tmp_path / f"garbage{suffix}"
    garbage.write_bytes(b"\x89 not a file format")
    _expect(garbage, "unreadable", read_spectra)


def test_write_spectra_validates(tmp_path):
    path = tmp_path / "s.npz"
    with pytest.raises(TactileInputError) as info:
        write_spectra(path, SpectraData(omega=np.arange(4.0), depths=DEPTHS))
    assert info.value.code == "missing_key"
    assert not path.exists() and _leftovers(tmp_path) == []


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_recording_header_without_samples(tmp_path, suffix):
    path = write_recording(tmp_path / f"rec{suffix}", _recording((3, 4, 64), np.float64, velocity=(0.02, 0.0)))
    shape, dtype, meta = read_recording_header(path)
    full = read_recording(path)
    assert shape == full.signals.shape and dtype == full.signals.dtype
    assert meta["fs"] == full.fs and meta["depths"] == full.depths and meta["velocity"] == (0.02, 0.0)
    spec = write_spectra(tmp_path / f"spec{suffix}", SpectraData(omega=np.arange(3.0), ratio=np.ones((2, 3)),
                                                                 depths=DEPTHS))
    with pytest.raises(TactileInputError) as info:
        read_recording_header(spec)
    assert info.value.code == "missing_key" and "tactile-jax fit" in str(info.value)
