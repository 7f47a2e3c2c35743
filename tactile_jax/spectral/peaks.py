"""Coherent texture lines of each probe pair, from spectra that are NOT prewhitened (numpy).

A texture mode of wavevector k = (kx, ky) sliding at v rings every probe at the
single frequency omega = |k . v|: a pure tone, narrower than one Welch bin. An
AR prewhitening filter notches such a tone and destroys its coherence, so the
line model reads the raw Welch spectra (``line_spectra``: ``segments`` with
``prewhiten=0`` and ``band.spectra``).

``detect_lines`` finds candidate lines as local maxima of a pair's shallow PSD
standing ``min_db`` above a running median background, merges the candidates
of the two pairs that fall within one bin of each other (one mode), and then
measures every channel at each mode over the Hann main lobe (+/- ``LOBE`` bins
around the peak):

- per pair (x: x1 -> x2, y: y1 -> y2): the H1 log amplitude ratio
  log|sum S12| - log sum S11, its Bendat-Piersol error sqrt((1 - g2) / (2 K g2))
  from the main lobe's coherence g2 and the effective number of segments K
  (``dof``), and the shallow and deep levels in dB above their backgrounds. A pair
  *hears* the mode when its shallow level passes ``weak_db`` with a peak within
  one bin of the mode, its deep level passes ``deep_db`` and the lobe
  coherence passes ``min_coherence``.
- across the pairs: the shallow level ratio log|y1 / x1| (H1 from the stronger
  shallow probe to the weaker: log|sum S_x1y1| - log sum S_ref), its error from
  the x1-y1 lobe coherence, where both shallow probes stand above their
  backgrounds (the deep probes need not hear it).

The frequency is refined to a fraction of a bin by the Hann two-bin amplitude
ratio (Grandke 1983): with the peak bin's amplitude A0 and its larger neighbour's
A1, the offset is (2 A1 - A0) / (A0 + A1) bins towards that neighbour.

Lines whose deep probes hear nothing coherent (the shallow PSD rises above the
background but the pair's coherence or deep level fails) are counted in
``Lines.shallow_only`` with the strongest one's frequency and level: a texture
too fine for the deep probes (``no_band``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["LOBE", "SUM", "ISO", "Lines", "line_spectra", "detect_lines", "find_lines", "hann_offset"]

#: half-width of the Hann main lobe, bins (a candidate is the highest bin within +/- LOBE)
LOBE = 2
#: half-width of the main-lobe sums, bins: +/- 1 bin holds 98-100 % of a Hann tone's power and, for a weak
#: line, a better signal-to-noise ratio than the whole lobe
SUM = 1
#: noise-power correlations of Hann (Welch) estimates 1 and 2 bins apart, (2/3)^2 and (1/6)^2: a sum of
#: 2 SUM + 1 adjacent bins averages LOBE_DOF_GAIN times more independent noise than one bin
_HANN_RHO = (1.0, 4.0 / 9.0, 1.0 / 36.0)
LOBE_DOF_GAIN = (2 * SUM + 1) ** 2 / sum(_HANN_RHO[abs(i - j)] for i in range(2 * SUM + 1) for j in range(2 * SUM + 1))
#: floor of the interpolated frequency's error, bins
OMEGA_FLOOR = 0.002
#: false-alarm probability of the coherence test for one bin of noise
COHERENCE_ALPHA = 1e-4
#: distance (bins) of the isolation test's bins from a peak
ISO = 3


class Lines(NamedTuple):
    """Coherent lines (modes) found in one record's spectra, sorted by frequency (numpy arrays).

    omega: (L,) rad/s, interpolated to a fraction of a bin; omega_err: (L,) its one-sigma error, rad/s
    (``OMEGA_FLOOR`` bins and the noise's share, 1 / sqrt(K snr) bins at the peak's snr). peak: (L,) int, the bin of the mode's
    peak in its stronger pair. heard: (2, L) bool, the x pair (row 0) and the y pair (row 1) hear
    the mode coherently in both probes. log_ratio, log_ratio_err: (2, L) each pair's H1 log
    amplitude ratio deep/shallow (natural log) and its one-sigma error (NaN where not heard).
    coherence: (2, L) each pair's main-lobe magnitude-squared coherence. shallow_db, deep_db:
    (2, L) each probe's peak PSD in dB above its running-median background (at the mode's bin).
    cross_log, cross_err: (L,) log|y1 / x1| of the shallow probes' amplitudes and its one-sigma
    error (NaN where not measured). cross_coherence: (L,) the x1-y1 main-lobe coherence.
    d_omega: bin width, rad/s. dof: effective number of segments K. n_truncated: candidates left
    out beyond ``max_lines`` per pair. shallow_only: (2,) per pair, lines of the shallow PSD that the
    deep probe does not hear coherently; shallow_only_omega, shallow_only_db: (2,) the strongest
    such line's frequency (rad/s) and shallow level (dB), NaN where none. shallow_power: (2, L) the
    main-lobe power of each pair's shallow probe (x1, y1) at the mode, the PSD summed over +/- ``SUM``
    bins times the bin width (a tone's power, signal units squared; None where not measured, as in
    ``Lines`` built by hand): unlike the levels in dB it does not depend on the noise background.
    """

    omega: np.ndarray
    omega_err: np.ndarray
    peak: np.ndarray
    heard: np.ndarray
    log_ratio: np.ndarray
    log_ratio_err: np.ndarray
    coherence: np.ndarray
    shallow_db: np.ndarray
    deep_db: np.ndarray
    cross_log: np.ndarray
    cross_err: np.ndarray
    cross_coherence: np.ndarray
    d_omega: float
    dof: float
    n_truncated: int
    shallow_only: np.ndarray
    shallow_only_omega: np.ndarray
    shallow_only_db: np.ndarray
    shallow_power: np.ndarray | None = None

    @property
    def n(self) -> int:
        """Number of modes."""
        return int(self.omega.size)


class _Spec(NamedTuple):
    psd: np.ndarray
    csd: np.ndarray
    xy: np.ndarray
    omega: np.ndarray
    n_valid: int
    dof: float


def line_spectra(signals, fs: float, *, nperseg: int | None = None, source: str | None = None):
    """Raw (un-prewhitened) Welch spectra of ``signals`` (4, N), ``fs`` in Hz: a ``band.Spectra`` of numpy arrays.

    nperseg: samples per Hann segment (default ``estimate.default_nperseg(N)``: 1024 for 16 s at 1 kHz,
    0.98 Hz bins). Raises ``TactileInputError`` for settings the record cannot meet.
    """
    from .band import Spectra
    from .segments import segments

    seg = segments(signals, fs, method="welch", nperseg=nperseg, prewhiten=0, source=source)
    total = max(float(np.sum(seg.count)), 1.0)
    m = seg.auto.shape[-1]
    omega = float(seg.d_omega) * np.arange(m)
    return Spectra(seg.auto.sum(0) / total, seg.csd.sum(0) / total, seg.xy.sum(0) / total, omega,
                   np.arange(m) < int(seg.n_valid), np.asarray(float(seg.dof)))


def hann_offset(a0, a_left, a_right):
    """Offset (bins, in [-0.5, 0.5]) of a tone from its peak bin, from the amplitudes (not powers) of
    the peak bin ``a0`` and its neighbours: Grandke's two-bin ratio for the Hann window."""
    a0, a_left, a_right = (np.asarray(v, float) for v in (a0, a_left, a_right))
    right = a_right >= a_left
    a1 = np.where(right, a_right, a_left)
    d = np.clip((2.0 * a1 - a0) / np.maximum(a0 + a1, 1e-300), 0.0, 0.5)
    return np.where(right, d, -d)


def _as_numpy(spec) -> _Spec:
    psd = np.asarray(spec.psd, float)
    n_valid = int(np.sum(np.asarray(spec.valid))) if getattr(spec, "valid", None) is not None else psd.shape[-1]
    return _Spec(psd, np.asarray(spec.csd, complex), np.asarray(spec.xy, complex), np.asarray(spec.omega, float),
                 n_valid, float(np.asarray(spec.dof)))


def _lobe_sum(v, idx):
    """sum of v (..., M) over idx - SUM .. idx + SUM: (..., len(idx))."""
    offs = np.arange(-SUM, SUM + 1)
    return np.take(v, idx[:, None] + offs[None, :], axis=-1).sum(-1)


def _bp_err(g2, dof):
    g2 = np.clip(g2, 1e-12, 1.0)
    return np.sqrt((1.0 - g2) / (2.0 * dof * g2))


def _candidates(s, bg, lo, hi, min_db, iso_db):
    """Bins of isolated local maxima of ``s`` in [lo, hi): the highest within +/- LOBE bins, ``min_db``
    above ``bg`` and ``iso_db`` above both bins ISO bins away (an isolated Hann tone is 31 dB above them;
    a peak in a forest of unresolved lines is not)."""
    m = s.size
    i = np.arange(lo, hi)
    if i.size == 0:
        return i
    win = np.lib.stride_tricks.sliding_window_view(np.pad(s, LOBE, mode="edge"), 2 * LOBE + 1)[i]
    is_max = (s[i] >= win.max(-1)) & (s[i] > s[np.clip(i - 1, 0, m - 1)])       # ties: the first
    side = np.maximum(s[np.clip(i - ISO, 0, m - 1)], s[np.clip(i + ISO, 0, m - 1)])
    return i[is_max & (s[i] > bg[i] * 10.0 ** (min_db / 10.0)) & (s[i] > side * 10.0 ** (iso_db / 10.0))]


def _background(psd, half_width, quantile):
    """Running ``quantile`` of ``psd`` (..., M) over +/- ``half_width`` bins: the noise under the lines."""
    pad = np.pad(psd, [(0, 0)] * (psd.ndim - 1) + [(half_width, half_width)], mode="reflect")
    win = np.lib.stride_tricks.sliding_window_view(pad, 2 * half_width + 1, axis=-1)
    return np.maximum(np.quantile(win, quantile, axis=-1), np.finfo(float).tiny)


def detect_lines(spec, *, max_lines: int = 64, min_db: float = 20.0, iso_db: float = 20.0, weak_db: float = 10.0,
                 deep_db: float = 6.0, min_coherence: float = 0.5, cross_db: float = 10.0,
                 min_cross_coherence: float = 0.5, background_bins: int = 64, background_quantile: float = 0.25,
                 first_bin: int = 3) -> Lines:
    """The coherent lines of ``spec`` (a ``band.Spectra``, numpy or jnp; NOT prewhitened): see the module.

    max_lines: candidates kept per pair (the strongest shallow peaks). min_db: a candidate's shallow peak
    above the background, the running ``background_quantile`` over +/- ``background_bins`` (dB). iso_db:
    the peak above the bins ``ISO`` bins away on both sides (dB; unresolved lines fail). weak_db, deep_db,
    min_coherence: what a pair needs to hear a mode (shallow and deep levels in dB above background with
    the same isolation, main-lobe coherence). cross_db, min_cross_coherence: both shallow probes' levels
    and their x1-y1 main-lobe coherence for the cross-pair level ratio. first_bin: lowest peak bin
    considered (the lowest bins mix a line with its image at -omega and the DC). Pure function.
    """
    s = _as_numpy(spec)
    psd, m = s.psd, s.n_valid
    d_omega = float(s.omega[1] - s.omega[0])
    bg = _background(psd[:, :m], background_bins, background_quantile)
    lo, hi = max(first_bin, LOBE, ISO), m - max(LOBE, ISO) - 1
    # the coherence a pair needs: min_coherence, and above what noise reaches with probability COHERENCE_ALPHA
    g2_min = max(min_coherence, 1.0 - COHERENCE_ALPHA ** (1.0 / max(s.dof - 1.0, 1e-3)))
    # candidates: per pair, the strongest max_lines shallow peaks
    cands, n_trunc = [], 0
    for p in range(2):
        c = _candidates(psd[2 * p, :m], bg[2 * p], lo, hi, min_db, iso_db)
        if c.size > max_lines:
            n_trunc += c.size - max_lines
            c = c[np.argsort(-psd[2 * p, c] / bg[2 * p, c])[:max_lines]]
        cands.append(np.sort(c))
    # merge the pairs' candidates within one bin: one mode at the stronger one's peak
    allc = sorted([(int(i), p) for p in range(2) for i in cands[p]], key=lambda t: t[0])
    modes: list[int] = []
    for i, p in allc:
        if modes and abs(i - modes[-1]) <= 1:
            j = modes[-1]
            if psd[2 * p, i] / bg[2 * p, i] > max(psd[0, j] / bg[0, j], psd[2, j] / bg[2, j]):
                modes[-1] = i
            continue
        modes.append(i)
    idx = np.asarray(modes, int)
    n = idx.size
    # each probe's level at the mode: its highest bin within one bin, in dB above its background; the
    # shallow probes' own peak there, isolated (else their lobe holds another line's leakage)
    near = np.stack([psd[:, idx + o] for o in (-1, 0, 1)]).max(0) if n else np.zeros((4, 0))
    db = 10.0 * np.log10(near / bg[:, idx]) if n else np.zeros((4, 0))
    power = np.stack([_lobe_sum(psd[0], idx), _lobe_sum(psd[2], idx)]) * d_omega if n else np.zeros((2, 0))
    own = np.zeros((2, n), bool)
    for p in range(2):
        if n:
            ch = psd[2 * p]
            own[p] = ((near[2 * p] >= np.maximum(ch[idx - 2], ch[idx + 2]))
                      & (near[2 * p] > np.maximum(ch[idx - ISO], ch[idx + ISO]) * 10.0 ** (iso_db / 10.0)))
    # each pair at the mode's bin: lobe sums, coherence, heard
    heard = np.zeros((2, n), bool)
    log_ratio = np.full((2, n), np.nan)
    err = np.full((2, n), np.nan)
    coh = np.zeros((2, n))
    shallow_only = np.zeros(2, int)
    so_omega, so_db = np.full(2, np.nan), np.full(2, np.nan)
    for p in range(2):
        if not n:
            continue
        s11, s22 = _lobe_sum(psd[2 * p], idx), _lobe_sum(psd[2 * p + 1], idx)
        s12 = np.abs(_lobe_sum(s.csd[p], idx))
        g2 = np.where((s11 > 0) & (s22 > 0), s12 ** 2 / np.maximum(s11 * s22, 1e-300), 0.0)
        coh[p] = g2
        shallow = (db[2 * p] >= weak_db) & own[p]
        h = shallow & (db[2 * p + 1] >= deep_db) & (g2 >= g2_min)
        heard[p] = h
        log_ratio[p] = np.where(h, np.log(np.maximum(s12, 1e-300)) - np.log(np.maximum(s11, 1e-300)), np.nan)
        err[p] = np.where(h, _bp_err(g2, s.dof * LOBE_DOF_GAIN), np.nan)
        so = shallow & ~h & (db[2 * p] >= min_db)
        shallow_only[p] = int(so.sum())
        if so.any():
            k = int(np.argmax(np.where(so, db[2 * p], -np.inf)))
            so_omega[p], so_db[p] = s.omega[idx[k]], db[2 * p, k]
    # the cross-pair shallow level ratio log|y1 / x1|, H1 from the stronger shallow probe
    cross_log, cross_err, cross_coh = np.full(n, np.nan), np.full(n, np.nan), np.zeros(n)
    if n:
        sx, sy = _lobe_sum(psd[0], idx), _lobe_sum(psd[2], idx)
        sxy = np.abs(_lobe_sum(s.xy[0], idx))
        g2c = np.where((sx > 0) & (sy > 0), sxy ** 2 / np.maximum(sx * sy, 1e-300), 0.0)
        cross_coh = g2c
        ok = (db[0] >= cross_db) & (db[2] >= cross_db) & own[0] & own[1] & (g2c >= max(min_cross_coherence, g2_min))
        x_ref = sx / bg[0, idx] >= sy / bg[2, idx]
        lc = np.where(x_ref, np.log(np.maximum(sxy, 1e-300)) - np.log(np.maximum(sx, 1e-300)),
                      np.log(np.maximum(sy, 1e-300)) - np.log(np.maximum(sxy, 1e-300)))
        cross_log = np.where(ok, lc, np.nan)
        cross_err = np.where(ok, _bp_err(g2c, s.dof * LOBE_DOF_GAIN), np.nan)
    # two pairs hearing a "mode" whose shallow probes are not coherent with each other hear two different
    # modes in one bin: split it into two single-pair modes (each its own frequency)
    split = heard[0] & heard[1] & (cross_coh < max(min_cross_coherence, g2_min))
    strong = np.where(db[0] >= db[2], 0, 1)
    pair_of = np.concatenate([np.full(n, -1), np.where(strong[split] == 0, 1, 0)])     # -1: both pairs
    rows = np.concatenate([np.arange(n), np.flatnonzero(split)])
    heard = heard[:, rows]
    for p in range(2):
        heard[p, :n] &= ~(split & (strong != p))
        heard[p, n:] &= pair_of[n:] == p
    idx_r = idx[rows]
    log_ratio, err = np.where(heard, log_ratio[:, rows], np.nan), np.where(heard, err[:, rows], np.nan)
    coh, db, power = coh[:, rows], db[:, rows], power[:, rows]
    cross_log, cross_err, cross_coh = cross_log[rows], cross_err[rows], cross_coh[rows]
    # frequency to a fraction of a bin, from the shallow amplitudes of the stronger pair (of the pair that hears it)
    if rows.size:
        ref = np.where(pair_of >= 0, 2 * np.maximum(pair_of, 0), np.where(db[0] >= db[2], 0, 2))
        amp = np.sqrt(psd[ref[None, :], idx_r[None, :] + np.arange(-1, 2)[:, None]])
        omega = (idx_r + hann_offset(amp[1], amp[0], amp[2])) * d_omega
        snr = 10.0 ** (np.take_along_axis(db, ref[None, :], 0)[0] / 10.0)
        omega_err = d_omega * np.sqrt(OMEGA_FLOOR ** 2 + 1.0 / (s.dof * snr))
    else:
        omega = omega_err = np.zeros(0)
    keep = heard.any(0) | np.isfinite(cross_log)
    sel = np.flatnonzero(keep)
    sel = sel[np.argsort(omega[sel], kind="stable")]
    return Lines(omega[sel], omega_err[sel], idx_r[sel], heard[:, sel], log_ratio[:, sel], err[:, sel],
                 coh[:, sel], db[0::2][:, sel], db[1::2][:, sel], cross_log[sel], cross_err[sel], cross_coh[sel],
                 d_omega, float(s.dof), int(n_trunc), shallow_only, so_omega, so_db, power[:, sel])


def _information(lines: Lines) -> tuple:
    """(modes measured twice or more, modes heard, -nperseg rank) for choosing a segment length."""
    n_meas = lines.heard.sum(0) + np.isfinite(lines.cross_log)
    return int(np.sum(n_meas >= 2)), int(lines.heard.any(0).sum())


def find_lines(signals, fs: float, *, nperseg: int | None = None, max_factor: int = 4, source: str | None = None,
               **detect_kw) -> Lines:
    """The lines of a recording ``signals`` (4, N) sampled at ``fs`` Hz: ``detect_lines`` on ``line_spectra``.

    nperseg: samples per Hann segment; None: the default (``default_nperseg(N)``) and segments 2, 4, ...
    ``max_factor`` times longer, at most N / 3 samples (5 or more segments), whose 512-bin grid still
    reaches 1.2 x the highest shallow line of the default: the one with the most modes measured at least
    twice (a pair's ratio or the cross-pair level), then the most modes heard, then the shorter. Longer
    segments resolve lines closer together and lines near DC; shorter ones average more segments.
    ``detect_kw``: ``detect_lines``'s settings. Raises ``TactileInputError`` for settings the record cannot meet.
    """
    from .estimate import default_nperseg
    from .segments import N_BINS

    x = np.asarray(signals, float)
    if nperseg is not None:
        return detect_lines(line_spectra(x, fs, nperseg=nperseg, source=source), **detect_kw)
    n = x.shape[-1]
    base = default_nperseg(n)
    first = detect_lines(line_spectra(x, fs, nperseg=base, source=source), **detect_kw)
    top = max([float(np.max(first.omega, initial=0.0))]
              + [float(w) for w in first.shallow_only_omega if np.isfinite(w)])
    best, best_key = first, _information(first) + (0,)
    f = 2
    while f <= max_factor and base * f <= n // 3:
        seg_len = base * f
        if (N_BINS - 1) * 2.0 * np.pi * fs / seg_len < 1.2 * top:
            break
        cand = detect_lines(line_spectra(x, fs, nperseg=seg_len, source=source), **detect_kw)
        key = _information(cand) + (-f,)
        if key > best_key:
            best, best_key = cand, key
        f *= 2
    return best
