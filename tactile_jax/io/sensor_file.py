"""Sensor files: a sensor's probe depths, surface radius, channel map and gains, in TOML.

``read_sensor(path)`` reads one into a :class:`SensorSpec`. Keys (SI units)::

    depths = [0.265e-3, 0.925e-3]          # [d1, d2] in metres, 0 < d1 < d2 (required)
    curvature_radius = 30e-3               # surface radius, m (optional)
    channels = ["x1", "x2", "y1", "y2"]    # the role of each channel of an audio file (optional)
    gain_ratio = 1.0                       # deep/shallow gain ratio g, or [gx, gy] (optional)

``channels`` lists, in the audio file's channel order, the probe each channel
carries: each of x1, x2, y1, y2 exactly once, any other channel as ``""`` or
``"unused"``. Without it an audio file's four channels are x1, x2, y1, y2.
HDF5 and NPZ recordings hold their signals in that order already; there the
sensor file's values are checked against the file's metadata and fill what
the file leaves out (``merge_metadata``).

Every failure is a one-line :class:`~tactile_jax.errors.TactileInputError`
naming the sensor file, with a ``code``: ``unreadable`` (missing file, not
TOML), ``bad_setting`` (unknown key, bad value, bad channel map),
``missing_key`` / ``bad_depths`` (the depths).
"""

from __future__ import annotations

import dataclasses
import math
import os
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import TactileInputError
from .recording import CHANNELS

__all__ = ["SensorSpec", "SENSOR_KEYS", "UNUSED_CHANNELS", "read_sensor", "as_sensor", "merge_metadata"]

#: the keys a sensor file may hold
SENSOR_KEYS = ("depths", "curvature_radius", "channels", "gain_ratio")
#: the names of a channel that carries no probe
UNUSED_CHANNELS = ("", "unused")
#: relative tolerance within which a sensor file's value agrees with a recording's metadata
AGREE_RTOL = 1e-6


@dataclasses.dataclass(frozen=True)
class SensorSpec:
    """A sensor as a sensor file describes it (SI units).

    depths: (d1, d2) probe depths, m, 0 < d1 < d2. curvature_radius: surface radius, m, or None.
    channels: the role of each channel of an audio file, in its order ("x1", "x2", "y1", "y2",
    or "" for a channel without a probe). gain_ratio: deep/shallow gain ratio g, (gx, gy), or None.
    source: the sensor file's path, or None for a sensor made in code.
    """

    depths: tuple[float, float]
    curvature_radius: float | None = None
    channels: tuple[str, ...] = CHANNELS
    gain_ratio: float | tuple[float, float] | None = None
    source: str | None = None

    @property
    def label(self) -> str:
        """What a recording's ``sensor`` field says of this sensor: the sensor file's path."""
        return self.source or "given"

    @property
    def channel_indices(self) -> tuple[int, int, int, int]:
        """The audio file's channel of x1, x2, y1 and y2."""
        return tuple(self.channels.index(role) for role in CHANNELS)  # type: ignore[return-value]


def read_sensor(path) -> SensorSpec:
    """Read and check a sensor file (TOML); raise ``TactileInputError`` naming it on any failure."""
    src = str(path)
    p = Path(os.fspath(path))
    if not p.exists():
        raise TactileInputError("sensor file not found", source=src, code="unreadable")
    if not p.is_file():
        raise TactileInputError("the sensor file is not a regular file", source=src, code="unreadable")
    try:
        with p.open("rb") as fh:
            table = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise TactileInputError(f"not a valid TOML sensor file ({exc})", source=src, code="unreadable") from None
    except UnicodeDecodeError:
        raise TactileInputError("not a valid TOML sensor file (not UTF-8 text)", source=src,
                                code="unreadable") from None
    except OSError as exc:
        raise TactileInputError(f"cannot read the sensor file: {exc.strerror or exc}", source=src,
                                code="unreadable") from None
    return _spec(table, src)


def as_sensor(sensor) -> SensorSpec | None:
    """``sensor`` as a SensorSpec: None stays None, a SensorSpec is kept, a path is read (``read_sensor``)."""
    if sensor is None or isinstance(sensor, SensorSpec):
        return sensor
    if isinstance(sensor, (str, os.PathLike)):
        return read_sensor(sensor)
    raise TypeError(f"sensor must be a path or a SensorSpec, got {type(sensor).__name__}")


def merge_metadata(meta: dict[str, Any], spec: SensorSpec, src: str) -> dict[str, Any]:
    """A recording file's metadata (``depths``, ``curvature_radius``, ``gain_ratio``; None when absent) with
    what the sensor file adds: where both give a value they must agree (within ``AGREE_RTOL``), else a
    one-line ``TactileInputError`` (code ``bad_setting``) naming the recording ``src``, the sensor file
    and every value that differs; where the file gives none, the sensor file's value is taken."""
    out = dict(meta)
    differ = []
    for key in ("depths", "curvature_radius", "gain_ratio"):
        ours, theirs = meta.get(key), getattr(spec, key)
        if theirs is None:
            continue
        if ours is None:
            out[key] = theirs
        elif not _agree(ours, theirs):
            differ.append(f"{key} {_show(ours)} in the file, {_show(theirs)} in the sensor file")
    if differ:
        raise TactileInputError(f"the sensor file {spec.label} disagrees with the file's metadata: "
                                + "; ".join(differ), source=src, code="bad_setting")
    return out


# --------------------------------------------------------------------------- checking


def _spec(table: dict, src: str) -> SensorSpec:
    unknown = [k for k in table if k not in SENSOR_KEYS]
    if unknown:
        raise TactileInputError(f"unknown key '{unknown[0]}'; a sensor file holds {', '.join(SENSOR_KEYS)}",
                                source=src, code="bad_setting")
    if "depths" not in table:
        raise TactileInputError("missing key 'depths' ([d1, d2] in metres)", source=src, code="missing_key")
    depths = table["depths"]
    if not (isinstance(depths, list) and len(depths) == 2 and all(_is_number(d) for d in depths)):
        raise TactileInputError(f"'depths' must be [d1, d2] in metres, got {depths!r}", source=src,
                                code="bad_depths")
    d1, d2 = (float(d) for d in depths)
    if not (math.isfinite(d1) and math.isfinite(d2) and 0 < d1 < d2):
        raise TactileInputError(f"'depths' must be [d1, d2] in metres with 0 < d1 < d2, got {[d1, d2]}",
                                source=src, code="bad_depths")
    radius = table.get("curvature_radius")
    if radius is not None:
        if not (_is_number(radius) and math.isfinite(radius) and radius > 0):
            raise TactileInputError(f"'curvature_radius' must be a positive number of metres, got {radius!r}",
                                    source=src, code="bad_setting")
        radius = float(radius)
    return SensorSpec(depths=(d1, d2), curvature_radius=radius, channels=_channels(table.get("channels"), src),
                      gain_ratio=_gain(table.get("gain_ratio"), src), source=src)


def _channels(value, src: str) -> tuple[str, ...]:
    if value is None:
        return CHANNELS
    roles = ", ".join(CHANNELS)
    if not (isinstance(value, list) and all(isinstance(v, str) for v in value)):
        raise TactileInputError(f"'channels' must list the role of each channel ({roles}, or \"unused\"), "
                                f"got {value!r}", source=src, code="bad_setting")
    named = [v.strip().lower() for v in value]
    bad = [v for v in named if v not in CHANNELS and v not in UNUSED_CHANNELS]
    if bad:
        raise TactileInputError(f"'channels' names '{bad[0]}'; each channel is one of {roles}, or \"unused\"",
                                source=src, code="bad_setting")
    wrong = [f"{role} {named.count(role)} times" for role in CHANNELS if named.count(role) != 1]
    if wrong:
        raise TactileInputError(f"'channels' must name each of {roles} exactly once; it names "
                                + ", ".join(wrong), source=src, code="bad_setting")
    return tuple("" if v in UNUSED_CHANNELS else v for v in named)


def _gain(value, src: str) -> float | tuple[float, float] | None:
    if value is None:
        return None
    pair = isinstance(value, list) and len(value) == 2
    values = value if pair else [value]
    if not all(_is_number(v) and math.isfinite(v) and v > 0 for v in values):
        raise TactileInputError(f"'gain_ratio' must be a positive number or a pair [gx, gy], got {value!r}",
                                source=src, code="bad_setting")
    return (float(values[0]), float(values[1])) if pair else float(values[0])


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _agree(a, b) -> bool:
    a, b = np.atleast_1d(np.asarray(a, float)), np.atleast_1d(np.asarray(b, float))
    if a.size != b.size:                         # a scalar gain against a pair: the scalar for both pairs
        a, b = np.broadcast_arrays(a, b)
    return bool(np.allclose(a, b, rtol=AGREE_RTOL, atol=0.0))


def _show(v) -> str:
    if isinstance(v, (tuple, list, np.ndarray)):
        return "[" + ", ".join(f"{float(x):g}" for x in np.ravel(v)) + "]"
    return f"{float(v):g}"
