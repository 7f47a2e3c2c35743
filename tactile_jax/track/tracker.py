"""A slip followed over time: sliding-window estimates from a stream of probe samples (``Tracker``).

Every ``hop`` seconds the tracker fits the last ``window`` seconds. The first
window in which the probes hear a moving texture is analysed in full (the
program ``fit`` runs: window, texture and direction chosen by the data); each
later window is one update from the last one's optimum (``track.step``) under
those choices. After ``REACQUIRE_AFTER`` updates in a row that do not settle
or whose misfit rose (a poor fit with a reduced chi-square over ``MISFIT_RISE``
times the level of the updates since the acquisition), the choices held may
no longer describe the slip (a steady misfit is not such a sign): the slip
changed inside the first such window. Where, ``change_point`` finds in the
probes' spectra, again in each window as more of the new slip comes into view.
The windows that still reach across that change are ``slip_change`` (no
values: they hold two slips, which one fit would average), and the first that
lies past it is analysed in full. After a window with no band the next
is analysed. An analysis whose window may reach across the slip's start is
done again, once, when the window lies past it.

Before any fit, each window's segments are tested for a moving texture
(``activity``): the shallow probes' low-frequency power against their
own high-frequency floor. A window with no moving segment is ``no_slip`` (no
values: a still contact is never reported as a speed fitted into noise); a
window whose first segments are still and last ones moving is ``slip_start`` (no
values: the full analysis waits for a window that lies inside the slip), the
reverse ``slip_stop`` (the update's values, which mix the two, while the
updates go on; none once they stopped: such a window gets no analysis).

An update's errors of vx, vy and a are widened where windows that share no
sample (a window apart, since the analysis) differ by more than their errors
allow (``_Held.widen``): each window hears another patch of the texture,
which neither its tapers' jackknife nor its spread across frequency sees.
Until two such windows exist, they are widened by ``UNCALIBRATED_WIDEN``.
A window's analysis fits a minor speed only where the window excludes 0 at
``DIRECTION_LEVEL``.

Rows hold ``t`` (the window's centre, s), ``window_s``, the columns ``fit``
writes (vx, vx_err, vy, vy_err, a, a_err, status, message, ...) and
``update`` ("analysis", "step", or "none" where nothing was fitted: a still window, a slip's start or end, a
band too narrow to fit, whose ``no_band`` row needs no analysis), ``moved`` (the step in sigmas), ``compute_s``.
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import math
import time
from typing import NamedTuple

import numpy as np

from ..errors import TactileInputError
from ..inference import run
from ..io.recording import SENSOR_DEFAULT, SENSOR_FROM_FILE
from ..inference.analysis import DIRECTIONS, WINDOWS, summary_of
from ..inference.core import MIN_BINS, POOR_FIT_REDCHI, Located, Summary, band_bins
from ..inference.fit import result_of
from ..inference.options import FitOptions, analysis_settings, choices_of, known_gains, settings_of
from ..inference.result import FitResult, no_band_result, result_from_summary, update_contact_depth
from ..inference.select import model_name, texture_name
from ..model.sensor import PAPER_SENSOR
from ..spectral.segments import AR_ORDER, segments
from ..status import Status
from . import step as step_mod

__all__ = ["Tracker", "track_recording", "activity", "Activity", "change_point", "default_nperseg", "misfit_rose",
           "WINDOW_S", "HOP_S",
           "MOVING_DB", "REACQUIRE_AFTER", "DIRECTION_LEVEL", "UNCALIBRATED_WIDEN", "direction_keep", "MISFIT_RISE",
           "MISFIT_MEMORY"]

#: default window and hop, seconds
WINDOW_S = 2.0
HOP_S = 0.1
#: a segment hears a moving texture where its shallow probes' mean power over the lowest quarter of the bins
#: is this far (dB) above their high-frequency floor (white noise: 0 dB, scatter below 1 dB)
MOVING_DB = 6.0
#: updates in a row that do not settle, or whose misfit has risen, before the window is analysed in full again
REACQUIRE_AFTER = 3
#: an update's misfit has risen where it is poor and its reduced chi-square exceeds this many times the
#: level the held choices have had: the median over the updates since the acquisition (``MISFIT_MEMORY`` of
#: them at most), taken between 1 and ``core.POOR_FIT_REDCHI`` (an acquisition across a change of the slip
#: misfits: its level must not excuse the poor updates after it)
MISFIT_RISE = 2.0
MISFIT_MEMORY = 20
#: the change-point search (``change_point``): segments of about this many seconds (a power of two samples),
#: half-overlapping, each described by its pairs' deep/shallow log power ratios in ``CHANGE_BANDS`` log-spaced
#: bands
CHANGE_SEGMENT_S = 0.128
CHANGE_BANDS = 6
#: splits more than this many segments from the best one are its rivals (``change_point``'s sharpness); a
#: change is placed where the best split's statistic is at least ``CHANGE_SHARP`` times theirs. On
#: benchmarks/track.py's recordings, where the misfit first rose: 1.85-4.4 at the paths' changes of speed or
#: direction; 1.1-1.6 where it rose inside a constant slip, and 1.2 at the press from 0.05 to 0.15 mm
CHANGE_APART = 4
CHANGE_SHARP = 1.75
#: the search reaches this far (s) before the first window whose misfit rose, so that the old slip is in view
CHANGE_LOOKBACK = 0.5
#: where the change cannot be placed, the window is analysed at once and again once it lies past the point this
#: fraction of a window before the end of the first window whose misfit rose
CHANGE_SEEN = 0.5
#: time-half-bandwidth of the window's DPSS tapers (5 tapers: the jackknife's groups): a 2 s
#: window resolves 2 Hz, where Welch segments that leave six groups resolve 4 Hz (Hann's main lobe)
NW = 4.0
#: fewest half-overlapping Welch segments in a window (the jackknife's groups; ``method="welch"``)
MIN_SEGMENTS = 6
#: a window's analysis fits a minor speed only where the window excludes 0 at this level: fitting it must lower
#: chi-square by the F(1, G - 1) quantile in units of the speed's error scale, a variance ratio from the window's
#: G jackknife groups (5 tapers: 7.71), where a 16 s record's analysis asks Akaike's 2. The spectra depend on a
#: minor speed quadratically, so a fitted value whose truth is 0 sits about twice as many of its Laplace errors
#: from 0 as chi-square's fall says, and the scale's G - 1 = 4 degrees of freedom leave it uncertain. On 48
#: windows of 3 cm/s slips along x or y (2 s, Hertz contact, 40-50 dB) Akaike's 2 fitted the minor speed in 19,
#: 10 of them more than 3 of their errors from 0; this level in 4. On 24 windows of the same slips 8 deg off x (a
#: minor speed of 14 % of |v|) it fits it in 9, Akaike's 2 in 17: a 2 s window seldom resolves such a speed
DIRECTION_LEVEL = 0.95
#: the quantities whose errors ``_Held.widen`` calibrates on windows that share no sample
WIDEN_QUANTITIES = ("vx", "vy", "a")
#: ... and the factors (vx, vy, a) they are widened by before any two rows since the analysis share no sample
#: (the analysis's own row and the first window's worth of updates): the rms, in units of their errors, of such
#: rows' deviations from the truth on benchmarks/track.py's 24 constant slips, unwidened: 1.50 over 500 speeds,
#: 1.66 over 356 radii (the rows after them, widened by their own comparisons: 0.90 and 1.30)
UNCALIBRATED_WIDEN = np.array([1.5, 1.5, 1.65])


def default_nperseg(n_window: int) -> int:
    """The Welch segment of a window of ``n_window`` samples: the longest power of two that leaves
    ``MIN_SEGMENTS`` half-overlapping segments (finest resolution at the jackknife's least)."""
    n = max(int(n_window) - AR_ORDER, 16)
    return max(16, 1 << ((2 * n // (MIN_SEGMENTS + 1)).bit_length() - 1))


class Activity(NamedTuple):
    """The moving-texture test of one window: moving (S,) per segment in time order, excess_db (S,) their
    low-band power over the floor, and the verdict: "still", "moving",
    "start" (still groups first, moving ones last) or "stop" (the reverse)."""

    moving: np.ndarray
    excess_db: np.ndarray
    verdict: str


def activity(window, nperseg: int) -> Activity:
    """Which of a window's half-overlapping segments hear a moving texture (see the module): window (4, N)
    samples, the shallow probes x1 and y1 Hann-windowed without prewhitening (a filter fitted to a loud part
    of the window would lift a still part's low band)."""
    x = np.asarray(window, float)[[0, 2]]
    step = nperseg // 2
    starts = np.arange(0, x.shape[-1] - nperseg + 1, step)
    idx = starts[:, None] + np.arange(nperseg)[None, :]
    seg = x[:, idx]                                                            # (2, S, nperseg)
    seg = (seg - seg.mean(axis=-1, keepdims=True)) * np.hanning(nperseg)
    power = np.sum(np.abs(np.fft.rfft(seg, axis=-1)) ** 2, axis=0)             # (S, nperseg // 2 + 1)
    m = power.shape[-1]
    low = power[:, 1:max(2, m // 4)].mean(axis=-1)
    floor = np.median(power[:, m // 2:], axis=-1)
    excess = 10.0 * np.log10(np.maximum(low, 1e-300) / np.maximum(floor, 1e-300))
    moving = excess >= MOVING_DB
    if not moving.any():
        verdict = "still"
    elif not moving[0] and moving[-1]:
        verdict = "start"
    elif moving[0] and not moving[-1]:
        verdict = "stop"
    else:
        verdict = "moving"
    return Activity(moving, excess, verdict)


def change_point(samples, fs: float) -> tuple[float, float]:
    """Where (s from the first sample) the slip changes most: the split of a run of samples (4, N) into a before
    and an after whose segments' features differ most in mean, for their scatter (the single change point of a
    shift in mean, each feature scaled by its pooled within-side variance). A segment's features are each pair's
    deep/shallow log power ratio in ``CHANGE_BANDS`` log-spaced bands: the ratio at a frequency is R(omega / v)
    (paper Eq. 5), which a change of speed, direction or contact moves, while the texture's own lumps (another
    patch of the surface) cancel from it, except in bands where the deep probe hears its noise alone. (Keeping
    only the bands the deep probe hears over its floor blunted the changes of speed, whose bands it hears on one
    side only: a sharpness of 1.1 at the speed change of benchmarks/track.py.)
    The split is sought with at least three segments each side. Returns where the change lies, midway between the
    last segment before the split and the first after (a resolution of half a segment, ``CHANGE_SEGMENT_S``), and
    how sharp the split is: its statistic over the largest of the splits more than ``CHANGE_APART`` segments from
    it (near 1: nothing tells where a change lies)."""
    x = np.asarray(samples, float)
    n = max(16, 1 << (int(round(CHANGE_SEGMENT_S * fs)).bit_length() - 1))
    step = n // 2
    starts = np.arange(0, x.shape[-1] - n + 1, step)
    if starts.size < 6:
        return 0.5 * x.shape[-1] / fs, 1.0
    seg = x[:, starts[:, None] + np.arange(n)[None, :]]                        # (4, S, n)
    power = np.abs(np.fft.rfft((seg - seg.mean(-1, keepdims=True)) * np.hanning(n), axis=-1)) ** 2
    edges = np.unique(np.round(np.geomspace(1, power.shape[-1] // 2, CHANGE_BANDS + 1)).astype(int))
    level = np.stack([np.log(np.maximum(power[..., a:b].mean(-1), 1e-300)) for a, b in zip(edges[:-1], edges[1:])])
    f = (level[:, 1::2] - level[:, 0::2]).reshape(-1, level.shape[-1]).T          # (S, 2 B)
    n_seg = f.shape[0]
    cum, cum2 = np.cumsum(f, 0), np.cumsum(f * f, 0)
    k = np.arange(3, n_seg - 2)                                                  # segments before the split
    mean_a, mean_b = cum[k - 1] / k[:, None], (cum[-1] - cum[k - 1]) / (n_seg - k)[:, None]
    within = (cum2[-1] - k[:, None] * mean_a ** 2 - (n_seg - k)[:, None] * mean_b ** 2) / (n_seg - 2)
    stat = (k * (n_seg - k) / n_seg) * np.sum((mean_a - mean_b) ** 2 / np.maximum(within, 1e-12), -1)
    i = int(np.argmax(stat))
    best = int(k[i])
    far = np.abs(k - best) > CHANGE_APART
    sharp = float(stat[i] / np.max(stat[far])) if far.any() else np.inf
    return float((starts[best - 1] + n + starts[best]) / 2.0 / fs), sharp


def direction_keep(groups: int, level: float = DIRECTION_LEVEL) -> float:
    """The fall of chi-square, in units of a minor speed's error scale estimated from ``groups`` jackknife groups,
    that a window's analysis needs to fit that speed rather than hold it at 0 (``DIRECTION_LEVEL``): the
    F(1, groups - 1) quantile. (scipy.special's, which the spectra's tapers import already: scipy.stats would add
    0.4 s to a track's first analysis.)"""
    from scipy.special import fdtri

    return float(fdtri(1, max(int(groups) - 1, 1), level))


def misfit_rose(redchi: float, history) -> bool:
    """Whether a poor update's reduced chi-square ``redchi`` rose above the level of the updates held so far
    (``history``, their reduced chi-squares): over ``MISFIT_RISE`` times their median, taken between 1 and
    ``core.POOR_FIT_REDCHI``."""
    level = float(np.clip(np.median(history), 1.0, POOR_FIT_REDCHI)) if len(history) else 1.0
    return bool(redchi > MISFIT_RISE * level)


class _StepData(NamedTuple):
    """What an update's row reads of its data (``result_from_summary``): the chain's bins and the random
    effects' sds."""

    mask_xy: np.ndarray
    lump_sd: np.ndarray


def step_summary(u: step_mod.Update) -> Summary:
    """The ``Summary`` of an update (numpy), which ``result_from_summary`` turns into a row."""
    e = u.errors
    loc = Located(u.state.i0, np.asarray(0), np.full(2, np.nan), u.speed0)
    return Summary(np.asarray(u.theta), *(np.asarray(x) for x in (e.cov, e.sd)), np.asarray(u.state.free),
                   *(np.asarray(x) for x in (e.scales, e.pooled, e.chi2, e.redchi, e.n_data, e.cond, e.decrement,
                                             e.step_sigma, e.converged, e.settled)),
                   np.asarray(e.status), np.asarray(e.n_bins), loc, np.asarray(e.jackknife), None, None, None,
                   _StepData(np.asarray(u.state.mask_xy), np.asarray(u.state.lump_sd)), np.asarray(e.spread),
                   np.asarray(e.roughness), np.asarray(e.lumpy))


@functools.cache
def _update_program():
    # kept in the persistent cache with its traced form (``run._exported``): a new process then skips the
    # seconds of tracing the update and the state programs
    return run._exported(step_mod.update, "track_update", (step_mod.TrackState, step_mod.Update))


@functools.cache
def _band_program():
    return run._exported(band_bins, "track_band", (Located,))


@functools.cache
def _state_program():
    return run._exported(step_mod.state_from, "track_state", (step_mod.TrackState,))


@dataclasses.dataclass
class _Held:
    """What the tracker holds between updates: the acquisition's choices and the state."""

    state: step_mod.TrackState
    settings: object
    window: str
    texture: str
    direction: str
    redchi: list = dataclasses.field(default_factory=list)
    bad: int = 0
    bad_since: float = math.nan     # the end (s) of the first window of the run of ``bad`` updates
    recheck_at: float | None = None     # a window that starts after this time (s) is analysed again, once
    # (window end s, log values (3,), their sds (3,)) of vx, vy, a in the rows of the last window and a hop, NaN
    # where not fitted; and the sums and counts of the squared differences, in their sds, of the rows since the
    # acquisition that share no sample (``widen``)
    estimates: collections.deque = dataclasses.field(default_factory=collections.deque)
    z2_sum: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    z2_n: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))

    def widen(self, end_s: float, res: FitResult, window_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Take ``res`` (a row ending at ``end_s``) into the history and return the factors (3,) its errors of vx,
        vy and a (``WIDEN_QUANTITIES``) are to be widened by, and whether each was measured: each one's rms over
        the pairs of rows a window or more apart (they share no sample: each window hears another patch of the
        texture, which its own errors cannot see) of their differences in units of their errors, where it is
        above 1; before any such pair, ``UNCALIBRATED_WIDEN``. A slip that changes slowly widens them too."""
        logs, sds = np.full(3, np.nan), np.full(3, np.nan)
        for q, name in enumerate(WIDEN_QUANTITIES):
            est = res[name]
            if est.value is not None and est.err and est.value > 0:
                logs[q], sds[q] = math.log(est.value), est.err / est.value
        # the latest row a window or more earlier: the rows before it are no longer needed (ends only increase)
        apart = end_s - window_s + 1e-9
        while len(self.estimates) > 1 and self.estimates[1][0] <= apart:
            self.estimates.popleft()
        if self.estimates and self.estimates[0][0] <= apart:
            _, old_logs, old_sds = self.estimates[0]
            z2 = np.square(logs - old_logs) / (np.square(sds) + np.square(old_sds))
            seen = np.isfinite(z2)
            self.z2_sum += np.where(seen, z2, 0.0)
            self.z2_n += seen
        self.estimates.append((end_s, logs, sds))
        measured = self.z2_n > 0
        mean = np.where(measured, self.z2_sum / np.maximum(self.z2_n, 1), np.square(UNCALIBRATED_WIDEN))
        return np.maximum(1.0, np.sqrt(mean)), measured


class Tracker:
    """Sliding-window estimates of a slip as it changes (see the module).

    fs: sample rate, Hz. sensor: a ``model.sensor.Sensor`` (depths d1, d2, curvature radius), or an object with
    ``depths`` and ``curvature_radius`` (a sensor file's); None: the paper's sensor, which every row then
    names. window, hop: seconds (defaults ``WINDOW_S``, ``HOP_S``). options: ``FitOptions`` (gains, window,
    known velocity). method: the window's spectral estimator, "multitaper" (DPSS tapers of time-half-bandwidth
    ``nw`` over the whole window) or "welch" (segments of ``nperseg``, default ``default_nperseg``); the
    moving-texture test uses ``default_nperseg``'s segments either way. t0: the time of the first
    sample, s. source: a name for messages and the rows' ``file``.

    ``push(samples)`` takes a (4, n) block of x1, x2, y1, y2 as it arrives and returns the rows that became
    due; ``rows`` keeps them all.
    """

    def __init__(self, fs: float, sensor=None, *, window: float = WINDOW_S, hop: float = HOP_S,
                 options: FitOptions = FitOptions(), method: str = "multitaper", nw: float = NW,
                 nperseg: int | None = None, t0: float = 0.0, source: str | None = None):
        src = source or "<stream>"
        fs = float(fs)
        if not math.isfinite(fs) or fs <= 0:
            raise TactileInputError(f"sample rate must be positive and finite, got {fs}", source=src, code="bad_fs")
        for name, value in (("window", window), ("hop", hop)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise TactileInputError(f"--{name} must be a positive number of seconds, got {value!r}", source=src,
                                        code="bad_setting")
        self.fs, self.source, self.options, self.t0 = fs, source, options, float(t0)
        if method not in ("multitaper", "welch"):
            raise TactileInputError(f"method must be 'multitaper' or 'welch', got {method!r}", source=src,
                                    code="bad_setting")
        self.method, self.nw = method, float(nw)
        self.n_window = int(round(window * fs))
        self.n_hop = max(1, int(round(hop * fs)))
        if hop > window:
            raise TactileInputError(f"--hop ({hop} s) must not exceed --window ({window} s)", source=src,
                                    code="bad_setting")
        self.nperseg = int(nperseg) if nperseg else default_nperseg(self.n_window)
        if self.n_window < 2 * self.nperseg or self.nperseg < 16:
            raise TactileInputError(f"a window of {window} s at {fs:g} Hz ({self.n_window} samples) is too short for "
                                    f"segments of {self.nperseg} samples", source=src, code="bad_setting")
        if sensor is None:
            self.depths, self.curvature_radius = (PAPER_SENSOR.d1, PAPER_SENSOR.d2), PAPER_SENSOR.curvature_radius
            self.sensor_name = SENSOR_DEFAULT
        elif hasattr(sensor, "d1"):
            self.depths, self.curvature_radius = (sensor.d1, sensor.d2), sensor.curvature_radius
            self.sensor_name = "given"
        else:
            self.depths = tuple(float(d) for d in sensor.depths)
            self.curvature_radius = getattr(sensor, "curvature_radius", None)
            self.sensor_name = str(getattr(sensor, "source", None) or getattr(sensor, "path", None) or "given")
        self.window_s, self.hop_s = self.n_window / fs, self.n_hop / fs
        self._settings = analysis_settings(options)
        self._choices = choices_of(options)
        self._gains = known_gains(options)
        self._buffer = np.zeros((4, 0))
        self._seen = 0                      # samples pushed
        self._next_end = self.n_window      # the next window ends at this sample
        self._held: _Held | None = None
        self._edge: float | None = None     # a slip's start (s) that the next analysis may straddle
        self._change: tuple | None = None   # a change of the slip the updates found: (search from, at most by), s
        self._located: float | None = None  # where ``change_point`` places it
        # samples kept before the window: the change-point search reaches back a window and more
        self.n_history = int(round((self.window_s + 2 * CHANGE_LOOKBACK) * fs))
        self._by_window: dict = {}
        self.rows: list[dict] = []

    # ------------------------------------------------------------------ the stream

    def push(self, samples) -> list[dict]:
        """Take a (4, n) block of samples (x1, x2, y1, y2); return the rows of the windows it completed."""
        x = np.asarray(samples, float)
        src = self.source or "<stream>"
        if x.ndim != 2 or x.shape[0] != 4:
            raise TactileInputError(f"a block must have shape (4, n) (x1, x2, y1, y2), got {x.shape}", source=src,
                                    code="bad_shape")
        if not np.all(np.isfinite(x)):
            raise TactileInputError(f"the block at sample {self._seen} holds NaN or inf samples", source=src,
                                    code="nonfinite")
        self._buffer = np.concatenate([self._buffer, x], axis=1)
        self._seen += x.shape[1]
        out = []
        while self._seen >= self._next_end:
            start = self._next_end - self.n_window                      # absolute sample index
            offset = start - (self._seen - self._buffer.shape[1])
            window = self._buffer[:, offset:offset + self.n_window]
            history = self._buffer[:, max(0, offset - self.n_history):offset + self.n_window]
            out.append(self._row(window, self.t0 + (start + 0.5 * self.n_window) / self.fs, history))
            self._next_end += self.n_hop
        keep = self._seen - (self._next_end - self.n_window - self.n_history)
        if keep < self._buffer.shape[1]:
            self._buffer = self._buffer[:, self._buffer.shape[1] - max(keep, 0):]
        self.rows.extend(out)
        return out

    # ------------------------------------------------------------------ one window

    def _record(self, window):
        if self.method == "multitaper":
            seg = segments(window, self.fs, method="multitaper", nw=self.nw, prewhiten=AR_ORDER, source=self.source)
        else:
            seg = segments(window, self.fs, nperseg=self.nperseg, prewhiten=AR_ORDER, source=self.source)
        return run._record(seg, self.depths, self._gains, self.options.velocity)

    def _row(self, window, t: float, history=None) -> dict:
        tic = time.perf_counter()
        rec = self._record(window)
        act = activity(window, self.nperseg)
        kind, moved = "none", None
        start_s = t - 0.5 * self.window_s
        end_s = t + 0.5 * self.window_s
        if act.verdict != "moving":
            self._edge = self._change = self._located = None
        if self._change is not None:
            # the change is placed again in each window, on the samples from a little before the first window whose
            # misfit rose to this window's end: the more of the new slip is in view, the better
            first, by = self._change
            hist = window if history is None else history
            since = max(first, end_s - hist.shape[-1] / self.fs)
            n_run = min(int(round((end_s - since) * self.fs)), hist.shape[-1])
            at, sharp = change_point(hist[:, hist.shape[-1] - n_run:], self.fs)
            if sharp >= CHANGE_SHARP:
                self._located = min(since + at, by)
            elif self._located is None:
                # the deep/shallow ratios did not change where the misfit rose (a texture's patch, or a change of
                # the slip too small to place): the window is analysed now, and again once it lies past the
                # middle of the first window whose misfit rose
                self._change = None
                self._edge = by - CHANGE_SEEN * self.window_s
            if self._located is not None and start_s >= self._located:
                self._change = self._located = None     # the window lies past the change: it is analysed
        if self._held is not None and self._held.recheck_at is not None and start_s >= self._held.recheck_at:
            self._held = None               # the window now lies past the start or change the analysis straddled
        if act.verdict == "still":
            self._held = None
            res = FitResult(status=Status.NO_SLIP, window=self._settings.window,
                            message=f"no slip: the probes hear no moving texture (low band "
                                    f"{float(np.max(act.excess_db)):.1f} dB over the noise floor at most, "
                                    f"{MOVING_DB:g} dB needed)")
        elif act.verdict == "start":
            # a window that is partly still holds two scenes: the full analysis waits for one that slips throughout
            self._held = None
            when = start_s + self._quiet_until(act)
            self._edge = when
            res = FitResult(status=Status.SLIP_START, window=self._settings.window,
                            message=f"a slip starts inside this window, after t = {when:.2f} s: estimates follow "
                                    "once a window lies inside the slip")
        elif act.verdict == "stop" and self._held is None:
            # a window in which the slip ends holds two scenes; with no fit to go on from, it gets no analysis
            res = FitResult(status=Status.SLIP_STOP, window=self._settings.window,
                            message="the slip ends inside this window: estimates follow once a window lies "
                                    "inside a slip")
        elif self._held is None and self._change is not None:
            # a window across the change holds two slips: an analysis of it would describe neither
            res = FitResult(status=Status.SLIP_CHANGE, window=self._settings.window,
                            message=f"the slip changes inside this window, near t = {self._located:.2f} s (the "
                                    "updates' misfit rose): estimates follow once a window lies past the change")
        elif self._held is None:
            n_bins, loc = _band_program()(rec, self._settings)
            if int(n_bins) < MIN_BINS:      # the analysis would say no_band: it is not run
                res = no_band_result(FitResult(window=self._settings.window), int(n_bins), np.asarray(loc.k0), rec.seg)
                self._edge = None
            else:
                res, kind = self._acquire(rec, start_s), "analysis"
        else:
            res, kind, moved = self._step(rec, t)
        if act.verdict == "stop" and kind == "step":
            res.status = Status.SLIP_STOP
            res.message = "; ".join(m for m in ("the slip ends inside this window: its values mix the slip and the "
                                                "still part", res.message) if m)
        res.sensor = self.sensor_name
        res.curvature_radius = self.curvature_radius
        row = res.to_record()
        row.update(file=self.source, t=round(t, 9), window_s=self.window_s, update=kind,
                   moved=None if moved is None or not np.isfinite(moved) else float(moved),
                   compute_s=time.perf_counter() - tic)
        if self.sensor_name == SENSOR_DEFAULT:
            row["message"] = "; ".join(m for m in (row.get("message"), "the paper's sensor assumed (no sensor file)")
                                       if m)
        return row

    def _quiet_until(self, act: Activity) -> float:
        """Seconds from the window's start to the end of its last still segment before the first moving one."""
        first = int(np.argmax(act.moving))
        step = self.nperseg // 2
        return ((first - 1) * step + self.nperseg) / self.fs if first > 0 else 0.0

    def _acquire(self, rec, start_s: float) -> FitResult:
        """The full analysis of one window: its choices are held by the updates that follow."""
        groups = int(np.count_nonzero(np.asarray(rec.seg.count)))
        a = run.analyse_one(rec, self._settings, self._choices._replace(direction_keep=direction_keep(groups)))
        s = summary_of(a)
        res = result_of(a, rec, self.options, curvature_radius=self.curvature_radius)     # fit's and batch's row
        limit = float(step_mod.poor_fit_limit(float(s.n_data), float(rec.seg.bin_factor)))
        if res.status == Status.POOR_FIT and res.redchi is not None and res.redchi <= limit:
            res.status = Status.OK          # within the noise of the window's few independent residuals
            res.message = "; ".join(m for m in res.message.split("; ") if not m.startswith("poor fit:"))
        if res.status in (Status.OK, Status.POOR_FIT, Status.NOT_CONVERGED):
            window = WINDOWS[int(a.window)]
            settings = self._window_settings(window)
            state = _state_program()(run._as_jnp(rec), settings, s.theta, s.free, s.data.log_k_knots,
                                     s.data.prior_center, s.data.lump_sd)
            # an analysis whose window may reach across the slip's start or a change (its choices then describe
            # neither side: a minor speed of the start's transient held oblique for seconds) is done again once
            # the window lies past it
            edge = self._edge if self._edge is not None and self._edge > start_s else None
            self._held = _Held(state, settings, window, texture_name(s.free), DIRECTIONS[int(a.direction)],
                               [float(s.redchi)], recheck_at=edge)
            _widened(res, *self._held.widen(start_s + self.window_s, res, self.window_s))
        self._edge = None
        return res

    def _window_settings(self, window: str):
        """The update program's settings for ``window``, made once: new arrays would cost the first call after
        each analysis 70 ms more (measured)."""
        if window not in self._by_window:
            settings = settings_of(self.options, window=window)
            if window == "hertz":
                settings = settings._replace(hertz=self._settings.hertz)
            self._by_window[window] = run._as_jnp(settings)
        return self._by_window[window]

    def _step(self, rec, t: float):
        held = self._held
        u = _update_program()(rec, held.settings, held.state, False)
        held.state = u.state
        e = u.errors
        s = step_summary(u)
        moved = float(u.moved)
        res = result_from_summary(s, velocity=self.options.velocity, curvature_radius=self.curvature_radius,
                                  model=model_name(s.free, self.options.velocity is not None), segments=rec.seg)
        res.window, res.texture, res.direction = held.window, held.texture, held.direction
        _widened(res, *held.widen(t + 0.5 * self.window_s, res, self.window_s))
        poor = res.status == Status.POOR_FIT
        if poor and bool(s.lumpy):
            # a steady misfit with no trend across frequency: a 2 s window hears few texture modes, every taper the
            # same ones. The speeds are the smooth model's with errors from that scatter, which hold them (on
            # benchmarks/track.py's constant slips all such windows were within 3 sigma of the truth): ok, said so
            res.status = Status.OK
            res.message = "; ".join([f"lumpy texture: the spectra scatter {res.redchi:.1f}x their noise from bin to "
                                     "bin with no trend across frequency (the window hears few texture modes); the "
                                     "errors come from that scatter"]
                                    + [m for m in res.message.split("; ") if m and not m.startswith("poor fit")])
        if res.status == Status.NOT_CONVERGED:           # the program's status: the step did not settle
            notes = [m for m in res.message.split("; ") if m and not m.startswith("the solver did not converge")]
            res.message = "; ".join([f"the update moved a parameter by {moved:.1f} sigma: not settled (the slip is "
                                     "changing, or the choices held no longer describe it)"] + notes)
        # updates in a row that do not settle, or whose misfit rose well above the level the held choices have
        # had: those choices may no longer describe the slip. A steady misfit (a lumpy window: all its tapers
        # hear the same few texture modes) is no reason to re-analyse: a full analysis misfits it alike.
        # Re-analysing after any three poor updates gave as many right updates on benchmarks/track.py (118 of
        # the paths' 190 windows inside a piece, as this rule with the analyses done again past a change; 38 %
        # of the constant slips' windows, against 40 %) at 2.6 times the cost of a 30 s file end to end
        redchi = float(e.redchi)
        rose = poor and misfit_rose(redchi, held.redchi)
        held.bad = held.bad + 1 if (res.status == Status.NOT_CONVERGED or rose) else 0
        if held.bad == 1:
            held.bad_since = t + 0.5 * self.window_s
        if np.isfinite(redchi):
            held.redchi = (held.redchi + [redchi])[-MISFIT_MEMORY:]
        if held.bad >= REACQUIRE_AFTER or res.status in (Status.NO_BAND, Status.FAILED):
            self._held = None               # a window past the change (or the next one) is analysed in full
            # the change lies inside the first window whose misfit rose: after its start, before its end
            self._change = ((held.bad_since - self.window_s - CHANGE_LOOKBACK, held.bad_since)
                            if held.bad >= REACQUIRE_AFTER else None)
        return res, "step", moved


def _widened(res: FitResult, factors, measured) -> None:
    """Widen ``res``'s errors of vx, vy and a by ``factors`` (``_Held.widen``); its message says by how much, and
    why."""
    said = {True: [], False: []}
    for name, f, m in zip(WIDEN_QUANTITIES, factors, measured):
        if f > 1.0 and res[name].err:
            res.set(name, err=res[name].err * f)
            said[bool(m)].append(f"{name} {f:.2f}x")
    if said[True] or said[False]:
        update_contact_depth(res)
    notes = [res.message]
    if said[True]:
        notes.append(f"errors widened ({', '.join(said[True])}): windows that share no sample scatter that much more "
                     "than their errors (each hears another patch of the texture)")
    if said[False]:
        notes.append(f"errors widened ({', '.join(said[False])}) until windows that share no sample can be compared: "
                     "each window hears another patch of the texture, which its own errors do not see")
    res.message = "; ".join(m for m in notes if m)


def track_recording(rec, *, window: float = WINDOW_S, hop: float = HOP_S, options: FitOptions = FitOptions(),
                    method: str = "multitaper", nperseg: int | None = None, record: int = 0,
                    progress=None) -> list[dict]:
    """The rows of a ``Tracker`` run over one record of a recording (``io.recording.Recording``), fed a second
    of samples at a time as a stream would feed it. progress: called with (samples done, samples in all)."""
    from ..io.recording import validate_recording
    from ..model.sensor import Sensor

    validate_recording(rec)
    one = rec.record(record)
    d1, d2 = (float(d) for d in one.depths)
    radius = one.curvature_radius if one.curvature_radius else PAPER_SENSOR.curvature_radius
    tracker = Tracker(one.fs, Sensor(d1, d2, radius), window=window, hop=hop, options=options, method=method,
                      nperseg=nperseg, source=one.source)
    tracker.sensor_name = getattr(one, "sensor", None) or SENSOR_FROM_FILE
    n = one.n_samples
    if n < tracker.n_window:
        raise TactileInputError(f"the recording holds {n / one.fs:.3g} s, less than one window of "
                                f"{tracker.window_s:.3g} s", source=one.source or "<recording>", code="too_short")
    block = max(1, int(round(one.fs)))
    for i in range(0, n, block):
        tracker.push(one.signals[:, i:i + block])
        if progress is not None:
            progress(min(i + block, n), n)
    return tracker.rows
