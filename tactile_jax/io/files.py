"""Recording and spectra files of the data contract: HDF5 (``.h5``, ``.hdf5``) and NumPy (``.npz``),
and audio recordings (``.wav``, ``.flac``: ``io.audio``).

The format is chosen by suffix. ``read_recording(path, sensor=None)`` reads any recording,
with an optional sensor file (``io.sensor_file``): the depths, surface radius, gains and
channel map of an audio file, checked against an HDF5/NPZ file's metadata and filling
what it leaves out. Readers validate what they read and turn every
failure (missing file, not HDF5/NPZ, missing key, wrong shape, NaN, ...) into a
one-line :class:`~tactile_jax.errors.TactileInputError` that names the file and
carries a ``code``. Writers are atomic: they write a temporary file in the
target's directory and ``os.replace`` it over the target, so a failed write
leaves any existing file untouched.

Layout written (readers also accept scalars and small arrays stored as HDF5
datasets instead of root attributes):

- recording: ``signals`` dataset; ``fs``, ``depths`` and the optional
  ``curvature_radius``, ``velocity``, ``gain_ratio`` as root attributes;
  ``truth`` as a JSON string root attribute (a string dataset when larger
  than an HDF5 attribute comfortably holds).
- spectra: ``omega``, ``psd``, ``csd``, ``xy``, ``group_count``, ``group_psd``, ``group_csd``,
  ``group_xy``, ``ratio``, ``ratio_err``, ``kernel``, ``whitening`` datasets; ``n_segments``,
  ``bin_factor``, ``fs``, ``depths`` and the optional keys as root attributes (docs/data-format.md).

In ``.npz`` every key is an array member; ``truth`` is a 0-d unicode array.
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, NamedTuple

import h5py
import numpy as np

from .atomic import atomic_write
from ..errors import TactileInputError
from .audio import AUDIO_SUFFIXES, is_audio_file, read_audio, read_audio_header
from .recording import SENSOR_FROM_FILE, Recording, validate_recording
from .sensor_file import SensorSpec, as_sensor, merge_metadata

__all__ = [
    "RECORDING_SUFFIXES",
    "STORE_SUFFIXES",
    "AUDIO_SUFFIXES",
    "SpectraData",
    "read_recording_header",
    "is_recording_file",
    "read_recording",
    "read_spectra",
    "write_recording",
    "write_spectra",
]

#: Suffixes of HDF5 and NPZ files: recordings with 'signals' and spectra files (case-insensitive).
STORE_SUFFIXES = (".h5", ".hdf5", ".npz")
#: File suffixes accepted for recordings (case-insensitive).
RECORDING_SUFFIXES = STORE_SUFFIXES + AUDIO_SUFFIXES

_KIND = {".h5": "hdf5", ".hdf5": "hdf5", ".npz": "npz", ".wav": "wav", ".flac": "flac"}
_AUDIO_KINDS = ("wav", "flac")
_RECORDING_KEYS = ("signals", "fs", "depths")
# HDF5 attributes live in the object header (64 KiB in all); larger strings go to a dataset.
_MAX_ATTR_BYTES = 32 * 1024


class SpectraData(NamedTuple):
    """Spectra of the four channels, for users who have spectra rather than signals (SI units).

    omega: (M,) temporal angular frequencies, rad/s, >= 0.
    psd: (4, M) power spectral densities of channels x1, x2, y1, y2 (units^2/Hz, one-sided), or None.
    csd: complex (2, M) cross-spectra S12 = E[conj(X1) X2] of the x pair and of the y pair, or None
        (needs ``psd``).
    xy: complex (4, M) cross-spectra E[conj(X_i) Y_j] between the pairs in the order (x1 y1, x1 y2,
        x2 y1, x2 y2), or None (needs ``csd``); with ``psd`` and ``csd`` the whole 4 x 4 spectral matrix.
    n_segments: effective number of independent segments averaged into ``psd``/``csd``/``xy`` (K_eff:
        the estimates' degrees of freedom are 2 K_eff), or None.
    group_count: (G,) segments in each group of consecutive segments, > 0, or None; with it
        group_psd (G, 4, M), group_csd (G, 2, M) and group_xy (G, 4, M, when ``xy`` is given):
        each group's mean spectra, whose count-weighted mean is ``psd``/``csd``/``xy`` (the fit's
        delete-one-group jackknife).
    ratio: (2, M) AMPLITUDE ratios |P2/P1| of the x and y pairs, or None.
    ratio_err: (2, M) standard errors of log|P2/P1| (natural log), or None (needs ``ratio``).
    depths: (d1, d2) probe depths in metres, 0 < d1 < d2.
    curvature_radius: sensor surface radius, m, or None.
    velocity: (vx, vy) in m/s when known, or None.
    gain_ratio: calibrated deep/shallow gain ratio g (float or per-pair (gx, gy)), or None.
    source: where the spectra came from (a path), for messages.
    The estimator that made ``psd``/``csd`` (optional; written by ``tactile-jax spectra``, so
    that a fit of the file models the spectra exactly as a fit of the recording does):
    kernel: (2, J) offsets (bins) and weights of one bin's spectral window, or None.
    bin_factor: variance inflation of a sum over adjacent bins (correlated bins), or None.
    whitening: (2, p + 1) AR prewhitening error filters of the x and y pairs, or None.
    fs: the recording's sample rate, Hz (needed with ``whitening``), or None.

    Either ``psd`` or ``ratio`` is required; both may be given.
    """

    omega: np.ndarray
    psd: np.ndarray | None = None
    csd: np.ndarray | None = None
    n_segments: float | None = None
    ratio: np.ndarray | None = None
    ratio_err: np.ndarray | None = None
    depths: tuple[float, float] = None  # type: ignore[assignment]  # required; checked on read/write
    curvature_radius: float | None = None
    velocity: tuple[float, float] | None = None
    gain_ratio: Any = None
    source: str | None = None
    kernel: np.ndarray | None = None
    bin_factor: float | None = None
    whitening: np.ndarray | None = None
    fs: float | None = None
    xy: np.ndarray | None = None
    group_count: np.ndarray | None = None
    group_psd: np.ndarray | None = None
    group_csd: np.ndarray | None = None
    group_xy: np.ndarray | None = None


# --------------------------------------------------------------------------- public API


def read_recording(path, sensor=None) -> Recording:
    """Read and validate a recording file (``.h5``, ``.hdf5``, ``.npz``, ``.wav`` or ``.flac``).

    HDF5/NPZ keys: ``signals`` (4, N) or (n, 4, N), float32/float64 kept as stored; ``fs`` (Hz);
    ``depths`` [d1, d2] (m); optional ``curvature_radius`` (m), ``velocity`` [vx, vy] (m/s),
    ``gain_ratio`` (scalar or per pair), ``truth`` (JSON string, decoded to a dict).
    WAV/FLAC: one (4, N) float64 record (``io.audio.read_audio``).
    sensor: None, a sensor file's path or a ``SensorSpec``. An audio file takes its depths, radius,
    gains and channel map from it (without one: the paper's sensor, channels x1, x2, y1, y2); an
    HDF5/NPZ file's metadata must agree with it (code ``bad_setting`` naming what differs), and
    what the file leaves out (``depths`` too) is taken from it. ``Recording.sensor`` says where the
    sensor came from. Raises ``TactileInputError`` (source = ``str(path)``, or the sensor file's
    path for a bad sensor file) on any failure.
    """
    path, src = _as_path(path)
    spec = as_sensor(sensor)
    if file_kind(path, src) in _AUDIO_KINDS:
        return read_audio(path, spec)
    rec = _read(path, src, lambda store, s: _recording_from_store(store, s, spec))
    return validate_recording(rec)


def write_recording(path, rec: Recording) -> Path:
    """Validate ``rec`` and write it atomically to ``path`` (format from the suffix); return the path.

    Optional fields are written only when not None (``truth`` only when non-empty).
    Raises ``TactileInputError`` for an invalid recording or suffix, ``OSError`` if the
    file cannot be written; an existing file at ``path`` is left untouched on failure.
    """
    path, src = _as_path(path)
    kind = _store_kind(path, src, "write_recording writes HDF5 or NPZ; a WAV file holds no metadata: "
                                  "write it with io.audio.write_wav")
    if not isinstance(rec, Recording):
        raise TypeError(f"write_recording expects a Recording, got {type(rec).__name__}")
    vsrc = rec.source or src
    validate_recording(rec if rec.source else dataclasses.replace(rec, source=src))
    fs = float(np.asarray(rec.fs).reshape(()))
    depths = _depth_pair(rec.depths, vsrc)
    attrs: dict[str, Any] = {"fs": np.float64(fs), "depths": np.asarray(depths, dtype=np.float64)}
    attrs.update(_optional_attrs(lambda k: getattr(rec, k), vsrc))
    truth = _encode_truth(rec.truth, vsrc)
    if truth is not None:
        attrs["truth"] = truth
    arrays = {"signals": np.asarray(rec.signals)}
    return _atomic_write(path, kind, arrays, attrs)


def read_spectra(path, sensor=None) -> SpectraData:
    """Read and validate a spectra file (``.h5``, ``.hdf5`` or ``.npz``).

    Keys: ``omega`` (M,) rad/s; ``psd`` (4, M) with optional complex ``csd`` (2, M), ``xy`` (4, M),
    ``n_segments`` and the groups ``group_count`` (G,), ``group_psd`` (G, 4, M), ``group_csd``
    (G, 2, M), ``group_xy`` (G, 4, M); and/or ``ratio`` (2, M) amplitude ratios with optional
    ``ratio_err`` (2, M, standard error of log ratio); ``depths`` [d1, d2] (m); optional
    ``curvature_radius`` (m), ``velocity`` (m/s), ``gain_ratio``; optional estimator
    description ``kernel`` (2, J), ``bin_factor``, ``whitening`` (2, p + 1), ``fs`` (Hz).
    sensor: None, a sensor file's path or a ``SensorSpec``, whose depths, curvature radius and gain
    ratio must agree with the file's (code ``bad_setting``) and fill the optional ones it leaves out.
    Raises ``TactileInputError`` (source = ``str(path)``) on any failure.
    """
    path, src = _as_path(path)
    spec = as_sensor(sensor)
    data = _read(path, src, lambda store, s: _spectra_checked(store.get, s))
    if spec is None:
        return data
    keys = ("depths", "curvature_radius", "gain_ratio")
    return data._replace(**merge_metadata({k: getattr(data, k) for k in keys}, spec, src))


def write_spectra(path, data: SpectraData) -> Path:
    """Validate ``data`` and write it atomically to ``path`` (format from the suffix); return the path.

    None fields are not written; ``source`` is not stored. Raises ``TactileInputError`` for
    invalid spectra or suffix, ``OSError`` if the file cannot be written.
    """
    path, src = _as_path(path)
    kind = _store_kind(path, src, "spectra files are HDF5 or NPZ")
    vsrc = getattr(data, "source", None) or src
    checked = _spectra_checked(lambda k: getattr(data, k, None), vsrc)
    arrays = {k: getattr(checked, k) for k in ("omega", "psd", "csd", "xy", "group_count", "group_psd", "group_csd",
                                               "group_xy", "ratio", "ratio_err", "kernel", "whitening")}
    arrays = {k: v for k, v in arrays.items() if v is not None}
    attrs: dict[str, Any] = {"depths": np.asarray(checked.depths, dtype=np.float64)}
    for key in ("n_segments", "bin_factor", "fs"):
        if getattr(checked, key) is not None:
            attrs[key] = np.float64(getattr(checked, key))
    attrs.update(_optional_attrs(lambda k: getattr(checked, k), vsrc))
    return _atomic_write(path, kind, arrays, attrs)


def is_recording_file(path) -> bool:
    """True if ``path`` has a recording suffix and holds a ``signals`` key (an audio file: starts as a WAV or
    FLAC file does); never raises.

    Cheap: opens the file but reads no data. Meant for scanning folders.
    """
    try:
        p = Path(os.fspath(path))
        kind = _KIND.get(p.suffix.lower())
        if kind is None or not p.is_file():
            return False
        if kind in _AUDIO_KINDS:
            return is_audio_file(p)
        if kind == "hdf5":
            if not h5py.is_hdf5(p):
                return False
            with h5py.File(p, "r") as f:
                return "signals" in f or "signals" in f.attrs
        with p.open("rb") as fh:
            if fh.read(2) != b"PK":
                return False
        z = np.load(p, allow_pickle=False)
        if not isinstance(z, np.lib.npyio.NpzFile):
            return False
        with z:
            return "signals" in z.files
    except Exception:
        return False


# --------------------------------------------------------------------------- reading


class _H5Store:
    """Keys of an open HDF5 file: a root dataset, else a root attribute."""

    def __init__(self, f: h5py.File, src: str):
        self._f, self._src = f, src

    def keys(self) -> set[str]:
        return set(self._f.keys()) | set(self._f.attrs.keys())

    def get(self, key: str):
        if key in self._f:
            obj = self._f[key]
            if not isinstance(obj, h5py.Dataset):
                raise TactileInputError(f"'{key}' is an HDF5 group, not an array", source=self._src, code="bad_shape")
            try:
                value = obj[()]
            except Exception as exc:
                raise TactileInputError(f"cannot read '{key}': {_brief(exc)}", source=self._src,
                                        code="unreadable") from None
        elif key in self._f.attrs:
            value = self._f.attrs[key]
        else:
            return None
        if isinstance(value, h5py.Empty):
            raise TactileInputError(f"'{key}' is empty", source=self._src, code="bad_shape")
        return value

    def shape_of(self, key: str):
        """(shape, dtype) of a stored array without reading a dataset's data; None when absent."""
        obj = self._f.get(key)
        if isinstance(obj, h5py.Dataset):
            return obj.shape, obj.dtype
        value = self.get(key)
        return None if value is None else (np.shape(value), np.asarray(value).dtype)


class _NpzStore:
    """Members of an open ``.npz`` archive (no pickles)."""

    def __init__(self, z, src: str):
        self._z, self._src = z, src

    def keys(self) -> set[str]:
        return set(self._z.files)

    def get(self, key: str):
        if key not in self._z.files:
            return None
        try:
            return self._z[key]
        except Exception as exc:
            raise TactileInputError(f"cannot read '{key}': {_brief(exc)}", source=self._src,
                                    code="unreadable") from None

    def shape_of(self, key: str):
        """(shape, dtype) of a member from its .npy header, without reading the data; None when absent."""
        if key not in self._z.files:
            return None
        with self._z.zip.open(f"{key}.npy") as fh:
            version = np.lib.format.read_magic(fh)
            read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                           else np.lib.format.read_array_header_2_0)
            shape, _, dtype = read_header(fh)
        return shape, dtype


def _read(path: Path, src: str, parse: Callable):
    """Open ``path`` as a store and ``parse(store, src)``; any failure becomes a TactileInputError."""
    kind = _store_kind(path, src, "an audio file holds a recording, not spectra: read it with read_recording")
    if not path.exists():
        raise TactileInputError("file not found", source=src, code="unreadable")
    if not path.is_file():
        raise TactileInputError("not a regular file", source=src, code="unreadable")
    try:
        if kind == "hdf5":
            try:
                f = h5py.File(path, "r")
            except Exception as exc:
                raise TactileInputError(f"not a readable HDF5 file ({_brief(exc)})", source=src,
                                        code="unreadable") from None
            with f:
                return parse(_H5Store(f, src), src)
        with path.open("rb") as fh:
            if fh.read(2) != b"PK":
                raise TactileInputError("not a valid NPZ archive (no zip signature)", source=src, code="unreadable")
        try:
            z = np.load(path, allow_pickle=False)
        except Exception as exc:
            raise TactileInputError(f"not a valid NPZ archive ({_brief(exc)})", source=src,
                                    code="unreadable") from None
        if not isinstance(z, np.lib.npyio.NpzFile):  # pragma: no cover - guarded by the zip signature
            raise TactileInputError("not a valid NPZ archive", source=src, code="unreadable")
        with z:
            return parse(_NpzStore(z, src), src)
    except TactileInputError:
        raise
    except MemoryError:
        raise
    except Exception as exc:
        raise TactileInputError(f"cannot read file: {_brief(exc)}", source=src, code="unreadable") from None


def _recording_from_store(store, src: str, spec: SensorSpec | None = None) -> Recording:
    meta = _recording_meta(store, src, "use read_spectra", spec)
    signals = _native(np.asarray(store.get("signals")))
    return Recording(signals=signals, truth=_decode_truth(store.get("truth"), src), source=src, **meta)


def _recording_meta(store, src: str, spectra_hint: str, spec: SensorSpec | None = None) -> dict[str, Any]:
    """Check the recording keys; return fs, depths, the optional fields and ``sensor`` (the samples are not
    read). With a sensor file the depths may be absent: ``merge_metadata`` checks and fills them."""
    keys = store.keys()
    for key in _RECORDING_KEYS:
        if key not in keys and not (key == "depths" and spec is not None):
            hint = f" (this looks like a spectra file: {spectra_hint})" if "omega" in keys else ""
            raise TactileInputError(
                f"missing key '{key}'; a recording needs 'signals', 'fs' and 'depths'{hint}",
                source=src, code="missing_key")
    depths = store.get("depths")
    meta = {"fs": _real_scalar(store.get("fs"), "fs", src, "bad_fs"),
            "depths": None if depths is None else _depth_pair(depths, src)}
    meta.update(_optional_values(store.get, src))
    if spec is not None:
        meta = merge_metadata(meta, spec, src)
    meta["sensor"] = SENSOR_FROM_FILE if spec is None else spec.label
    return meta


def read_recording_header(path, sensor=None) -> tuple[tuple[int, ...], np.dtype, dict[str, Any]]:
    """The shape and dtype of a recording's ``signals`` and its metadata, without reading the samples.

    Returns ``(shape, dtype, meta)`` with ``meta`` holding ``fs`` (Hz), ``depths`` (m), the
    optional ``curvature_radius``, ``velocity``, ``gain_ratio`` (None when absent) and ``sensor``
    (``Recording.sensor``). ``sensor`` as in ``read_recording``; an audio file's shape is that of
    its signals as read, (4, N) float64. Raises ``TactileInputError`` as ``read_recording`` does
    for unreadable files and missing keys; the shape and values are not validated here (see
    ``recording.validate_recording``).
    """
    path, src = _as_path(path)
    spec = as_sensor(sensor)
    if file_kind(path, src) in _AUDIO_KINDS:
        return read_audio_header(path, spec)

    def parse(store, s):
        meta = _recording_meta(store, s, "fit it with 'tactile-jax fit'", spec)
        shape, dtype = store.shape_of("signals")
        return tuple(shape), np.dtype(dtype), meta

    return _read(path, src, parse)


# --------------------------------------------------------------------------- validation helpers


def _spectra_checked(get: Callable[[str], Any], src: str) -> SpectraData:
    """Validate the spectra keys given by ``get(key)`` (None when absent) into a SpectraData."""
    raw_omega = get("omega")
    if raw_omega is None:
        if all(get(k) is None for k in ("signals", "psd", "ratio")):
            raise TactileInputError("the file holds neither a recording ('signals') nor spectra ('omega', 'psd')",
                                    source=src, code="missing_key")
        raise TactileInputError("missing key 'omega' (rad/s)", source=src, code="missing_key")
    omega = np.asarray(raw_omega)
    if omega.dtype.kind not in "fiu" or omega.ndim != 1:
        raise TactileInputError(f"'omega' must be a real (M,) array in rad/s, got {_describe(omega)}",
                                source=src, code="bad_shape")
    if omega.size == 0:
        raise TactileInputError("'omega' is empty", source=src, code="too_short")
    omega = _finite(_as_float(omega), "omega", src)
    if np.any(omega < 0):
        raise TactileInputError(f"'omega' must be >= 0 rad/s, got minimum {float(omega.min())}",
                                source=src, code="bad_shape")
    m = omega.size

    raw = {k: get(k) for k in ("psd", "csd", "xy", "ratio", "ratio_err")}
    if raw["psd"] is None and raw["ratio"] is None:
        raise TactileInputError("missing key: spectra need either 'psd' (4, M) or 'ratio' (2, M)",
                                source=src, code="missing_key")
    if raw["csd"] is not None and raw["psd"] is None:
        raise TactileInputError("'csd' given without 'psd'", source=src, code="missing_key")
    if raw["xy"] is not None and raw["csd"] is None:
        raise TactileInputError("'xy' given without 'psd' and 'csd'", source=src, code="missing_key")
    if raw["ratio_err"] is not None and raw["ratio"] is None:
        raise TactileInputError("'ratio_err' given without 'ratio'", source=src, code="missing_key")

    psd = csd = xy = ratio = ratio_err = None
    if raw["psd"] is not None:
        psd = _matrix(raw["psd"], "psd", 4, m, src)
        if np.any(psd < 0):
            raise TactileInputError("'psd' must be >= 0", source=src, code="bad_shape")
    if raw["csd"] is not None:
        csd = _matrix(raw["csd"], "csd", 2, m, src, complex_ok=True)
    if raw["xy"] is not None:
        xy = _matrix(raw["xy"], "xy", 4, m, src, complex_ok=True)
    if raw["ratio"] is not None:
        ratio = _matrix(raw["ratio"], "ratio", 2, m, src)
        if np.any(ratio <= 0):
            raise TactileInputError("'ratio' (amplitude ratio |P2/P1|) must be > 0", source=src, code="bad_shape")
    if raw["ratio_err"] is not None:
        ratio_err = _matrix(raw["ratio_err"], "ratio_err", 2, m, src)
        if np.any(ratio_err <= 0):
            raise TactileInputError("'ratio_err' (standard error of log ratio) must be > 0",
                                    source=src, code="bad_shape")

    n_segments = get("n_segments")
    if n_segments is not None:
        n_segments = _real_scalar(n_segments, "n_segments", src, "bad_setting")
        if not (np.isfinite(n_segments) and n_segments > 0):
            raise TactileInputError(f"'n_segments' must be positive, got {n_segments}", source=src,
                                    code="bad_setting")

    raw_depths = get("depths")
    if raw_depths is None:
        raise TactileInputError("missing key 'depths' ([d1, d2] in metres)", source=src, code="missing_key")
    depths = _depth_pair(raw_depths, src)
    if not (np.all(np.isfinite(depths)) and 0 < depths[0] < depths[1]):
        raise TactileInputError(f"'depths' must be [d1, d2] in metres with 0 < d1 < d2, got {list(depths)}",
                                source=src, code="bad_depths")
    return SpectraData(omega=omega, psd=psd, csd=csd, xy=xy, n_segments=n_segments, ratio=ratio,
                       ratio_err=ratio_err, depths=depths, source=src, **_optional_values(get, src),
                       **_estimator_values(get, src), **_groups(get, psd, csd, xy, src))


def _groups(get: Callable[[str], Any], psd, csd, xy, src: str) -> dict[str, Any]:
    """The optional groups: ``group_count`` (G,) > 0 and each group's mean spectra, which must average
    (weighted by the counts) to ``psd``, ``csd`` and ``xy``."""
    keys = ("group_count", "group_psd", "group_csd", "group_xy")
    raw = {k: get(k) for k in keys}
    out: dict[str, Any] = dict.fromkeys(keys)
    if all(v is None for v in raw.values()):
        return out
    need = ["group_count", "group_psd", "group_csd"] + (["group_xy"] if xy is not None else [])
    missing = [k for k in need if raw[k] is None]
    if missing or csd is None:
        what = ", ".join(f"'{k}'" for k in missing) if missing else "'psd' and 'csd'"
        raise TactileInputError(f"groups of segments given without {what}", source=src, code="missing_key")
    if raw["group_xy"] is not None and xy is None:
        raise TactileInputError("'group_xy' given without 'xy'", source=src, code="missing_key")
    count = np.asarray(raw["group_count"])
    if count.dtype.kind not in "fiu" or count.ndim != 1 or count.size < 1:
        raise TactileInputError(f"'group_count' must be a real (G,) array, got {_describe(count)}", source=src,
                                code="bad_shape")
    count = _finite(count.astype(np.float64), "group_count", src)
    if np.any(count <= 0):
        raise TactileInputError("'group_count' (segments in each group) must be > 0", source=src, code="bad_shape")
    out["group_count"] = count
    for key, whole in (("group_psd", psd), ("group_csd", csd), ("group_xy", xy)):
        if whole is None:
            continue
        a = np.asarray(raw[key])
        shape = (count.size,) + whole.shape
        if a.dtype.kind not in ("fiu" if key == "group_psd" else "fiuc") or a.shape != shape:
            raise TactileInputError(f"'{key}' must be a {'real' if key == 'group_psd' else 'numeric'} array of "
                                    f"shape (G, {whole.shape[0]}, M) = {shape} to match 'group_count' and 'omega', "
                                    f"got {_describe(a)}", source=src, code="bad_shape")
        a = _finite(_as_float(a), key, src)
        if key != "group_psd" and a.dtype.kind != "c":
            a = a.astype(np.result_type(a.dtype, np.complex64))
        if key == "group_psd" and np.any(a < 0):
            raise TactileInputError("'group_psd' must be >= 0", source=src, code="bad_shape")
        mean = np.tensordot(count, a, axes=1) / count.sum()
        scale = np.max(np.abs(whole), initial=0.0)
        if not np.allclose(mean, whole, rtol=1e-5, atol=1e-9 * scale):
            name = key.removeprefix("group_")
            raise TactileInputError(f"'{key}' does not average to '{name}' (weighted by 'group_count')", source=src,
                                    code="bad_shape")
        out[key] = a
    return out


def _estimator_values(get: Callable[[str], Any], src: str) -> dict[str, Any]:
    """The optional description of the spectral estimator: kernel, bin_factor, whitening, fs."""
    out: dict[str, Any] = {"kernel": None, "bin_factor": None, "whitening": None, "fs": None}
    for key in ("bin_factor", "fs"):
        value = get(key)
        if value is not None:
            value = _real_scalar(value, key, src, "bad_setting")
            if not (np.isfinite(value) and value > 0):
                raise TactileInputError(f"'{key}' must be positive and finite, got {value}", source=src,
                                        code="bad_setting")
            out[key] = value
    kernel = _two_rows(get("kernel"), "kernel", "(2, J) array of bin offsets and weights", src)
    if kernel is not None and (np.any(kernel[1] < 0) or not np.isclose(kernel[1].sum(), 1.0, rtol=1e-6)):
        raise TactileInputError("'kernel' weights (second row) must be >= 0 and sum to 1", source=src,
                                code="bad_shape")
    out["kernel"] = kernel
    out["whitening"] = _two_rows(get("whitening"), "whitening", "(2, p + 1) array of AR error filters", src)
    if out["whitening"] is not None and out["fs"] is None:
        raise TactileInputError("'whitening' given without 'fs' (Hz)", source=src, code="missing_key")
    return out


def _two_rows(value, key: str, what: str, src: str) -> np.ndarray | None:
    """A finite real (2, J >= 1) float64 array, or None when absent."""
    if value is None:
        return None
    a = np.asarray(value)
    if a.dtype.kind not in "fiu" or a.ndim != 2 or a.shape[0] != 2 or a.shape[1] < 1:
        raise TactileInputError(f"'{key}' must be a {what}, got {_describe(a)}", source=src, code="bad_shape")
    return _finite(a.astype(np.float64), key, src)


def _matrix(value, key: str, rows: int, m: int, src: str, *, complex_ok: bool = False) -> np.ndarray:
    """A finite (rows, M) array; real unless ``complex_ok`` (then returned complex)."""
    a = np.asarray(value)
    kinds = "fiuc" if complex_ok else "fiu"
    if a.dtype.kind not in kinds:
        what = "numeric" if complex_ok else "real"
        raise TactileInputError(f"'{key}' must be a {what} array, got dtype {a.dtype}", source=src, code="bad_shape")
    if a.shape != (rows, m):
        raise TactileInputError(f"'{key}' must have shape ({rows}, M) = ({rows}, {m}) to match 'omega', got {a.shape}",
                                source=src, code="bad_shape")
    a = _as_float(a)
    if complex_ok and a.dtype.kind != "c":
        a = a.astype(np.result_type(a.dtype, np.complex64))
    return _finite(a, key, src)


def _optional_values(get: Callable[[str], Any], src: str) -> dict[str, Any]:
    """``curvature_radius``, ``velocity``, ``gain_ratio`` normalised to floats/tuples (None when absent)."""
    out: dict[str, Any] = {"curvature_radius": None, "velocity": None, "gain_ratio": None}
    r = get("curvature_radius")
    if r is not None:
        r = _real_scalar(r, "curvature_radius", src, "bad_setting")
        if not (np.isfinite(r) and r > 0):
            raise TactileInputError(f"'curvature_radius' must be positive and finite (m), got {r}",
                                    source=src, code="bad_setting")
        out["curvature_radius"] = r
    v = get("velocity")
    if v is not None:
        a = np.asarray(v)
        if a.dtype.kind not in "fiu" or a.size != 2:
            raise TactileInputError(f"'velocity' must be [vx, vy] in m/s, got {_describe(a)}",
                                    source=src, code="bad_setting")
        a = a.astype(np.float64).ravel()
        if not np.all(np.isfinite(a)):
            raise TactileInputError(f"'velocity' must be finite, got {a.tolist()}", source=src, code="bad_setting")
        out["velocity"] = (float(a[0]), float(a[1]))
    g = get("gain_ratio")
    if g is not None:
        a = np.asarray(g)
        if a.dtype.kind not in "fiu" or a.size not in (1, 2):
            raise TactileInputError(f"'gain_ratio' must be a number or a pair (gx, gy), got {_describe(a)}",
                                    source=src, code="bad_setting")
        a = a.astype(np.float64).ravel()
        if not (np.all(np.isfinite(a)) and np.all(a > 0)):
            raise TactileInputError(f"'gain_ratio' must be positive and finite, got {a.tolist()}",
                                    source=src, code="bad_setting")
        out["gain_ratio"] = float(a[0]) if a.size == 1 else (float(a[0]), float(a[1]))
    return out


def _optional_attrs(get: Callable[[str], Any], src: str) -> dict[str, Any]:
    """The optional fields as storable arrays, only those that are not None."""
    attrs: dict[str, Any] = {}
    for key, value in _optional_values(get, src).items():
        if value is not None:
            attrs[key] = np.asarray(value, dtype=np.float64)
    return attrs


def _real_scalar(value, key: str, src: str, code: str) -> float:
    a = np.asarray(value)
    if a.dtype.kind not in "fiu" or a.size != 1:
        raise TactileInputError(f"'{key}' must be a real number, got {_describe(a)}", source=src, code=code)
    return float(a.reshape(()))


def _depth_pair(value, src: str) -> tuple[float, float]:
    a = np.asarray(value)
    if a.dtype.kind not in "fiu" or a.size != 2:
        raise TactileInputError(f"'depths' must be [d1, d2] in metres, got {_describe(a)}", source=src,
                                code="bad_depths")
    a = a.astype(np.float64).ravel()
    return (float(a[0]), float(a[1]))


def _finite(a: np.ndarray, key: str, src: str) -> np.ndarray:
    bad = ~np.isfinite(a)
    if bad.any():
        where = ", ".join(str(int(i)) for i in np.argwhere(bad)[0])
        raise TactileInputError(f"'{key}' contains {int(bad.sum())} NaN or inf values (first at index [{where}])",
                                source=src, code="nonfinite")
    return a


def _as_float(a: np.ndarray) -> np.ndarray:
    """Integers become float64; float and complex arrays keep their dtype (native byte order)."""
    return a.astype(np.float64) if a.dtype.kind in "iu" else _native(a)


def _native(a: np.ndarray) -> np.ndarray:
    """Same dtype in native byte order (a big-endian float32 stays float32)."""
    if a.dtype.byteorder not in ("=", "|") and a.dtype != a.dtype.newbyteorder("="):
        return a.astype(a.dtype.newbyteorder("="))
    return a


def _decode_truth(value, src: str) -> dict:
    if value is None:
        return {}
    if isinstance(value, np.ndarray):
        if value.shape != () or value.dtype.kind not in "USO":
            raise TactileInputError("'truth' must be a JSON string", source=src, code="unreadable")
        value = value.item()
    try:
        if isinstance(value, bytes):
            value = value.decode("utf-8")
        if not isinstance(value, str):
            raise TypeError(f"got {type(value).__name__}")
        obj = json.loads(value)
    except (TypeError, ValueError) as exc:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise TactileInputError(f"'truth' is not a valid JSON string ({_brief(exc)})", source=src,
                                code="unreadable") from None
    if not isinstance(obj, dict):
        raise TactileInputError(f"'truth' must decode to a JSON object, got {type(obj).__name__}",
                                source=src, code="unreadable")
    return obj


def _encode_truth(truth, src: str) -> str | None:
    if not truth:
        return None
    if not isinstance(truth, Mapping):
        raise TactileInputError(f"'truth' must be a dict, got {type(truth).__name__}", source=src, code="bad_setting")
    try:
        return json.dumps(dict(truth), default=_json_default)
    except (TypeError, ValueError) as exc:
        raise TactileInputError(f"'truth' is not JSON-serialisable ({_brief(exc)})", source=src,
                                code="bad_setting") from None


def _json_default(obj):
    if isinstance(obj, (np.ndarray, np.generic)):
        return obj.tolist()
    raise TypeError(f"Object of type {type(obj).__name__} is not JSON serializable")


# --------------------------------------------------------------------------- writing


def _atomic_write(path: Path, kind: str, arrays: dict[str, np.ndarray], attrs: dict[str, Any]) -> Path:
    """Write ``arrays`` and ``attrs`` as HDF5 or NPZ through the package's one atomic writer."""
    def write(tmp):
        if kind == "npz":
            with open(tmp, "wb") as fh:
                _write_npz(fh, arrays, attrs)
        else:
            _write_h5(tmp, arrays, attrs)

    return atomic_write(path, write)


def _write_h5(tmp: Path, arrays: dict[str, np.ndarray], attrs: dict[str, Any]) -> None:
    with h5py.File(tmp, "w") as f:
        for key, value in arrays.items():
            f.create_dataset(key, data=value)
        for key, value in attrs.items():
            if isinstance(value, str) and len(value.encode("utf-8")) > _MAX_ATTR_BYTES:
                f.create_dataset(key, data=value, dtype=h5py.string_dtype("utf-8"))
            else:
                f.attrs[key] = value


def _write_npz(fh, arrays: dict[str, np.ndarray], attrs: dict[str, Any]) -> None:
    members = dict(arrays)
    members.update({k: np.asarray(v) for k, v in attrs.items()})  # a str becomes a 0-d unicode array
    np.savez(fh, **members)


# --------------------------------------------------------------------------- small helpers


def _as_path(path) -> tuple[Path, str]:
    return Path(os.fspath(path)), str(path)


def file_kind(path: Path, src: str) -> str:
    """The format of ``path`` by its suffix: ``hdf5``, ``npz``, ``wav`` or ``flac``."""
    kind = _KIND.get(path.suffix.lower())
    if kind is None:
        accepted = ", ".join(RECORDING_SUFFIXES)
        got = f"'{path.suffix}'" if path.suffix else "no suffix"
        raise TactileInputError(f"unsupported file type ({got}); accepted suffixes: {accepted}", source=src,
                                code="unreadable")
    return kind


def _store_kind(path: Path, src: str, audio_problem: str) -> str:
    """``file_kind`` of an HDF5 or NPZ file; an audio suffix is refused with ``audio_problem``."""
    kind = file_kind(path, src)
    if kind in _AUDIO_KINDS:
        raise TactileInputError(audio_problem, source=src, code="unreadable")
    return kind


def _describe(a: np.ndarray) -> str:
    if a.size <= 4 and a.dtype.kind in "fiub":
        return f"{a.tolist()!r}"
    return f"{a.dtype} array of shape {a.shape}"


def _brief(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    if len(text) > 200:
        text = text[:197] + "..."
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__
