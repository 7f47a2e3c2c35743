"""The data contract (docs/data-format.md) that the files and the analysis share.

The recording (four probe signals and their metadata, ``Recording``, checked by
``validate_recording``) and the names of a result row's fields (``RESULT_FIELDS``).
Both the file layer (``io``) and the analysis (``inference``) import this module; it
imports neither, nor anything of the package but ``errors``. ``io.recording`` re-exports
the recording's names, ``inference.result`` ``RESULT_FIELDS``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from .errors import TactileInputError

__all__ = ["CHANNELS", "SENSOR_DEFAULT", "SENSOR_FROM_FILE", "Recording", "validate_recording", "RESULT_FIELDS"]

#: Channel order of every recording: x pair (shallow, deep), then y pair.
CHANNELS = ("x1", "x2", "y1", "y2")
#: ``Recording.sensor`` of an audio recording read without a sensor file: the paper's sensor is assumed
SENSOR_DEFAULT = "paper (default)"
#: ``Recording.sensor`` of an HDF5/NPZ recording whose sensor metadata comes from the file itself
SENSOR_FROM_FILE = "file"

#: the data contract's result fields, in order; ``inference.result.FitResult.to_record`` adds more after them
RESULT_FIELDS = ("file", "index", "vx", "vx_err", "vy", "vy_err", "a", "a_err", "contact_depth",
                 "contact_depth_err", "gain_ratio", "gain_ratio_err", "k0x", "k0y", "model", "window",
                 "converged", "status", "message")


@dataclasses.dataclass(frozen=True)
class Recording:
    """Probe signals with their sampling and sensor metadata (SI units).

    signals: (4, N) or (n, 4, N) float32/float64, channels ``CHANNELS``.
    fs: sample rate, Hz. depths: (d1, d2) in metres, d1 < d2.
    curvature_radius: sensor surface radius, m (optional).
    velocity: (vx, vy) in m/s when the arm knows it (optional).
    gain_ratio: calibrated deep/shallow gain ratio g (optional; scalar or per pair).
    truth: what a simulator knew (free-form, JSON-serialisable), else empty.
    source: where it came from (a path), for messages.
    sensor: where the sensor metadata comes from: ``SENSOR_FROM_FILE`` (the recording file),
    a sensor file's path, ``SENSOR_DEFAULT`` (the paper's sensor, assumed for an audio file
    read without a sensor file), or None (made in code).
    """

    signals: np.ndarray
    fs: float
    depths: tuple[float, float]
    curvature_radius: float | None = None
    velocity: tuple[float, float] | None = None
    gain_ratio: Any = None
    truth: dict = dataclasses.field(default_factory=dict)
    source: str | None = None
    sensor: str | None = None

    @property
    def n_records(self) -> int:
        """Number of records (1 for a (4, N) signal array)."""
        return 1 if self.signals.ndim == 2 else self.signals.shape[0]

    @property
    def n_samples(self) -> int:
        return self.signals.shape[-1]

    def record(self, i: int) -> "Recording":
        """Record ``i`` as a single (4, N) recording."""
        if self.signals.ndim == 2:
            if i != 0:
                raise IndexError(i)
            return self
        return dataclasses.replace(self, signals=self.signals[i])


def validate_recording(rec: Recording) -> Recording:
    """Check a recording against the data contract; raise ``TactileInputError`` naming its source.

    Checks shape (4, N) or (n, 4, N), finite samples, fs > 0 and finite,
    0 < d1 < d2. Returns the recording unchanged.
    """
    src = rec.source or "<recording>"
    sig = rec.signals
    if not isinstance(sig, np.ndarray) or sig.dtype.kind not in "fiu":
        raise TactileInputError("signals must be a real numeric array", source=src, code="bad_shape")
    if sig.ndim not in (2, 3) or sig.shape[-2] != 4:
        raise TactileInputError(
            f"signals must have shape (4, N) or (n, 4, N) with channels x1, x2, y1, y2; got {sig.shape}",
            source=src, code="bad_shape")
    if sig.shape[-1] < 2 or (sig.ndim == 3 and sig.shape[0] == 0):
        raise TactileInputError(f"signals hold no samples (shape {sig.shape})", source=src, code="too_short")
    bad = ~np.isfinite(sig)
    if bad.any():
        idx = np.argwhere(bad)[0]
        where = ", ".join(str(int(v)) for v in idx)
        raise TactileInputError(
            f"signals contain {int(bad.sum())} NaN or inf samples (first at index [{where}])",
            source=src, code="nonfinite")
    fs = rec.fs
    if fs is None:
        raise TactileInputError("missing sample rate 'fs'", source=src, code="bad_fs")
    try:
        fs = float(np.asarray(fs).reshape(()))
    except (TypeError, ValueError):
        raise TactileInputError(f"sample rate 'fs' must be a scalar, got {fs!r}", source=src, code="bad_fs") from None
    if not np.isfinite(fs) or fs <= 0:
        raise TactileInputError(f"sample rate 'fs' must be positive and finite, got {fs}", source=src, code="bad_fs")
    if rec.depths is None:
        raise TactileInputError("missing probe 'depths'", source=src, code="bad_depths")
    d = np.asarray(rec.depths, dtype=float).ravel()
    if d.shape != (2,) or not np.all(np.isfinite(d)) or not (0 < d[0] < d[1]):
        raise TactileInputError(
            f"'depths' must be [d1, d2] in metres with 0 < d1 < d2, got {d.tolist()}",
            source=src, code="bad_depths")
    return rec
