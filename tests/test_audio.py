"""Audio recordings (WAV, FLAC) and sensor files: samples as read, channel maps, one-line errors, the
``sensor`` column, and the CLI on a short WAV file.

Reading is checked on the Recording read back; the default tier runs one short fit (``fit x.wav
--sensor s.toml``, the Gaussian window's program that the joint modules compile, on their worker);
the comparison of a WAV file's fit with its HDF5 file's is slow.
"""

from __future__ import annotations

import sys

import h5py
import numpy as np
import pytest
from click.testing import CliRunner
from scipy.io import wavfile

from tactile_jax._optional import MissingExtra
from tactile_jax.cli import main
from tactile_jax.errors import TactileInputError
from tactile_jax.inference.result import RESULT_FIELDS, FitResult
from tactile_jax.io.audio import AUDIO_SUFFIXES, read_audio_header, write_wav
from tactile_jax.io.files import (
    RECORDING_SUFFIXES,
    is_recording_file,
    read_recording,
    read_recording_header,
    read_spectra,
    write_recording,
)
from tactile_jax.io.recording import SENSOR_DEFAULT, SENSOR_FROM_FILE, Recording
from tactile_jax.io.results import read_results, write_results
from tactile_jax.io.sensor_file import SensorSpec, merge_metadata, read_sensor
from tactile_jax.model.sensor import PAPER_SENSOR

PAPER_DEPTHS = (PAPER_SENSOR.d1, PAPER_SENSOR.d2)
VX = 0.023


def _signals(n=256, channels=4, seed=0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-0.9, 0.9, (channels, n))


def _toml(path, text: str):
    path.write_text(text)
    return path


def _expect(func, *args, code: str, names, **kw) -> TactileInputError:
    """``func(*args)`` raises a one-line TactileInputError with ``code`` whose message names ``names``."""
    with pytest.raises(TactileInputError) as info:
        func(*args, **kw)
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.startswith(f"{names}: "), msg
    assert info.value.code == code, msg
    return info.value


# --------------------------------------------------------------------------- audio samples


@pytest.mark.parametrize("dtype, scale", [(np.int16, 2.0 ** 15), (np.int32, 2.0 ** 31), (np.uint8, None),
                                          (np.float32, None)])
def test_wav_samples_become_float64(tmp_path, dtype, scale):
    x = _signals()
    if dtype is np.float32:
        stored = x.astype(np.float32)
        expect = stored.astype(np.float64)
    elif dtype is np.uint8:
        stored = np.round(x * 127 + 128).astype(np.uint8)
        expect = (stored.astype(np.float64) - 128) / 128
    else:
        stored = np.round(x * (scale - 1)).astype(dtype)
        expect = stored / scale
    path = tmp_path / "rec.wav"
    wavfile.write(path, 2000, np.ascontiguousarray(stored.T))
    rec = read_recording(path)
    assert rec.signals.dtype == np.float64 and rec.signals.shape == (4, 256)
    np.testing.assert_array_equal(rec.signals, expect)
    assert np.all(rec.signals >= -1) and np.all(rec.signals < 1)
    assert rec.fs == 2000.0 and isinstance(rec.fs, float)
    assert rec.depths == PAPER_DEPTHS and rec.curvature_radius == PAPER_SENSOR.curvature_radius
    assert rec.sensor == SENSOR_DEFAULT and rec.source == str(path)
    assert rec.velocity is None and rec.gain_ratio is None and rec.truth == {}


def test_write_wav_round_trip(tmp_path):
    x = _signals() * 40.0                                   # a float WAV holds any amplitude
    path = write_wav(tmp_path / "rec.wav", Recording(x, 1000.0, (1e-3, 2e-3)))
    rate, raw = wavfile.read(path)
    assert rate == 1000 and raw.dtype == np.float32 and raw.shape == (256, 4)
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.signals, x.astype(np.float32).astype(np.float64))
    assert rec.depths == PAPER_DEPTHS                        # a WAV file holds no metadata
    assert is_recording_file(path)
    assert [p.name for p in tmp_path.iterdir()] == ["rec.wav"]


def test_write_wav_refuses(tmp_path):
    _expect(write_wav, tmp_path / "m.wav", Recording(np.zeros((2, 4, 8)), 1000.0, PAPER_DEPTHS), code="bad_shape",
            names=tmp_path / "m.wav")
    _expect(write_wav, tmp_path / "f.wav", Recording(np.zeros((4, 8)), 999.5, PAPER_DEPTHS), code="bad_fs",
            names=tmp_path / "f.wav")
    _expect(write_wav, tmp_path / "r.h5", Recording(np.zeros((4, 8)), 1000.0, PAPER_DEPTHS), code="bad_setting",
            names=tmp_path / "r.h5")
    err = _expect(write_recording, tmp_path / "r.wav", Recording(np.zeros((4, 8)), 1000.0, PAPER_DEPTHS),
                  code="unreadable", names=tmp_path / "r.wav")
    assert "write_wav" in str(err)
    assert list(tmp_path.iterdir()) == []


def test_flac_round_trip(tmp_path):
    sf = pytest.importorskip("soundfile")
    stored = np.round(_signals() * (2 ** 23 - 1)).astype(np.int32)
    path = tmp_path / "rec.flac"
    sf.write(path, (stored << 8).T, 4000, subtype="PCM_24")     # int32 samples are full-scale: 24 bits left-justified
    rec = read_recording(path)
    assert rec.fs == 4000.0 and rec.signals.dtype == np.float64
    np.testing.assert_array_equal(rec.signals, stored / 2.0 ** 23)
    assert rec.sensor == SENSOR_DEFAULT and is_recording_file(path)
    shape, dtype, meta = read_recording_header(path)
    assert shape == (4, 256) and dtype == np.float64 and meta["fs"] == 4000.0


def test_flac_without_soundfile_names_the_extra(tmp_path, monkeypatch):
    path = tmp_path / "rec.flac"
    path.write_bytes(b"fLaC" + bytes(60))
    monkeypatch.setitem(sys.modules, "soundfile", None)            # import soundfile raises ImportError
    with pytest.raises(MissingExtra) as info:
        read_recording(path)
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith(f"{path}: ") and 'pip install "tactile_jax[audio]"' in msg
    res = CliRunner().invoke(main, ["fit", str(path)])
    assert res.exit_code == 2
    assert res.output.strip() == f"error: {msg}"
    res = CliRunner().invoke(main, ["batch", str(tmp_path), "--out", str(tmp_path / "r.json")])
    assert res.exit_code == 2 and res.output.strip() == f"error: {msg}"       # before anything is fitted
    assert not (tmp_path / "r.json").exists()


def test_suffixes_and_header(tmp_path):
    assert set(AUDIO_SUFFIXES) <= set(RECORDING_SUFFIXES)
    path = write_wav(tmp_path / "rec.wav", Recording(_signals(n=100), 500.0, PAPER_DEPTHS))
    shape, dtype, meta = read_audio_header(path)
    assert (shape, dtype) == ((4, 100), np.float64)
    assert meta["fs"] == 500.0 and meta["depths"] == PAPER_DEPTHS and meta["sensor"] == SENSOR_DEFAULT
    (tmp_path / "junk.wav").write_bytes(b"RIFF\x00\x00\x00\x00WAVEjunk")
    (tmp_path / "text.wav").write_text("hello")
    assert not is_recording_file(tmp_path / "text.wav")
    _expect(read_recording, tmp_path / "junk.wav", code="unreadable", names=tmp_path / "junk.wav")
    _expect(read_recording, tmp_path / "gone.wav", code="unreadable", names=tmp_path / "gone.wav")
    err = _expect(read_spectra, path, code="unreadable", names=path)
    assert "read_recording" in str(err)


# --------------------------------------------------------------------------- channels and the sensor file


SENSOR_TOML = """
depths = [0.3e-3, 1.1e-3]
curvature_radius = 25e-3
channels = ["y2", "unused", "x1", "x2", "y1"]
gain_ratio = [1.05, 0.95]
"""


def test_channel_map_with_an_extra_channel(tmp_path):
    x = _signals(channels=5)
    path = tmp_path / "five.wav"
    wavfile.write(path, 1000, np.ascontiguousarray(x.T.astype(np.float32)))
    sensor = _toml(tmp_path / "sensor.toml", SENSOR_TOML)
    spec = read_sensor(sensor)
    assert spec == SensorSpec(depths=(0.3e-3, 1.1e-3), curvature_radius=25e-3, channels=("y2", "", "x1", "x2", "y1"),
                              gain_ratio=(1.05, 0.95), source=str(sensor))
    for given in (sensor, str(sensor), spec):
        rec = read_recording(path, sensor=given)
        np.testing.assert_array_equal(rec.signals, x[[2, 3, 4, 0]].astype(np.float32).astype(np.float64))
        assert rec.depths == (0.3e-3, 1.1e-3) and rec.curvature_radius == 25e-3
        assert rec.gain_ratio == (1.05, 0.95) and rec.sensor == str(sensor)
    shape, _, meta = read_recording_header(path, sensor=sensor)
    assert shape == (4, 256) and meta["sensor"] == str(sensor) and meta["gain_ratio"] == (1.05, 0.95)


@pytest.mark.parametrize("channels, n, words", [
    (None, 3, "holds 3 channels; a recording needs 4"),
    (None, 5, "holds 5 channels; a recording needs 4 (x1, x2, y1, y2): give a sensor file"),
    ('["x1", "x2", "y1", "y2"]', 6, "holds 6 channels, the sensor file"),
    ('["x1", "x2", "unused", "y1", "", "y2"]', 5, "puts y2 on channel 5 (counted from 0)"),
])
def test_wrong_channel_count(tmp_path, channels, n, words):
    path = tmp_path / "rec.wav"
    wavfile.write(path, 1000, np.zeros((64, n), np.int16))
    sensor = None
    if channels is not None:
        sensor = _toml(tmp_path / "s.toml", f"depths = [0.2e-3, 0.9e-3]\nchannels = {channels}\n")
    err = _expect(read_recording, path, sensor=sensor, code="bad_shape", names=path)
    assert words in str(err)
    _expect(read_recording_header, path, sensor=sensor, code="bad_shape", names=path)


@pytest.mark.parametrize("text, code, words", [
    ("depths = [0.3e-3, 1e-3\n", "unreadable", "not a valid TOML sensor file"),
    ("depths = [0.3e-3, 1e-3]\ndepth = 1\n", "bad_setting", "unknown key 'depth'"),
    ("curvature_radius = 0.03\n", "missing_key", "missing key 'depths'"),
    ("depths = [1e-3, 0.5e-3]\n", "bad_depths", "0 < d1 < d2, got [0.001, 0.0005]"),
    ("depths = [0.0, 1e-3]\n", "bad_depths", "0 < d1 < d2"),
    ("depths = [1e-3]\n", "bad_depths", "[d1, d2] in metres"),
    ("depths = ['a', 'b']\n", "bad_depths", "[d1, d2] in metres"),
    ("depths = [1e-3, 2e-3]\ncurvature_radius = -1\n", "bad_setting", "'curvature_radius' must be"),
    ("depths = [1e-3, 2e-3]\ngain_ratio = [1, 2, 3]\n", "bad_setting", "'gain_ratio' must be"),
    ("depths = [1e-3, 2e-3]\nchannels = ['x1', 'x1', 'y1', 'y2']\n", "bad_setting",
     "exactly once; it names x1 2 times, x2 0 times"),
    ("depths = [1e-3, 2e-3]\nchannels = ['x1', 'x2', 'y1', 'z']\n", "bad_setting", "names 'z'"),
    ("depths = [1e-3, 2e-3]\nchannels = 'x1 x2 y1 y2'\n", "bad_setting", "must list the role of each channel"),
])
def test_bad_sensor_files(tmp_path, text, code, words):
    sensor = _toml(tmp_path / "s.toml", text)
    err = _expect(read_sensor, sensor, code=code, names=sensor)
    assert words in str(err)
    wav = write_wav(tmp_path / "rec.wav", Recording(_signals(), 1000.0, PAPER_DEPTHS))
    _expect(read_recording, wav, sensor=sensor, code=code, names=sensor)      # the sensor file's error


def test_missing_sensor_file(tmp_path):
    _expect(read_sensor, tmp_path / "none.toml", code="unreadable", names=tmp_path / "none.toml")
    res = CliRunner().invoke(main, ["fit", str(tmp_path / "x.wav"), "--sensor", str(tmp_path / "none.toml")])
    assert res.exit_code == 2
    assert res.output.strip() == f"error: {tmp_path / 'none.toml'}: sensor file not found"


# --------------------------------------------------------------------------- HDF5/NPZ with a sensor file


def test_hdf5_and_a_disagreeing_sensor_file(tmp_path):
    path = write_recording(tmp_path / "rec.h5", Recording(_signals(), 1000.0, PAPER_DEPTHS, curvature_radius=0.03))
    assert read_recording(path).sensor == SENSOR_FROM_FILE
    sensor = _toml(tmp_path / "s.toml", SENSOR_TOML)
    err = _expect(read_recording, path, sensor=sensor, code="bad_setting", names=path)
    assert str(err) == (f"{path}: the sensor file {sensor} disagrees with the file's metadata: depths [0.000265, "
                        "0.000925] in the file, [0.0003, 0.0011] in the sensor file; curvature_radius 0.03 in the "
                        "file, 0.025 in the sensor file")
    _expect(read_recording_header, path, sensor=sensor, code="bad_setting", names=path)


def test_hdf5_metadata_filled_from_the_sensor_file(tmp_path):
    path = tmp_path / "rec.npz"
    np.savez(path, signals=_signals(), fs=1000.0)                        # no depths, no radius
    sensor = _toml(tmp_path / "s.toml", "depths = [0.265e-3, 0.925e-3]\ncurvature_radius = 0.03\n"
                                         "channels = ['x1', 'unused', 'x2', 'y1', 'y2']\ngain_ratio = 1.1\n")
    rec = read_recording(path, sensor=sensor)
    assert rec.depths == PAPER_DEPTHS and rec.curvature_radius == 0.03 and rec.gain_ratio == 1.1
    assert rec.sensor == str(sensor)
    np.testing.assert_array_equal(rec.signals, _signals())                # HDF5/NPZ: x1, x2, y1, y2 as stored
    _expect(read_recording, path, code="missing_key", names=path)        # without it the depths are missing
    with h5py.File(tmp_path / "g.h5", "w") as f:
        f.create_dataset("signals", data=_signals())
        f.attrs.update(fs=1000.0, depths=np.array(PAPER_DEPTHS), gain_ratio=np.array([1.1, 1.1]))
    assert read_recording(tmp_path / "g.h5", sensor=sensor).gain_ratio == (1.1, 1.1)   # g against (g, g): agree


def test_merge_metadata_names_every_difference():
    spec = SensorSpec(depths=PAPER_DEPTHS, gain_ratio=(1.0, 1.2), source="s.toml")
    meta = {"depths": PAPER_DEPTHS, "curvature_radius": 0.03, "gain_ratio": 1.0}
    with pytest.raises(TactileInputError, match=r"^r\.h5: .*gain_ratio 1 in the file, \[1, 1.2\] in the sensor file$"):
        merge_metadata(meta, spec, "r.h5")
    same = merge_metadata({**meta, "gain_ratio": None}, spec, "r.h5")
    assert same == {"depths": PAPER_DEPTHS, "curvature_radius": 0.03, "gain_ratio": (1.0, 1.2)}


# --------------------------------------------------------------------------- rows and batch


def test_sensor_column_in_result_rows(tmp_path):
    row = FitResult(sensor=SENSOR_DEFAULT, file="x.wav").to_record()
    assert row["sensor"] == SENSOR_DEFAULT
    error_row = {**dict.fromkeys(RESULT_FIELDS), "file": "y.wav", "status": "bad_shape"}
    for suffix in (".json", ".csv"):
        back = read_results(write_results(tmp_path / f"r{suffix}", [error_row, row]))
        assert list(back[0])[:len(RESULT_FIELDS) + 1] == [*RESULT_FIELDS, "sensor"]
        assert back[0]["sensor"] is None and back[1]["sensor"] == SENSOR_DEFAULT


def test_batch_finds_audio_files_and_keeps_their_errors_as_rows(tmp_path):
    from tactile_jax.batch.run import run_batch, scan_inputs

    data = tmp_path / "data"
    data.mkdir()
    write_wav(data / "a.wav", Recording(_signals(n=2048), 1000.0, PAPER_DEPTHS))
    wavfile.write(data / "three.wav", 1000, np.zeros((64, 3), np.int16))
    write_recording(data / "b.h5", Recording(_signals(), 1000.0, PAPER_DEPTHS, curvature_radius=0.03))
    sensor = _toml(tmp_path / "s.toml", "depths = [0.265e-3, 0.925e-3]\ncurvature_radius = 0.02\n")
    infos = {i.path.rsplit("/", 1)[-1]: i for i in scan_inputs([data])}
    assert infos["a.wav"].error is None and infos["a.wav"].sensor == SENSOR_DEFAULT
    assert infos["a.wav"].n_samples == 2048 and infos["b.h5"].sensor == SENSOR_FROM_FILE
    assert infos["three.wav"].error.code == "bad_shape"
    infos = {i.path.rsplit("/", 1)[-1]: i for i in scan_inputs([data], sensor=sensor)}
    assert infos["a.wav"].sensor == str(sensor) and infos["a.wav"].curvature_radius == 0.02
    assert infos["b.h5"].error.code == "bad_setting" and "curvature_radius 0.03" in str(infos["b.h5"].error)

    # a row fitted under another sensor is not resumed (no fit runs: the refusal comes first)
    out = tmp_path / "r.json"
    write_results(out, [{**dict.fromkeys(RESULT_FIELDS), "file": str(data / "a.wav"), "index": 0, "status": "ok",
                         "sensor": SENSOR_DEFAULT, "options": "defaults"}])
    with pytest.raises(TactileInputError, match="fitted with sensor 'paper \\(default\\)', this run has sensor"):
        run_batch([data / "a.wav"], out, sensor=sensor, progress=False)


def test_batch_row_of_an_audio_file_with_nan_samples(tmp_path):
    from tactile_jax.batch.run import run_batch

    x = _signals(n=512).astype(np.float32)
    x[2, 10] = np.nan
    path = tmp_path / "nan.wav"
    wavfile.write(path, 1000, np.ascontiguousarray(x.T))
    out = tmp_path / "r.json"
    summary = run_batch([path], out, progress=False)                     # nothing to fit: no program runs
    assert summary.n_failed == 1
    (row,) = read_results(out)
    assert row["status"] == "nonfinite" and row["message"].startswith(f"{path}: signals contain 1 NaN")


# --------------------------------------------------------------------------- fits


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    from tactile_jax.simulation.scene import Scene, simulate

    folder = tmp_path_factory.mktemp("audio")
    rec = simulate(Scene(velocity=(VX, 0.0), duration=4.0, seed=0))
    return folder, rec, write_recording(folder / "scene.h5", rec), write_wav(folder / "scene.wav", rec)


def test_wav_and_hdf5_hold_the_same_signals(scene):
    _, rec, h5, wav = scene
    a, b = read_recording(h5), read_recording(wav)
    np.testing.assert_allclose(b.signals, a.signals, rtol=0, atol=6e-8 * np.abs(a.signals).max())
    np.testing.assert_array_equal(b.signals, a.signals.astype(np.float32))
    assert (b.fs, b.depths, b.curvature_radius) == (a.fs, a.depths, a.curvature_radius)


@pytest.mark.xdist_group("joint")        # the Gaussian program of the joint modules' worker: no compile of its own
def test_fit_cli_on_a_wav_file_with_a_sensor_file(scene, tmp_path):
    folder, rec, _, _ = scene
    # five channels in another order, one without a probe
    order = [3, 0, 2, 1]                                   # file channels 0..3 carry y2, x1, y1, x2; 4 is unused
    data = np.zeros((5, rec.n_samples), np.float32)
    data[:4] = rec.signals[order]
    wav = tmp_path / "five.wav"
    wavfile.write(wav, int(rec.fs), np.ascontiguousarray(data.T))
    sensor = _toml(tmp_path / "sensor.toml", f"depths = [{rec.depths[0]!r}, {rec.depths[1]!r}]\n"
                                             f"curvature_radius = {rec.curvature_radius!r}\n"
                                             'channels = ["y2", "x1", "y1", "x2", "unused"]\n')
    out = tmp_path / "r.csv"
    res = CliRunner().invoke(main, ["fit", str(wav), "--sensor", str(sensor), "--window", "gaussian",
                                    "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "sensor assumed" not in res.output
    (row,) = read_results(out)
    assert row["file"] == str(wav) and row["sensor"] == str(sensor) and row["status"] == "ok"
    assert row["vx"] == pytest.approx(VX, rel=0.05)


@pytest.mark.slow
def test_wav_fits_as_its_hdf5_file(scene):
    """The same signals as float32 WAV (paper's sensor by default) and as HDF5: the same estimates."""
    import jax

    from tactile_jax.inference.fit import fit_recording
    from tactile_jax.inference.options import FitOptions

    folder, _, h5, wav = scene
    assert jax.config.jax_enable_x64
    out = folder / "wav.json"
    res = CliRunner().invoke(main, ["fit", str(wav), "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "sensor assumed: the paper's (probe depths 0.265 and 0.925 mm, R = 30 mm)" in res.output
    (row,) = read_results(out)
    assert row["sensor"] == SENSOR_DEFAULT
    ref = fit_recording(read_recording(h5), FitOptions())
    assert ref.sensor == SENSOR_FROM_FILE and ref.status == row["status"] == "ok"
    assert (ref.window, ref.texture, ref.direction) == (row["window"], row["texture"], row["direction"])
    for key in ("vx", "vx_err", "a", "a_err", "vy_upper", "redchi"):
        want = ref.to_record()[key]
        assert row[key] == pytest.approx(want, rel=1e-4), key
