"""Recordings whose slip changes over time: a path of pieces, each a constant slip and contact.

A path is a list of :class:`Piece` (duration, velocity, contact). Every moving
piece is simulated by :func:`scene.simulate` without noise, with its own seed
(a new realisation of the same texture statistics, as if the object moved to
a fresh spot); a still piece (velocity (0, 0)) is zero signal, since a
pressed object that does not move gives no AC pressure. The pieces are
joined along time with raised-cosine crossfades, so that no step enters the
signals: centred on a join of two moving pieces, and inside the moving piece
at a join with a still one (it fades in after the join, or out before it, so
a still piece holds no signal at all). One white Gaussian noise process of
constant std is added to the whole recording:

    sigma = sqrt(P_ref) 10^(-snr_db / 20),

P_ref the larger of the mean powers of the shallow channels x1 and y1 over
the samples of the moving pieces (the reference of ``Scene.snr_db``). A
still piece therefore holds noise of std sigma alone.

``truth["path"]`` lists the pieces with their start and end times (s), vx,
vy (m/s), a (m, None for a still piece without a contact), contact_depth and
window; :func:`truth_at` finds the piece a time span lies in.
:func:`standard_paths` holds the paths of the tracker's benchmark and tests.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Iterable

import numpy as np

from ..errors import TactileInputError
from ..io.recording import Recording
from ..model.sensor import PAPER_SENSOR, Sensor
from ..model.window import WINDOWS
from .scene import Scene, _number, simulate
from .texture import RandomTexture, describe_texture

__all__ = ["Piece", "simulate_path", "truth_at", "standard_paths"]


def _bad(msg: str) -> TactileInputError:
    return TactileInputError(msg, code="bad_setting")


def _finite(name: str, value) -> float:
    if isinstance(value, bool):
        raise _bad(f"{name} must be a number, got {value!r}")
    return _number(name, value)        # the scene's check: a finite number, one line otherwise


def _positive(name: str, value) -> float:
    v = _finite(name, value)
    if v <= 0:
        raise _bad(f"{name} must be positive, got {value!r}")
    return v


@dataclasses.dataclass(frozen=True)
class Piece:
    """A stretch of constant slip and contact (SI units).

    duration: seconds (> 0).
    velocity: (vx, vy) of the object over the sensor, m/s; (0, 0) is a still
        contact (no signal, only the recording's noise).
    contact_radius: a, m; or ``contact_depth`` (m) instead, a = sqrt(R d) with
        R the sensor's curvature radius. A moving piece needs exactly one of
        the two; a still piece may give one or none (its ``a`` in the truth is
        then None).

    The values are checked and stored as floats; a bad one raises a one-line
    ``TactileInputError`` (code "bad_setting").
    """

    duration: float
    velocity: tuple[float, float] = (0.0, 0.0)
    contact_radius: float | None = None
    contact_depth: float | None = None

    def __post_init__(self):
        object.__setattr__(self, "duration", _positive("Piece duration", self.duration))
        try:
            v = tuple(self.velocity)
        except TypeError:
            raise _bad(f"Piece velocity must be two numbers (vx, vy), got {self.velocity!r}") from None
        if len(v) != 2:
            raise _bad(f"Piece velocity must be two numbers (vx, vy), got {self.velocity!r}")
        object.__setattr__(self, "velocity", (_finite("Piece vx", v[0]), _finite("Piece vy", v[1])))
        for name in ("contact_radius", "contact_depth"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, _positive(f"Piece {name}", value))
        has_r, has_d = self.contact_radius is not None, self.contact_depth is not None
        if has_r and has_d:
            raise _bad("Piece: give one of contact_radius and contact_depth, not both"
                       f" (got contact_radius={self.contact_radius!r}, contact_depth={self.contact_depth!r})")
        if self.moving and not (has_r or has_d):
            raise _bad(f"Piece: a moving piece (velocity {self.velocity}) needs contact_radius or contact_depth")

    @property
    def moving(self) -> bool:
        """Whether the object slides (velocity not (0, 0))."""
        return self.velocity != (0.0, 0.0)

    def radius(self, sensor: Sensor = PAPER_SENSOR) -> float | None:
        """Contact radius a (m) on ``sensor``, or None for a piece without a contact."""
        if self.contact_radius is not None:
            return self.contact_radius
        if self.contact_depth is not None:
            return math.sqrt(float(sensor.curvature_radius) * self.contact_depth)
        return None


def _piece_seed(seq: np.random.SeedSequence) -> int:
    return int(seq.generate_state(1, dtype=np.uint32)[0])


def _ramp(n: int) -> np.ndarray:
    """Raised-cosine fade-in of ``n`` samples, 0.5 (1 - cos(pi u)) at the sample centres u in (0, 1)."""
    u = (np.arange(n) + 0.5) / n
    return 0.5 * (1.0 - np.cos(np.pi * u))


def simulate_path(
    pieces: Iterable[Piece],
    *,
    texture=RandomTexture(),
    window: str = "hertz",
    fs: float = 1000.0,
    snr_db: float | None = 45.0,
    sensor: Sensor = PAPER_SENSOR,
    seed: int = 0,
    crossfade: float = 0.005,
) -> Recording:
    """Simulate a path of pieces: a Recording with signals (4, n) float64 and the path in ``truth``.

    pieces: the :class:`Piece` list, in time order. Piece i spans the samples
        round(t_i fs) .. round(t_{i+1} fs) - 1, t_i the sum of the durations
        before it, so the pieces tile the recording without drift.
    texture, window, sensor: as in ``Scene``, shared by all pieces.
    fs: sample rate, Hz. seed: seeds each moving piece's texture (a seed
        drawn from ``seed`` and the piece index) and, independently, the noise.
    snr_db: sets the std of the one noise process of the whole recording,
        sigma = sqrt(P_ref) 10^(-snr_db / 20), P_ref the larger of the mean
        powers of x1 and y1 over the moving pieces; None: no noise.
    crossfade: length (s) of the raised-cosine crossfades. At a join of two
        moving pieces it is centred on the join (both are simulated half of
        it longer, and their weights sum to 1); at a join with a still piece
        the moving piece fades in over its first crossfade seconds, or out
        over its last. 0: the pieces are cut at the joins.

    ``truth`` (JSON-serialisable) holds ``path``: one dict per piece with
    start, end (s), vx, vy (m/s), a and contact_depth (m; None for a still
    piece without a contact), window, moving and seed (the scene seed of a
    moving piece, else None); and texture (``describe_texture``), snr_db,
    noise_std, seed, fs, duration, n_samples, crossfade, window, depths and
    curvature_radius. Raises a one-line ``TactileInputError`` (code
    "bad_setting") for a bad path or setting.
    """
    try:
        pieces = [pieces] if isinstance(pieces, Piece) else list(pieces)
    except TypeError:
        raise _bad(f"pieces must be a list of Piece, got {type(pieces).__name__}") from None
    if not pieces:
        raise _bad("pieces: the path needs at least one piece")
    for i, p in enumerate(pieces):
        if not isinstance(p, Piece):
            raise _bad(f"pieces: item {i} is a {type(p).__name__}, not a Piece")
    fs = _positive("fs", fs)
    if snr_db is not None:
        snr_db = _finite("snr_db", snr_db)
    crossfade = _finite("crossfade", crossfade)
    if crossfade < 0:
        raise _bad(f"crossfade must be >= 0, got {crossfade!r}")
    if window not in WINDOWS:
        raise _bad(f"window must be one of {', '.join(WINDOWS)}, got {window!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise _bad(f"seed must be a non-negative integer, got {seed!r}")
    seed = int(seed)

    edges = np.concatenate([[0.0], np.cumsum([p.duration for p in pieces])])
    bounds = np.rint(edges * fs).astype(np.int64)
    n_total = int(bounds[-1])
    n_cf = int(round(crossfade * fs))
    # a join b of two moving pieces: the ramp spans [b - h_left, b + h_right); of a still and a moving
    # piece: the n_cf samples of the moving piece next to b
    h_left, h_right = n_cf // 2, n_cf - n_cf // 2
    last = len(pieces) - 1
    for i, p in enumerate(pieces):
        n_i = int(bounds[i + 1] - bounds[i])
        need = 1
        if p.moving:      # its samples (with the halves of the crossfades it shares) must hold its ramps
            fade_in = 0 if i == 0 else (h_right if pieces[i - 1].moving else n_cf)
            fade_out = 0 if i == last else (h_left if pieces[i + 1].moving else n_cf)
            need = max(2, fade_in + fade_out)
        if n_i < need:
            raise _bad(f"piece {i}: duration {p.duration} s gives {n_i} samples at fs {fs} Hz;"
                       f" need at least {need} (the crossfades of {crossfade} s at its joins, 2 for a moving piece)")

    root = np.random.SeedSequence(seed)
    noise_seq, *piece_seqs = root.spawn(len(pieces) + 1)
    ramp = _ramp(n_cf)
    clean = np.zeros((4, n_total))
    moving_mask = np.zeros(n_total, dtype=bool)
    path = []
    R = float(sensor.curvature_radius)
    for i, p in enumerate(pieces):
        b0, b1 = int(bounds[i]), int(bounds[i + 1])
        a = p.radius(sensor)
        entry = {
            "start": b0 / fs,
            "end": b1 / fs,
            "vx": p.velocity[0],
            "vy": p.velocity[1],
            "a": a,
            "contact_depth": None if a is None else a * a / R,
            "window": window,
            "moving": p.moving,
            "seed": None,
        }
        if p.moving:
            lo = b0 - (h_left if i > 0 and pieces[i - 1].moving else 0)
            hi = b1 + (h_right if i < last and pieces[i + 1].moving else 0)
            piece_seed = _piece_seed(piece_seqs[i])
            scene = Scene(texture=texture, velocity=p.velocity, contact_radius=p.contact_radius,
                          contact_depth=p.contact_depth, window=window, fs=fs, duration=(hi - lo) / fs,
                          snr_db=None, sensor=sensor, seed=piece_seed)
            try:
                sig = simulate(scene).signals
            except TactileInputError as e:
                raise TactileInputError(f"piece {i}: {e.problem}", code=e.code) from None
            weight = np.ones(hi - lo)
            if i > 0 and n_cf:
                weight[:n_cf] = ramp
            if i < last and n_cf:
                weight[-n_cf:] = ramp[::-1]
            clean[:, lo:hi] += sig * weight
            moving_mask[b0:b1] = True
            entry["seed"] = piece_seed
        path.append(entry)

    noise_std = 0.0
    signals = clean
    if snr_db is not None:
        if not moving_mask.any():
            raise _bad("snr_db needs a moving piece to set the noise level (the path is all still);"
                       " give snr_db=None for a silent recording")
        p_ref = max(float(np.mean(np.square(clean[0, moving_mask]))), float(np.mean(np.square(clean[2, moving_mask]))))
        noise_std = math.sqrt(p_ref) * 10.0 ** (-snr_db / 20.0)
        signals = clean + noise_std * np.random.default_rng(noise_seq).standard_normal(clean.shape)

    truth = {
        "path": path,
        "texture": describe_texture(texture),
        "snr_db": snr_db,
        "noise_std": noise_std,
        "seed": seed,
        "fs": fs,
        "duration": n_total / fs,
        "n_samples": n_total,
        "crossfade": n_cf / fs,
        "window": window,
        "depths": [float(sensor.d1), float(sensor.d2)],
        "curvature_radius": R,
    }
    return Recording(
        signals=np.ascontiguousarray(signals, dtype=np.float64),
        fs=fs,
        depths=(float(sensor.d1), float(sensor.d2)),
        curvature_radius=R,
        velocity=None,
        gain_ratio=None,
        truth=truth,
        source=f"simulate_path(seed={seed})",
    )


def truth_at(truth, t0: float, t1: float) -> dict | None:
    """The piece of ``truth["path"]`` that the span [t0, t1] (s) lies in, or None.

    truth: the ``truth`` dict of :func:`simulate_path` (or its Recording).
    Returns a copy of the piece dict of the piece holding the span's midpoint
    when the span reaches past that piece's ends by no more than the
    crossfade plus half a sample; None when it overlaps a neighbour further
    (a span across a join) or lies outside the recording.
    """
    truth = getattr(truth, "truth", truth)
    try:
        path = truth["path"]
    except (TypeError, KeyError):
        raise _bad("truth has no 'path': give the truth of simulate_path") from None
    t0, t1 = _finite("t0", t0), _finite("t1", t1)
    if t1 < t0:
        raise _bad(f"t1 must be >= t0, got t0={t0}, t1={t1}")
    fs = truth.get("fs")
    tol = float(truth.get("crossfade") or 0.0) + (0.5 / float(fs) if fs else 0.0)
    mid = 0.5 * (t0 + t1)
    for k, piece in enumerate(path):
        inside = piece["start"] <= mid < piece["end"] or (k == len(path) - 1 and mid == piece["end"])
        if inside:
            if t0 >= piece["start"] - tol and t1 <= piece["end"] + tol:
                return dict(piece)
            return None
    return None


def standard_paths() -> dict[str, list[Piece]]:
    """Ready-made paths (name -> pieces) for the tracker's benchmark and tests, each 6-12 s.

    - ``still_then_slide``: 2 s still, then 4 s along x at 3 cm/s (a = 2 mm);
    - ``axis_oblique_y``: 4 s along x at 3 cm/s, 4 s oblique at (2, 2) cm/s,
      4 s mostly along y at (1, 4) cm/s (a = 2 mm);
    - ``press_deeper``: 4 s along x at 3 cm/s at contact depth 0.05 mm
      (a = 1.22 mm on the 30 mm sensor), then 4 s at 0.15 mm (a = 2.12 mm);
    - ``speed_change``: 4 s along x at 1.5 cm/s, then 4 s at 6 cm/s (a = 2 mm);
    - ``slide_stop_slide``: 3 s along y at 3 cm/s, 2 s still, 3 s along -x at
      3 cm/s (a = 2 mm, kept while still).

    Simulate one with ``simulate_path(standard_paths()[name])`` (the Hertz
    window by default).
    """
    a = 2.0e-3
    return {
        "still_then_slide": [Piece(2.0, (0.0, 0.0), contact_radius=a),
                             Piece(4.0, (0.03, 0.0), contact_radius=a)],
        "axis_oblique_y": [Piece(4.0, (0.03, 0.0), contact_radius=a),
                           Piece(4.0, (0.02, 0.02), contact_radius=a),
                           Piece(4.0, (0.01, 0.04), contact_radius=a)],
        "press_deeper": [Piece(4.0, (0.03, 0.0), contact_depth=0.05e-3),
                         Piece(4.0, (0.03, 0.0), contact_depth=0.15e-3)],
        "speed_change": [Piece(4.0, (0.015, 0.0), contact_radius=a),
                         Piece(4.0, (0.06, 0.0), contact_radius=a)],
        "slide_stop_slide": [Piece(3.0, (0.0, 0.03), contact_radius=a),
                             Piece(2.0, (0.0, 0.0), contact_radius=a),
                             Piece(3.0, (-0.03, 0.0), contact_radius=a)],
    }
