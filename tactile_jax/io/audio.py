"""Audio recordings: the probes are microphones, so a recording is a multichannel WAV or FLAC file.

WAV is read with ``scipy.io.wavfile``, FLAC with ``soundfile`` (the ``audio``
extra). Samples become float64: integer PCM scaled to [-1, 1) (signed n-byte
PCM divided by 2^(8n - 1), unsigned 8-bit PCM centred on 128 first), float
samples kept as they are. The sample rate comes from the file. An audio file
holds no sensor metadata: the channels are x1, x2, y1, y2 in that order and
the sensor is the paper's (``model.sensor.PAPER_SENSOR``: depths 0.265 and
0.925 mm, R = 30 mm), unless a sensor file (``io.sensor_file``) gives the
depths, the surface radius, the gains and the role of each channel. The
recording's ``sensor`` field says which: ``"paper (default)"`` or the sensor
file's path.

Every failure is a one-line :class:`~tactile_jax.errors.TactileInputError`
naming the audio file; a channel count that does not give the four probes has
code ``bad_shape``. A FLAC file without ``soundfile`` installed raises
:class:`~tactile_jax._optional.MissingExtra` naming the file and the extra.
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from .._optional import need
from ..errors import TactileInputError
from .atomic import atomic_write
from .recording import CHANNELS, SENSOR_DEFAULT, Recording, validate_recording
from .sensor_file import SensorSpec, as_sensor

__all__ = ["AUDIO_SUFFIXES", "is_audio_file", "read_audio", "read_audio_header", "write_wav"]

#: suffixes of audio recordings (case-insensitive)
AUDIO_SUFFIXES = (".wav", ".flac")

_KIND = {".wav": "wav", ".flac": "flac"}


def read_audio(path, sensor=None) -> Recording:
    """Read and validate a WAV or FLAC recording as a (4, N) float64 ``Recording``.

    sensor: None (the paper's sensor, channels x1, x2, y1, y2), a sensor file's path or a
    ``SensorSpec``: its depths, curvature radius, gain ratio and channel map. Raises
    ``TactileInputError`` (source = ``str(path)``) on any failure.
    """
    p, src, kind = _audio_path(path)
    spec = as_sensor(sensor)
    fs, data = _read_samples(p, src, kind, header_only=False)
    picks = _channel_picks(data.shape[1], spec, src)
    signals = _to_float(np.ascontiguousarray(data[:, list(picks)].T))
    rec = Recording(signals=signals, fs=float(fs), source=src, **_metadata(spec))
    return validate_recording(rec)


def read_audio_header(path, sensor=None) -> tuple[tuple[int, ...], np.dtype, dict[str, Any]]:
    """The shape (4, N) and dtype (float64) of an audio recording's signals, as read, and its metadata
    (``fs``, ``depths``, ``curvature_radius``, ``velocity``, ``gain_ratio``, ``sensor``), reading no samples
    where the format allows. ``sensor`` as in ``read_audio``; the channel count is checked here."""
    p, src, kind = _audio_path(path)
    spec = as_sensor(sensor)
    fs, shape = _read_samples(p, src, kind, header_only=True)
    _channel_picks(shape[1], spec, src)
    return (4, int(shape[0])), np.dtype(np.float64), {"fs": float(fs), **_metadata(spec)}


def write_wav(path, recording: Recording) -> Path:
    """Write a (4, N) recording as a float32 WAV file (channels x1, x2, y1, y2), atomically; return the path.

    A WAV file keeps the samples (rounded to float32) and the sample rate, which must be a whole
    number of hertz; depths and the other metadata are left out (a sensor file gives them on
    reading). Raises ``TactileInputError`` for an invalid recording, a suffix other than ``.wav``,
    several records or a fractional rate; ``OSError`` if the file cannot be written.
    """
    p, src = Path(os.fspath(path)), str(path)
    if p.suffix.lower() != ".wav":
        raise TactileInputError(f"write_wav writes .wav files, got '{p.suffix or 'no suffix'}'", source=src,
                                code="bad_setting")
    if not isinstance(recording, Recording):
        raise TypeError(f"write_wav expects a Recording, got {type(recording).__name__}")
    validate_recording(recording if recording.source else dataclasses.replace(recording, source=src))
    if recording.signals.ndim != 2:
        raise TactileInputError(f"a WAV file holds one record; this recording holds {recording.n_records}: "
                                "write each with recording.record(i)", source=src, code="bad_shape")
    fs = float(np.asarray(recording.fs).reshape(()))
    if fs != round(fs):
        raise TactileInputError(f"a WAV file needs a whole number of samples per second, got fs = {fs}",
                                source=src, code="bad_fs")
    data = np.ascontiguousarray(np.asarray(recording.signals, dtype=np.float32).T)
    if not np.all(np.isfinite(data)):
        raise TactileInputError("signals exceed the float32 range of a WAV file", source=src, code="nonfinite")
    from scipy.io import wavfile

    return atomic_write(p, lambda tmp: wavfile.write(tmp, int(round(fs)), data))


def is_audio_file(path) -> bool:
    """True if ``path`` has an audio suffix and starts as a WAV or FLAC file does; never raises."""
    try:
        p = Path(os.fspath(path))
        kind = _KIND.get(p.suffix.lower())
        if kind is None or not p.is_file():
            return False
        with p.open("rb") as fh:
            head = fh.read(12)
        if kind == "wav":
            return head[:4] in (b"RIFF", b"RIFX", b"RF64") and head[8:12] == b"WAVE"
        return head[:4] == b"fLaC" or head[:3] == b"ID3"
    except Exception:
        return False


# --------------------------------------------------------------------------- reading


def _audio_path(path) -> tuple[Path, str, str]:
    p, src = Path(os.fspath(path)), str(path)
    kind = _KIND.get(p.suffix.lower())
    if kind is None:
        raise TactileInputError(f"not an audio file suffix ('{p.suffix}'); audio files are "
                                f"{', '.join(AUDIO_SUFFIXES)}", source=src, code="unreadable")
    if not p.exists():
        raise TactileInputError("file not found", source=src, code="unreadable")
    if not p.is_file():
        raise TactileInputError("not a regular file", source=src, code="unreadable")
    return p, src, kind


def _read_samples(p: Path, src: str, kind: str, *, header_only: bool):
    """(fs, samples (N, C)), or with ``header_only`` (fs, (N, C)) reading as few samples as the format allows."""
    if kind == "flac":
        sf = need("soundfile", "audio", f"{src}: reading FLAC")
        try:
            if header_only:
                info = sf.info(str(p))
                return info.samplerate, (int(info.frames), int(info.channels))
            data, fs = sf.read(str(p), dtype="float64", always_2d=True)
        except Exception as exc:  # soundfile's LibsndfileError and the like
            raise TactileInputError(f"not a readable FLAC file ({_brief(exc)})", source=src,
                                    code="unreadable") from None
        return fs, data
    from scipy.io import wavfile

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", wavfile.WavFileWarning)   # chunks the reader skips (LIST, ...)
            try:
                fs, data = wavfile.read(str(p), mmap=header_only)
            except ValueError:
                if not header_only:
                    raise
                fs, data = wavfile.read(str(p))                   # 24-bit PCM cannot be memory-mapped
    except MemoryError:
        raise
    except Exception as exc:
        raise TactileInputError(f"not a readable WAV file ({_brief(exc)})", source=src, code="unreadable") from None
    shape = (data.shape[0], 1 if data.ndim == 1 else data.shape[1])
    if header_only:
        return fs, shape
    return fs, data.reshape(shape)


def _channel_picks(n: int, spec: SensorSpec | None, src: str) -> tuple[int, int, int, int]:
    """The file channels of x1, x2, y1, y2 for a file of ``n`` channels under the sensor's channel map."""
    need4 = f"a recording needs 4 ({', '.join(CHANNELS)})"
    if n < 4:
        raise TactileInputError(f"the audio file holds {n} channel{'s' if n != 1 else ''}; {need4}", source=src,
                                code="bad_shape")
    if spec is None:
        if n > 4:
            raise TactileInputError(f"the audio file holds {n} channels; {need4}: give a sensor file (--sensor) "
                                    "whose 'channels' names the role of each", source=src, code="bad_shape")
        return (0, 1, 2, 3)
    roles = spec.channels
    beyond = [f"{role} on channel {i}" for i, role in enumerate(roles) if role and i >= n]
    if beyond:
        raise TactileInputError(f"the sensor file {spec.label} puts {', '.join(beyond)} (counted from 0), but the "
                                f"audio file holds {n} channels", source=src, code="bad_shape")
    if len(roles) != n:
        raise TactileInputError(f"the audio file holds {n} channels, the sensor file {spec.label} maps "
                                f"{len(roles)}: its 'channels' must give each channel a role "
                                f"({', '.join(CHANNELS)} or \"unused\")", source=src, code="bad_shape")
    return spec.channel_indices


def _to_float(a: np.ndarray) -> np.ndarray:
    """float64 samples: signed integers over 2^(bits - 1), unsigned 8-bit centred on 128 first, floats kept."""
    if a.dtype.kind == "i":
        return a.astype(np.float64) / float(2 ** (8 * a.dtype.itemsize - 1))
    if a.dtype.kind == "u":
        half = float(2 ** (8 * a.dtype.itemsize - 1))
        return (a.astype(np.float64) - half) / half
    return a.astype(np.float64)


def _metadata(spec: SensorSpec | None) -> dict[str, Any]:
    """The Recording fields an audio file cannot hold: from the sensor file, else the paper's sensor."""
    if spec is not None:
        return {"depths": spec.depths, "curvature_radius": spec.curvature_radius, "velocity": None,
                "gain_ratio": spec.gain_ratio, "sensor": spec.label}
    from ..model.sensor import PAPER_SENSOR

    return {"depths": (PAPER_SENSOR.d1, PAPER_SENSOR.d2), "curvature_radius": PAPER_SENSOR.curvature_radius,
            "velocity": None, "gain_ratio": None, "sensor": SENSOR_DEFAULT}


def _brief(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    if len(text) > 200:
        text = text[:197] + "..."
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__
