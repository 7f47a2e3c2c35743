"""Probe signals to grouped periodogram products on a fixed grid: the pipeline's only variable-shape step.

Every later stage of the joint pipeline (``band``, ``core``) is compiled for
ONE shape, whatever the recording's length, segment length or estimator: the
spectra arrive here as (G, ..., M) sums of periodogram products over G groups
of consecutive segments (or tapers), on the first M bins of the estimate,
with zero groups and zero bins as padding. The full spectra are the sum over
the groups; the jackknife leaves one group out. With at most G segments each
group is one segment (the delete-one-segment jackknife); with more, a
delete-one-group jackknife over G groups of adjacent segments. ``to_spectra``
and ``from_spectra`` carry a ``Segments`` through a spectra file and back.

numpy, no compilation: Burg prewhitening, Welch segments or DPSS tapers, FFT.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np

from ..errors import TactileInputError
from .estimate import (
    _onesided_factor as _onesided,
    adjacent_bin_factor,
    bin_rho,
    cached_window,
    dpss_tapers,
    spectral_kernel,
    welch_dof,
    default_nperseg,
)

__all__ = ["N_GROUPS", "N_BINS", "KERNEL_OFFSETS", "AR_ORDER", "Segments", "segments", "burg_ar",
           "min_nperseg", "check_nperseg", "to_spectra", "from_spectra"]

#: groups of segments (the jackknife's leave-one-out units)
N_GROUPS = 32
#: bins of the fixed grid (DC first); an estimate with more bins is cut above, with fewer padded
N_BINS = 512
#: offsets (bins) of the spectral-window kernel's fixed support
KERNEL_OFFSETS = np.arange(-6.0, 6.25, 0.5)
#: order of the AR prewhitening filters' fixed slot (a lower order is zero-padded)
AR_ORDER = 8


class Segments(NamedTuple):
    """One record's grouped periodogram products (arrays; a leading batch axis under ``vmap``).

    auto: (G, 4, M) summed |X_c|^2 of (x1, x2, y1, y2), PSD units (units^2/Hz) times segments.
    csd: (G, 2, M) complex summed conj(X1) X2 of the x and y pairs. xy: (G, 4, M) complex summed
    conj(X_i) Y_j in the order (x1 y1, x1 y2, x2 y1, x2 y2). All divided by the prewhitening
    filters' response at the bin (|A|^2; conj(A_x) A_y for xy): spectra of the signals themselves.
    count: (G,) segments in each group (0: padding). d_omega: bin width, rad/s. n_valid: bins of
    the estimate on the grid. dof: effective number of independent segments (Welch 1967).
    overlap: segments / dof. bin_factor: variance inflation of a sum over adjacent bins.
    kernel: (J,) the spectral window's weights at ``KERNEL_OFFSETS`` (sum 1). whitening: (2, p + 1)
    AR error filters of the pairs ([1, 0, ...]: none). fs: Hz. nperseg: samples per segment
    (the record length for multitaper).
    """

    auto: np.ndarray
    csd: np.ndarray
    xy: np.ndarray
    count: np.ndarray
    d_omega: np.ndarray
    n_valid: np.ndarray
    dof: np.ndarray
    overlap: np.ndarray
    bin_factor: np.ndarray
    kernel: np.ndarray
    whitening: np.ndarray
    fs: np.ndarray
    nperseg: np.ndarray


def burg_ar(x: np.ndarray, order: int) -> np.ndarray:
    """Burg estimate of the AR error filter [1, a1, ..., ap] of ``x`` (N,); a silent channel gives [1, 0, ...].

    The numpy form of ``prewhiten.burg_ar``: run eagerly, the jnp one compiles its operations again for
    every new recording length, which this stage must not."""
    x = np.asarray(x, float) - np.mean(x)
    ef, eb = x.copy(), x.copy()
    a = np.ones(1)
    # the sums by einsum, not BLAS: a threaded BLAS splits a long dot product over its threads, so that the same
    # samples gave other rounding in a process with one BLAS thread (a batch's workers) than in one with several
    dot = lambda u, v: float(np.einsum("i,i->", u, v))      # noqa: E731
    for _ in range(order):
        f, b = ef[1:], eb[:-1]
        den = dot(f, f) + dot(b, b)
        k = -2.0 * dot(f, b) / den if den > 0 else 0.0
        ef, eb = f + k * b, b + k * f
        a = np.concatenate([a, [0.0]])
        a = a + k * a[::-1]
    return a


def _response(coeffs, omega, fs):
    """A(exp(i omega / fs)) of filters (..., p + 1) at omega (M,): (..., M) complex (numpy
    ``prewhiten.filter_response``, for the same reason as ``burg_ar``)."""
    k = np.arange(coeffs.shape[-1])
    return coeffs @ np.exp(-1j * np.outer(k, omega / fs))


def _groups(n_seg: int) -> tuple[np.ndarray, np.ndarray]:
    """Each of ``n_seg`` consecutive segments' group (at most ``N_GROUPS``), and the segments in each group."""
    group = np.minimum(np.arange(n_seg) * N_GROUPS // n_seg, N_GROUPS - 1)
    return group, np.bincount(group, minlength=N_GROUPS).astype(float)


def min_nperseg() -> int:
    """The shortest Welch segment (samples) that can give a band: 2 (``band.MIN_BINS`` + 1) = 14.

    A segment of n samples has n // 2 + 1 bins, and ``band.select`` never uses DC or the top bin,
    which leaves n // 2 - 1; a slip along one axis puts the whole band in one pair, and a fit
    takes at least ``band.MIN_BINS`` usable bins (fewer is ``no_band``)."""
    from .band import MIN_BINS

    return 2 * (MIN_BINS + 1)


def check_nperseg(nperseg, n_samples: int, *, source: str | None = None) -> int:
    """``nperseg`` as an int, or ``TactileInputError`` (code ``bad_setting``) naming ``source`` when it is
    not an integer, shorter than ``min_nperseg()`` or longer than the ``n_samples`` it is cut from.

    The one check of a Welch segment for ``fit``, ``batch`` and ``spectra`` (all build ``segments``)."""
    shortest = min_nperseg()
    if (isinstance(nperseg, bool) or not isinstance(nperseg, (int, float, np.integer, np.floating))
            or not float(nperseg).is_integer()):
        raise TactileInputError(f"nperseg must be a whole number of samples, got {nperseg!r}", source=source,
                                code="bad_setting")
    nperseg = int(nperseg)
    if nperseg < shortest:
        raise TactileInputError(f"nperseg={nperseg} is too short to give a band: a Welch segment needs at least "
                                f"{shortest} samples ({shortest // 2 - 1} bins besides DC and the top bin)",
                                source=source, code="bad_setting")
    if nperseg > n_samples:
        raise TactileInputError(f"nperseg={nperseg} does not fit a recording of {n_samples} samples", source=source,
                                code="bad_setting")
    return nperseg


@functools.lru_cache(maxsize=32)
def _estimator(method: str, nperseg: int, n_samples: int, nw: float, n_tapers: int):
    """Tapers (T, n), step, number of segments, dof, bin factor and the kernel on ``KERNEL_OFFSETS``."""
    if method == "welch":
        w = cached_window("hann", nperseg)
        step = nperseg - nperseg // 2
        n_seg = (n_samples - nperseg) // step + 1
        tapers, dof = w[None, :], welch_dof(w, step, n_seg)
        nfft, reach = nperseg, 3.0
    else:
        tapers = dpss_tapers(n_samples, nw, n_tapers)
        step, n_seg, dof, nfft = 0, n_tapers, float(n_tapers), n_samples
        reach = min(math.ceil(nw) + 1.0, float(KERNEL_OFFSETS[-1]))
    # the support ``spectra.estimate_spectra`` gives its kernel: a spectra file written from it fits the same
    offsets, weights = spectral_kernel(tapers, nfft, reach)
    kernel = np.interp(KERNEL_OFFSETS, offsets, weights, left=0.0, right=0.0)
    return tapers, step, n_seg, float(dof), adjacent_bin_factor(bin_rho(tapers, nfft)), kernel / kernel.sum()


def segments(signals, fs: float, *, method: str = "welch", nperseg: int | None = None, prewhiten: int | None = 8,
             nw: float = 4.0, n_tapers: int | None = None, source: str | None = None) -> Segments:
    """``Segments`` of one record ``signals`` (4, N) sampled at ``fs`` Hz.

    method: "welch" (Hann, half overlap, each segment's mean removed; ``nperseg`` samples,
    default ``spectra.default_nperseg(N)``) or "multitaper" (DPSS, ``nw``, ``n_tapers``).
    prewhiten: order of the Burg AR filter of each pair's shallow probe applied to both of its
    probes before averaging and divided out after (None or 0: off; at most ``AR_ORDER``).
    Raises ``TactileInputError`` for settings the record cannot meet.
    """
    x = np.asarray(signals, float)
    n = x.shape[-1]
    p = int(prewhiten or 0)
    if method not in ("welch", "multitaper"):
        raise TactileInputError(f"unknown spectral method {method!r}; expected 'welch' or 'multitaper'",
                                source=source, code="bad_setting")
    if not 0 <= p <= AR_ORDER:
        raise TactileInputError(f"prewhiten must be 0..{AR_ORDER}, got {prewhiten!r}", source=source,
                                code="bad_setting")
    if n < max(32, 4 * p):
        raise TactileInputError(f"recording has N={n} samples, too short to estimate spectra", source=source,
                                code="too_short")
    coeffs = np.zeros((2, AR_ORDER + 1))
    coeffs[:, 0] = 1.0
    if p:
        coeffs[0, :p + 1] = burg_ar(x[0], p)
        coeffs[1, :p + 1] = burg_ar(x[2], p)
        filt = np.repeat(coeffs[:, :p + 1], 2, axis=0)                    # x1, x2 share the x filter
        x = sum(filt[:, k, None] * x[:, p - k:n - k] for k in range(p + 1))
    if method == "welch":
        nperseg = check_nperseg(nperseg or default_nperseg(n), x.shape[-1], source=source)
        tapers, step, n_seg, dof, bin_factor, kernel = _estimator("welch", nperseg, x.shape[-1], 0.0, 0)
        idx = np.arange(n_seg)[:, None] * step + np.arange(nperseg)[None, :]
        seg = x[:, idx]                                                    # (4, K, n)
        seg = seg - seg.mean(axis=-1, keepdims=True)
        spec = np.fft.rfft(seg * tapers[0], axis=-1)
        scale = 1.0 / (fs * np.sum(tapers[0] ** 2))
        nfft = nperseg
    else:
        n_tapers = int(n_tapers or max(1, int(math.floor(2.0 * nw)) - 3))
        x = x - x.mean(axis=-1, keepdims=True)
        tapers, _, n_seg, dof, bin_factor, kernel = _estimator("multitaper", 0, x.shape[-1], float(nw), n_tapers)
        spec = np.fft.rfft(x[:, None, :] * tapers[None], axis=-1)
        scale = 1.0 / fs
        nfft = x.shape[-1]
        nperseg = nfft
    m = nfft // 2 + 1
    spec = spec * np.sqrt(scale * _onesided(nfft))                        # (4, K, m)
    omega = 2.0 * np.pi * fs * np.arange(m) / nfft
    resp = _response(coeffs, omega, fs)                                    # (2, m)
    gain = np.abs(resp) ** 2
    auto = np.abs(spec) ** 2 / np.repeat(gain, 2, axis=0)[:, None, :]
    csd = np.conj(spec[0::2]) * spec[1::2] / gain[:, None, :]
    xy = (np.conj(spec[0:2, None]) * spec[None, 2:4]).reshape(4, n_seg, m) / (np.conj(resp[0]) * resp[1])
    group, count = _groups(n_seg)
    m_out = min(m, N_BINS)
    # the groups are runs of consecutive segments: each run summed in order (``np.add.reduceat``, the sums
    # ``np.add.at`` gives, in a tenth of its time)
    first = np.flatnonzero(np.r_[True, group[1:] != group[:-1]])

    def grouped(v):
        out = np.zeros((N_GROUPS,) + v.shape[:1] + (N_BINS,), v.dtype)
        out[group[first], :, :m_out] = np.moveaxis(np.add.reduceat(v[..., :m_out], first, axis=1), 1, 0)
        return out

    return Segments(grouped(auto), grouped(csd), grouped(xy), count, np.asarray(omega[1]), np.asarray(m_out),
                    np.asarray(dof), np.asarray(n_seg / dof if method == "welch" else 1.0), np.asarray(bin_factor),
                    np.asarray(kernel), coeffs, np.asarray(float(fs)), np.asarray(nperseg))


def to_spectra(seg: Segments) -> dict:
    """The fields of a spectra file (``io.SpectraData``) that give ``seg`` back through ``from_spectra``.

    On the estimate's bins 0 .. n_valid - 1 (DC first): omega (M,) rad/s; psd (4, M), csd (2, M) and
    xy (4, M) complex, the averaged 4 x 4 spectral matrix (units^2/Hz); group_count (G,) segments in
    each non-empty group and group_psd (G, 4, M), group_csd (G, 2, M), group_xy (G, 4, M) each group's
    mean; n_segments the effective number of independent segments (``dof``); bin_factor; kernel (2, J)
    ``KERNEL_OFFSETS`` (bins) and the spectral window's weights; whitening (2, AR_ORDER + 1); fs (Hz);
    and, where every bin has one, ratio (2, M) each pair's H1 amplitude ratio |S12| / S11 and ratio_err
    (2, M) the Bendat-Piersol error of its log from the bin's coherence, sqrt((1 - g2) / (2 dof g2)).
    """
    m = int(seg.n_valid)
    count = np.asarray(seg.count, float)
    use = count > 0
    c = count[use]
    total = count.sum()
    out = {"omega": float(seg.d_omega) * np.arange(m), "group_count": c}
    for key, name in (("auto", "psd"), ("csd", "csd"), ("xy", "xy")):
        g = np.asarray(getattr(seg, key))[use][..., :m]
        out[name] = g.sum(0) / total
        out["group_" + name] = g / c[:, None, None]
    out.update(n_segments=float(seg.dof), bin_factor=float(seg.bin_factor),
               kernel=np.stack([KERNEL_OFFSETS, np.asarray(seg.kernel, float)]),
               whitening=np.asarray(seg.whitening, float), fs=float(seg.fs))
    s11, s22, mag = out["psd"][0::2], out["psd"][1::2], np.abs(out["csd"])
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = mag / s11
        g2 = mag * mag / (s11 * s22)
        err = np.sqrt((1.0 - g2) / (2.0 * float(seg.dof) * g2))
    if np.all(np.isfinite(ratio) & (ratio > 0) & np.isfinite(err) & (err > 0)):
        out.update(ratio=ratio, ratio_err=err)
    return out


def from_spectra(omega, psd, csd, xy=None, *, dof: float, groups=None, kernel=None, bin_factor=None,
                 whitening=None, fs=None, source: str | None = None) -> Segments:
    """``Segments`` of given spectra (of ``to_spectra``'s fields: the same ``Segments`` again).

    omega: (M,) rad/s, uniformly spaced on bins k d_omega (k >= 0). psd (4, M); csd (2, M) and xy (4, M)
    complex (None: no x-y spectra, zero). dof: effective number of independent segments behind them.
    groups: (count (G,), psd (G, 4, M), csd (G, 2, M), xy (G, 4, M) or None), each group's mean
    spectra and number of segments, for the delete-one-group jackknife (their count-weighted mean is
    psd, csd and xy, which are then not read); groups beyond ``N_GROUPS`` are merged, consecutive ones
    together, as ``segments`` merges segments; None: one group (no jackknife).
    kernel: (offsets in bins, weights) of one bin's spectral window (None: one bin). bin_factor: variance
    inflation of a sum over adjacent bins (None: 1). whitening: (2, p + 1) AR error filters of the x and
    y pairs and fs (Hz) their sample rate (None: none). Raises ``TactileInputError`` for a grid the fit
    cannot use.
    """
    omega = np.asarray(omega, float)
    d = np.diff(omega)
    if omega.size < 8 or not np.allclose(d, d[0], rtol=1e-6) or d[0] <= 0:
        raise TactileInputError("fitting PSD/CSD needs at least 8 uniformly spaced omega bins", source=source,
                                code="bad_shape")
    d_omega = float(d[0])
    first = omega[0] / d_omega
    if abs(first - round(first)) > 1e-6:
        raise TactileInputError("omega must lie on a grid k * d_omega (a bin at omega = k * spacing)", source=source,
                                code="bad_shape")
    first = int(round(first))
    m = min(omega.size, N_BINS - first)
    if m < 8:
        raise TactileInputError(f"the spectra start at bin {first}, beyond the fit's grid of {N_BINS} bins",
                                source=source, code="bad_shape")
    if groups is None:
        count = np.ones(1)
        parts = [np.asarray(psd, float)[None], np.asarray(csd, complex)[None],
                 None if xy is None else np.asarray(xy, complex)[None]]
    else:
        count = np.asarray(groups[0], float)
        parts = [np.asarray(groups[1], float) * count[:, None, None],
                 np.asarray(groups[2], complex) * count[:, None, None],
                 None if groups[3] is None else np.asarray(groups[3], complex) * count[:, None, None]]
    n = count.size
    group = np.minimum(np.arange(n) * N_GROUPS // n, N_GROUPS - 1)

    def grouped(v, rows, dtype):
        out = np.zeros((N_GROUPS, rows, N_BINS), dtype)
        if v is not None:
            np.add.at(out, (group, slice(None), slice(first, first + m)), v[..., :m])
        return out

    counts = np.zeros(N_GROUPS)
    np.add.at(counts, group, count)
    total = float(counts.sum())
    if kernel is None:
        kernel = ((0.0,), (1.0,))
    offsets, weights = (np.asarray(k, float) for k in kernel)
    kern = np.zeros(KERNEL_OFFSETS.size)
    pos = np.clip(np.rint((offsets - KERNEL_OFFSETS[0]) * 2).astype(int), 0, KERNEL_OFFSETS.size - 1)
    np.add.at(kern, pos, weights)
    if abs(kern.sum() - 1.0) > 1e-12:
        kern = kern / kern.sum()
    coeffs = np.zeros((2, AR_ORDER + 1))
    coeffs[:, 0] = 1.0
    if whitening is not None:
        w = np.asarray(whitening, float)
        if w.shape[-1] > AR_ORDER + 1:
            raise TactileInputError(f"'whitening' filters of order {w.shape[-1] - 1}: the fit takes at most "
                                    f"{AR_ORDER}", source=source, code="bad_shape")
        coeffs[:, :w.shape[-1]] = w
    fs = float(fs) if fs else d_omega * N_BINS / math.pi          # only the whitening filter uses it
    dof = float(dof)
    return Segments(grouped(parts[0], 4, float), grouped(parts[1], 2, complex), grouped(parts[2], 4, complex),
                    counts, np.asarray(d_omega), np.asarray(first + m), np.asarray(dof),
                    np.asarray(max(total / dof, 1.0) if groups is not None else 1.0),
                    np.asarray(float(bin_factor) if bin_factor else 1.0), kern, coeffs, np.asarray(fs), np.asarray(0))
