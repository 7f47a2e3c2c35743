"""Auto- and cross-spectra of the four probe channels, by Welch or multitaper averaging.

Recordings have shape ``(..., 4, N)`` with channels ``[x1, x2, y1, y2]``
(index 1 the shallow probe, index 2 the deep one) sampled at ``fs`` Hz.
Leading batch dimensions are carried through, and everything here works
under ``jit`` and ``vmap``: segment lengths, taper counts and FFT sizes are
static Python ints, the data and ``fs`` may be traced.

Names say which kind of spectrum they hold (docs/model.md, "Conventions"):

- ``psd`` / ``csd`` are POWER spectral densities (signal units^2 / Hz),
  one-sided, scaled as ``scipy.signal.welch(..., scaling="density")``;
- ``log_ratio`` is the log of the AMPLITUDE ratio |P2 / P1| = |S12| / S11,
  whose slope in omega is half that of the log power ratio S22 / S11.

The estimate of a pair's amplitude ratio is the H1 transfer estimate
|S12| / S11, which noise on the deep channel does not bias; its per-bin
standard error and the coherence-based bin selection follow Bendat & Piersol.

Every computation runs in the input's floating dtype (float32 in, float32
out; float64 in, float64 out); integer input is promoted to JAX's default
float, half precision to float32.

Result tuples are registered as pytrees whose leaves are the arrays only;
``n_segments``, ``dof`` and ``method`` are static metadata, so they stay
Python numbers when a result passes through ``jit`` or ``vmap``.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import TactileInputError
from .prewhiten import filter_gain, filter_response, whiten_pairs

__all__ = [
    "conditioned_psd",
    "neighbour_log_ratio_err",
    "CrossSpectra",
    "AmplitudeRatio",
    "default_nperseg",
    "welch_spectra",
    "multitaper_spectra",
    "estimate_spectra",
    "whitened_psd",
    "coherence",
    "amplitude_ratio",
    "usable_band",
]

Array = jax.Array

#: family-wise significance of the zero-coherence test over all bins in :func:`usable_band`
COHERENCE_ALPHA = 0.01


class CrossSpectra(NamedTuple):
    """One-sided auto- and cross-spectral densities of the four channels.

    Attributes:
        freq: ``(M,)`` bin frequencies in Hz, ``0 .. fs/2``, DC included.
        omega: ``(M,)`` the same in rad/s, ``2 pi freq``.
        psd: ``(..., 4, M)`` one-sided POWER spectral densities of
            ``[x1, x2, y1, y2]`` in signal units^2 / Hz (the scaling of
            ``scipy.signal.welch(scaling="density")``: white noise of variance
            ``s2`` gives ``2 s2 / fs``).
        csd: ``(..., 2, M)`` complex one-sided cross spectral densities
            ``S12 = E[conj(X1) X2]`` of the x pair ``(x1, x2)`` and the y pair
            ``(y1, y2)``, units^2 / Hz (the convention of
            ``scipy.signal.csd(x1, x2)``).
        n_segments: number of averaged segments (Welch) or tapers
            (multitaper); a Python int.
        dof: effective number of independent averages ``K_eff``, a Python
            float. Welch: ``K / (1 + 2 sum_{j=1}^{K-1} (1 - j/K) rho(j)^2)``
            with ``rho(j) = sum w[n] w[n + j step] / sum w^2`` (Welch 1967;
            Percival & Walden); multitaper: the number of tapers.
        method: ``"welch"`` or ``"multitaper"``.
        bin_factor: variance inflation of a sum over many adjacent bins,
            ``1 + 2 sum_j rho_j`` with ``rho_j`` the correlation of spectral
            estimates ``j`` bins apart for white noise (Hann Welch: 1.94;
            multitaper: about ``2 nw``). Fits that treat bins as independent
            multiply their covariance by it. A Python float.
        kernel: the spectral window seen by one bin, ``(offsets, weights)``:
            tuples of offsets in bins and weights summing to 1, so that the
            expected estimate at bin i is ``sum_j w_j S(omega_i + offset_j *
            d_omega)`` for a true density S. Fits use it to model the
            resolution bias of a steep spectrum.
        whitening: ``(..., 2, p + 1)`` AR error filters of the x and y pairs
            applied before averaging (``estimate_spectra(prewhiten=p)``), or
            None. The estimator saw ``S |A|^2``: the kernel acts on that.
        fs: the sample rate, Hz (needed with ``whitening``), or None.
        centroid: ``(..., 2, M)`` the realised power centroid of each pair's
            shallow probe within each bin's spectral window, in bins:
            ``Re sum conj(X1) X1' / sum |X1|^2`` over the segments, ``X1'`` the
            segment's transform with the derivative taper ``(i n / 2 pi) w'(t)``
            (Welch only; None for multitaper and for spectra read from a file).
            For a deep probe that is a smooth filter R of the shallow one, the
            H1 ratio at bin m is ``R_m + R'_m centroid_m`` to first order
            (``R'`` per bin): the random part of the resolution error, which
            ``pair_fit`` models.
        spread: ``(..., 2, M)`` bins^2: ``sum |X1'|^2 / sum |X1|^2 - |c|^2`` with
            ``c`` the complex centroid, the derivative transform's power that the
            centroid does not explain. The deep probe's incoherent power from the
            slope of R is ``R'^2 S11 spread``: a part of ``1 - coherence`` that is
            not noise (``pair_fit.noise_err``). None where ``centroid`` is.
        bin_corr: ``(rho_1, rho_2, ...)`` the correlations of white-noise
            estimates 1, 2, ... bins apart, to the first below 1e-3 (Hann Welch:
            0.444, 0.028). With a coherent pair and noise on the deep probe they
            are those of the log ratio's errors too
            (``tests/test_spectra.py``). A tuple of Python floats; ()
            for spectra read from a file.
        xy: ``(..., 4, M)`` complex cross-spectral densities ``E[conj(X_i) Y_j]``
            between the pairs, in the order (x1 y1, x1 y2, x2 y1, x2 y2),
            units^2 / Hz: under slow slip both pairs hear the modes of small
            |k| and these carry what the pairs alone do not (``xy_chain``).
            None for spectra read from a file.
    """

    freq: Array
    omega: Array
    psd: Array
    csd: Array
    n_segments: int
    dof: float
    method: str
    bin_factor: float = 1.0
    kernel: tuple = ((0.0,), (1.0,))
    whitening: Array | None = None
    fs: Array | None = None
    centroid: Array | None = None
    spread: Array | None = None
    bin_corr: tuple = ()
    xy: Array | None = None


class AmplitudeRatio(NamedTuple):
    """Log AMPLITUDE ratio of the deep to the shallow probe, per pair and bin.

    Attributes:
        omega: ``(M,)`` bin frequencies in rad/s.
        log_ratio: ``(..., 2, M)`` ``log(|S12| / S11)`` for the x and y pairs:
            the log amplitude ratio ``|P2 / P1|`` (H1 estimate), dimensionless.
            ``-inf`` where ``|S12| == 0`` (nothing shared by the pair).
        log_ratio_err: ``(..., 2, M)`` one-sigma standard error of
            ``log_ratio``, ``sqrt((1 - g2) / (2 K g2))`` with ``K = dof`` and
            ``g2`` the coherence (Bendat & Piersol); ``inf`` where ``g2 == 0``.
        coherence: ``(..., 2, M)`` magnitude-squared coherence ``g2`` in [0, 1].
        dof: effective number of averages ``K`` used for the error (Python float).
        bin_factor: the spectra's ``bin_factor`` (correlation between bins).
    """

    omega: Array
    log_ratio: Array
    log_ratio_err: Array
    coherence: Array
    dof: float
    bin_factor: float = 1.0


# Arrays are the leaves; counts and names are static metadata.
jax.tree_util.register_pytree_node(
    CrossSpectra,
    lambda s: ((s.freq, s.omega, s.psd, s.csd, s.whitening, s.fs, s.centroid, s.spread, s.xy),
               (s.n_segments, s.dof, s.method, s.bin_factor, s.kernel, s.bin_corr)),
    lambda aux, leaves: CrossSpectra(*leaves[:4], *aux[:5], *leaves[4:8], bin_corr=aux[5], xy=leaves[8]),
)
jax.tree_util.register_pytree_node(
    AmplitudeRatio,
    lambda r: ((r.omega, r.log_ratio, r.log_ratio_err, r.coherence), (r.dof, r.bin_factor)),
    lambda aux, leaves: AmplitudeRatio(*leaves, *aux),
)


# ---------------------------------------------------------------------------
# argument checks (Python, on static shapes and settings only)


def _as_signals(signals) -> Array:
    x = jnp.asarray(signals)
    if jnp.iscomplexobj(x):
        raise TactileInputError(
            f"signals must be real; got dtype {x.dtype}", code="bad_setting"
        )
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    elif jnp.dtype(x.dtype).itemsize < 4:
        x = x.astype(jnp.float32)
    if x.ndim < 2 or x.shape[-2] != 4:
        raise TactileInputError(
            f"signals must have shape (..., 4, N) with channels [x1, x2, y1, y2]; got shape {tuple(x.shape)}",
            code="bad_shape",
        )
    return x


def _check_fs(fs) -> None:
    if np.ndim(fs) != 0:
        raise TactileInputError(f"sample rate fs must be a scalar in Hz; got shape {np.shape(fs)}", code="bad_fs")
    try:
        value = float(fs)
    except TypeError:  # traced (jax.errors.ConcretizationTypeError is a TypeError): cannot check here
        return
    if not (math.isfinite(value) and value > 0):
        raise TactileInputError(f"sample rate fs must be a positive finite number of Hz; got {value!r}", code="bad_fs")


def _check_int(name: str, value, *, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise TactileInputError(f"{name} must be an int >= {minimum}; got {value!r}", code="bad_setting")
    return int(value)


def _check_leave_one_out(leave_one_out, n_segments: int) -> None:
    if leave_one_out and n_segments < 2:
        raise TactileInputError(f"leave_one_out needs at least 2 segments or tapers; got {n_segments}",
                                code="bad_setting")


def _is_concrete_number(value) -> bool:
    try:
        float(value)
    except TypeError:
        return False
    return True


def default_nperseg(n_samples: int) -> int:
    """Default Welch segment length (samples) for a recording of ``n_samples``.

    The largest power of two not above ``n_samples // 8``, and at least 16.
    With the default 50 % overlap this averages 15 to 30 segments: for 16 s
    at 1 kHz (N = 16000) it gives nperseg = 1024 (0.98 Hz bins, 30 segments,
    ``dof`` about 28). Recordings shorter than 16 samples are too short.
    """
    target = int(n_samples) // 8
    if target < 16:
        return 16
    return 1 << (target.bit_length() - 1)


# ---------------------------------------------------------------------------
# static (numpy) constants


def _onesided_factor(nfft: int) -> np.ndarray:
    """2 for every one-sided bin except DC and (even ``nfft``) Nyquist, which are 1."""
    factor = np.full(nfft // 2 + 1, 2.0)
    factor[0] = 1.0
    if nfft % 2 == 0:
        factor[-1] = 1.0
    return factor


def get_window(window, nperseg: int) -> np.ndarray:
    """``scipy.signal.get_window`` (periodic); the Hann window, the default, in numpy: importing
    scipy.signal takes about 1.2 s, a third of a fresh ``tactile-jax fit``'s start."""
    if isinstance(window, str) and window in ("hann", "hanning"):
        return 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(nperseg) / nperseg)
    from scipy.signal import get_window as scipy_window

    return scipy_window(window, nperseg)


@functools.lru_cache(maxsize=64)
def cached_window(window, nperseg: int) -> np.ndarray:
    w = np.asarray(get_window(window, nperseg), dtype=np.float64)
    w.setflags(write=False)
    return w


def _window_array(window, nperseg: int | None) -> tuple[np.ndarray, int]:
    """The Welch window as float64 numpy and its length."""
    if isinstance(window, (str, tuple)):
        if nperseg is None:
            raise AssertionError("nperseg must be resolved before a named window")
        try:
            hash(window)
            w = cached_window(window, nperseg)
        except TypeError:  # a tuple holding something unhashable
            w = np.asarray(get_window(window, nperseg), dtype=np.float64)
        except ValueError as exc:
            raise TactileInputError(f"unknown window {window!r}: {exc}", code="bad_setting") from None
        return w, nperseg
    w = np.asarray(window, dtype=np.float64)
    if w.ndim != 1 or w.size < 1:
        raise TactileInputError(f"window must be a name or a 1-D array; got shape {w.shape}", code="bad_setting")
    if nperseg is not None and w.size != nperseg:
        raise TactileInputError(
            f"window has {w.size} samples but nperseg={nperseg}", code="bad_setting"
        )
    if not np.all(np.isfinite(w)) or not np.any(w != 0):
        raise TactileInputError("window must be finite and not all zero", code="bad_setting")
    return w, w.size


def welch_dof(w: np.ndarray, step: int, n_segments: int) -> float:
    """Effective number of independent segments of a Welch average (Welch 1967)."""
    wss = float(np.sum(w * w))
    total = 0.0
    for j in range(1, n_segments):
        shift = j * step
        if shift >= w.size:
            break
        rho = float(np.sum(w[:-shift] * w[shift:])) / wss
        total += (1.0 - j / n_segments) * rho * rho
    return n_segments / (1.0 + 2.0 * total)


def bin_rho(tapers: np.ndarray, nfft: int) -> np.ndarray:
    """rho_j, j = 0 .. nfft/2 - 1: the correlation of white-noise spectral estimates j bins apart
    for the average of unit-energy ``tapers`` (K, n) periodograms,
    (1/K) sum_{k,l} |sum_n h_k h_l exp(-2 pi i j n / nfft)|^2 (Percival & Walden)."""
    h = tapers / np.sqrt(np.sum(tapers * tapers, axis=-1, keepdims=True))
    k = h.shape[0]
    prod = (h[:, None, :] * h[None, :, :]).reshape(k * k, -1)
    return np.sum(np.abs(np.fft.rfft(prod, n=nfft, axis=-1)) ** 2, axis=0)[:nfft // 2] / k


def adjacent_bin_factor(rho: np.ndarray) -> float:
    """1 + 2 sum_{j>=1} rho_j: the variance inflation of a sum over many adjacent bins."""
    return float(1.0 + 2.0 * np.sum(rho[1:]))


def _bin_corr(rho: np.ndarray, max_lag: int = 16) -> tuple:
    """``CrossSpectra.bin_corr``: rho_1, rho_2, ... up to the first below 1e-3 (at most ``max_lag``)."""
    lags = rho[1:max_lag + 1]
    small = np.flatnonzero(lags < 1e-3)
    return tuple(float(r) for r in lags[:small[0] if small.size else lags.size])


def spectral_kernel(tapers: np.ndarray, nfft: int, half_width: float, step: float = 0.5) -> tuple:
    """Mean |FT|^2 of unit-energy ``tapers`` (K, n) at offsets -half_width..half_width bins of ``nfft``."""
    h = tapers / np.sqrt(np.sum(tapers * tapers, axis=-1, keepdims=True))
    offsets = np.arange(-half_width, half_width + step / 2, step)
    n = np.arange(h.shape[-1])
    phase = np.exp(-2j * np.pi * np.outer(offsets, n) / nfft)            # (J, n)
    power = np.mean(np.abs(h @ phase.T) ** 2, axis=0)                     # (J,)
    weights = power / power.sum()
    return tuple(float(o) for o in offsets), tuple(float(w) for w in weights)


@functools.lru_cache(maxsize=16)
def dpss_tapers(n_samples: int, nw: float, n_tapers: int) -> np.ndarray:
    """The first ``n_tapers`` discrete prolate spheroidal sequences of length ``n_samples`` and time-half-bandwidth
    ``nw``, unit energy, in Percival and Walden's sign convention (1993, p. 379): those of
    ``scipy.signal.windows.dpss(..., sym=True, norm=2)``, by the same tridiagonal eigenproblem. Not scipy.signal
    itself: importing it takes 2.2 s, which every ``track`` run paid before its first window (scipy.linalg: 0.2 s)."""
    from scipy.linalg import eigh_tridiagonal

    m = int(n_samples)
    t = np.arange(m, dtype=np.float64)
    diag = ((m - 1 - 2 * t) / 2.0) ** 2 * np.cos(2 * np.pi * float(nw) / m)
    off = t[1:] * (m - t[1:]) / 2.0
    _, vec = eigh_tridiagonal(diag, off, select="i", select_range=(m - n_tapers, m - 1))
    tapers = np.ascontiguousarray(vec[:, ::-1].T)
    # symmetric tapers have a positive sum; antisymmetric ones start with a positive lobe
    for k in range(0, n_tapers, 2):
        if tapers[k].sum() < 0:
            tapers[k] *= -1
    thresh = max(1e-7, 1.0 / m)
    for k in range(1, n_tapers, 2):
        if tapers[k][tapers[k] ** 2 > thresh][0] < 0:
            tapers[k] *= -1
    tapers.setflags(write=False)
    return tapers


# ---------------------------------------------------------------------------
# jitted cores


def _detrend(seg: Array, kind: str) -> Array:
    if kind == "none":
        return seg
    seg = seg - jnp.mean(seg, axis=-1, keepdims=True)
    if kind == "linear":
        length = seg.shape[-1]
        t = np.arange(length, dtype=np.float64) - 0.5 * (length - 1)
        t_sq = float(np.sum(t * t))
        if t_sq > 0:
            t = jnp.asarray(t, seg.dtype)
            slope = jnp.sum(seg * t, axis=-1, keepdims=True) / jnp.asarray(t_sq, seg.dtype)
            seg = seg - slope * t
    return seg


def _segment_products(spec: Array) -> tuple[Array, Array, Array]:
    """Per-segment |X|^2 of the four channels, conj(X1) X2 of the two pairs and conj(X_i) Y_j between them
    (``CrossSpectra.xy``), from ``spec`` (..., 4, K, M)."""
    x, y = spec[..., 0:2, None, :, :], spec[..., None, 2:4, :, :]
    xy = (jnp.conj(x) * y).reshape(spec.shape[:-3] + (4,) + spec.shape[-2:])
    return jnp.square(spec.real) + jnp.square(spec.imag), jnp.conj(spec[..., 0::2, :, :]) * spec[..., 1::2, :, :], xy


def _pair_spectra(spec: Array, scale: Array) -> tuple[Array, Array, Array]:
    """Average |X|^2 and conj(X1) X2 over axis -2 of ``spec`` (..., 4, K, M) and scale."""
    return tuple(jnp.mean(x, axis=-2) * scale for x in _segment_products(spec))


def _leave_one_out_spectra(spec: Array, scale: Array) -> tuple[Array, Array, Array]:
    """Delete-one averages of ``_pair_spectra``: a new leading axis of K, averaging all segments but k."""
    return tuple(_drop_one(x) * scale for x in _segment_products(spec))


def _drop_one(x: Array) -> Array:
    """Means over axis -2 (K) leaving each k out in turn, on a new leading axis of K."""
    k = x.shape[-2]
    return jnp.moveaxis((jnp.sum(x, axis=-2, keepdims=True) - x) / (k - 1), -2, 0)


def _derivative_taper(w: np.ndarray) -> np.ndarray:
    """The real h(t) with ``(i n / 2 pi) w'(t) = i h(t)``: w' the circular spectral derivative (exact for a
    periodic window; Hann: h = sin(2 pi t / n) / 2), so that the transform with taper i h is the derivative of
    the window's spectrum with respect to frequency in bins."""
    n = w.size
    k = np.fft.fftfreq(n) * n
    if n % 2 == 0:
        k[n // 2] = 0.0
    return np.real(-np.fft.ifft(k * np.fft.fft(w)) / 1j)


def _centroid(seg: Array, window: Array, dtaper: Array, leave_one_out: bool) -> tuple[Array, Array]:
    """``CrossSpectra.centroid`` and ``spread`` of the shallow channels (0 and 2) of detrended segments (..., 4, K, n)."""
    shallow = seg[..., 0::2, :, :]
    x = jnp.fft.rfft(shallow * window, axis=-1)
    xd = jnp.fft.rfft(shallow * dtaper, axis=-1) * 1j
    cross = jnp.conj(x) * xd
    mean = _drop_one if leave_one_out else (lambda v: jnp.mean(v, axis=-2))
    power, cross, dpower = mean(jnp.square(jnp.abs(x))), mean(cross), mean(jnp.square(jnp.abs(xd)))
    ok = power > 0
    c = _safe_div(cross, power, ok)
    spread = jnp.clip(_safe_div(dpower, power, ok) - jnp.square(jnp.abs(c)), 0.0, None)
    return jnp.where(ok, c.real, 0.0), jnp.where(ok, spread, 0.0)


def _freq_axis(fs: Array, nfft: int, dtype) -> tuple[Array, Array]:
    freq = jnp.arange(nfft // 2 + 1, dtype=dtype) * (fs / nfft)
    return freq, (2.0 * np.pi) * freq


@functools.partial(jax.jit, static_argnames=("nperseg", "step", "n_segments", "detrend", "leave_one_out"))
def _welch_core(x, fs, window, dtaper, *, nperseg: int, step: int, n_segments: int, detrend: str,
                leave_one_out=False):
    dtype = x.dtype
    fs = jnp.asarray(fs, dtype)
    window = jnp.asarray(window, dtype)
    dtaper = jnp.asarray(dtaper, dtype)
    if nperseg % step == 0:
        # overlapping segments from strided blocks: a reshape and r slices, 31 % less time for the
        # batch's spectral stage than the gather below (256 records of 4 x 8192, 2 CPU cores)
        r = nperseg // step
        blocks = x[..., :(n_segments + r - 1) * step].reshape(x.shape[:-1] + (n_segments + r - 1, step))
        seg = jnp.concatenate([blocks[..., j:j + n_segments, :] for j in range(r)], axis=-1)
    else:
        index = np.arange(n_segments)[:, None] * step + np.arange(nperseg)[None, :]
        seg = jnp.take(x, index, axis=-1)  # (..., 4, K, nperseg)
    seg = _detrend(seg, detrend)
    spec = jnp.fft.rfft(seg * window, axis=-1)  # (..., 4, K, M)
    scale = jnp.asarray(_onesided_factor(nperseg), dtype) / (fs * jnp.sum(jnp.square(window)))
    psd, csd, xy = (_leave_one_out_spectra if leave_one_out else _pair_spectra)(spec, scale)
    freq, omega = _freq_axis(fs, nperseg, dtype)
    return (freq, omega, psd, csd, xy) + _centroid(seg, window, dtaper, leave_one_out)


@functools.partial(jax.jit, static_argnames=("nfft", "leave_one_out"))
def _multitaper_core(x, fs, tapers, *, nfft: int, leave_one_out=False):
    dtype = x.dtype
    fs = jnp.asarray(fs, dtype)
    tapers = jnp.asarray(tapers, dtype)  # (K, N), unit energy
    x = x - jnp.mean(x, axis=-1, keepdims=True)
    spec = jnp.fft.rfft(x[..., None, :] * tapers, n=nfft, axis=-1)  # (..., 4, K, M)
    energy = jnp.sum(jnp.square(tapers), axis=-1)[:, None]  # (K, 1)
    spec = spec / jnp.sqrt(energy).astype(spec.dtype)
    scale = jnp.asarray(_onesided_factor(nfft), dtype) / fs
    psd, csd, xy = (_leave_one_out_spectra if leave_one_out else _pair_spectra)(spec, scale)
    freq, omega = _freq_axis(fs, nfft, dtype)
    return freq, omega, psd, csd, xy


# ---------------------------------------------------------------------------
# estimators


def welch_spectra(signals, fs, *, nperseg=None, noverlap=None, window="hann", detrend="constant",
                  leave_one_out: bool = False) -> CrossSpectra:
    """Welch (averaged modified periodogram) auto- and cross-spectra.

    Matches ``scipy.signal.welch`` / ``scipy.signal.csd`` with the same
    ``nperseg``, ``noverlap``, ``window`` and ``detrend``, ``scaling="density"``,
    one-sided, mean average, no boundary padding (trailing samples that do not
    fill a segment are dropped).

    Args:
        signals: ``(..., 4, N)`` recordings, channels ``[x1, x2, y1, y2]``, in
            signal units (for example pascals or volts).
        fs: sample rate in Hz (Python float or traced scalar).
        nperseg: segment length in samples (static int). Default
            :func:`default_nperseg` (largest power of two <= N // 8, at least
            16), or the length of an array ``window``.
        noverlap: overlap between segments in samples (static int),
            ``0 <= noverlap < nperseg``; default ``nperseg // 2``.
        window: a ``scipy.signal.get_window`` spec (name or tuple, periodic
            form as in scipy) or a 1-D array of ``nperseg`` weights.
        detrend: ``"constant"`` (remove each segment's mean), ``"linear"``
            or ``False`` / ``None`` / ``"none"``.
        leave_one_out: return the K delete-one-segment estimates instead
            (``psd``, ``csd`` with a leading axis of K, segment k left out of
            the k-th), for a jackknife of anything computed from the spectra.

    Returns:
        :class:`CrossSpectra` with ``M = nperseg // 2 + 1`` bins, PSDs in
        units^2 / Hz, ``n_segments`` the number of segments and ``dof`` their
        effective number given the overlap.

    Raises:
        TactileInputError: ``too_short`` when ``N < nperseg``; ``bad_setting``
            for invalid settings; ``bad_shape``/``bad_fs`` for bad inputs.
    """
    x = _as_signals(signals)
    _check_fs(fs)
    n_samples = x.shape[-1]
    if detrend is None or detrend is False:
        detrend = "none"
    if detrend not in ("constant", "linear", "none"):
        raise TactileInputError(
            f"detrend must be 'constant', 'linear' or None; got {detrend!r}", code="bad_setting"
        )
    if nperseg is not None:
        nperseg = _check_int("nperseg", nperseg, minimum=1)
    elif not isinstance(window, (str, tuple)):
        nperseg = int(np.size(window))
    else:
        nperseg = default_nperseg(n_samples)
    if n_samples < nperseg:
        raise TactileInputError(
            f"recording has N={n_samples} samples, fewer than one Welch segment of nperseg={nperseg}",
            code="too_short",
        )
    w, nperseg = _window_array(window, nperseg)
    if noverlap is None:
        noverlap = nperseg // 2
    noverlap = _check_int("noverlap", noverlap, minimum=0)
    if noverlap >= nperseg:
        raise TactileInputError(
            f"noverlap={noverlap} must be smaller than nperseg={nperseg}", code="bad_setting"
        )
    step = nperseg - noverlap
    n_segments = (n_samples - nperseg) // step + 1
    _check_leave_one_out(leave_one_out, n_segments)
    freq, omega, psd, csd, xy, centroid, spread = _welch_core(
        x, fs, w, _derivative_taper(w), nperseg=nperseg, step=step, n_segments=n_segments, detrend=detrend,
        leave_one_out=bool(leave_one_out)
    )
    rho = bin_rho(w[None, :], nperseg)
    return CrossSpectra(freq, omega, psd, csd, n_segments, welch_dof(w, step, n_segments), "welch",
                        adjacent_bin_factor(rho), spectral_kernel(w[None, :], nperseg, 3.0),
                        centroid=centroid, spread=spread, bin_corr=_bin_corr(rho), xy=xy)


def multitaper_spectra(signals, fs, *, nw=4.0, n_tapers=None, nfft=None, leave_one_out: bool = False) -> CrossSpectra:
    """Multitaper (Thomson) auto- and cross-spectra with DPSS tapers.

    The record's mean is removed, each channel is multiplied by the
    ``n_tapers`` unit-energy DPSS tapers of ``scipy.signal.windows.dpss``
    (static constants), and the eigenspectra are averaged with equal weights
    (no adaptive weighting). The density scaling is that of
    :func:`welch_spectra`: white noise of variance ``s2`` gives ``2 s2 / fs``.

    Args:
        signals: ``(..., 4, N)`` recordings, channels ``[x1, x2, y1, y2]``, in
            signal units.
        fs: sample rate in Hz (Python float or traced scalar).
        nw: time-half-bandwidth product (dimensionless); the spectral
            resolution is ``2 nw fs / N`` Hz. Must satisfy ``0 < nw < N / 2``.
        n_tapers: number of tapers (static int), default ``floor(2 nw) - 3``
            (at least 1); 5 for ``nw = 4``. The last tapers of the usual
            ``2 nw - 1`` leak 1-6 % of their power outside the band, which
            swamps the deep probe's weak bins when the spectrum spans decades.
        nfft: FFT length in samples (static int, ``>= N``; zero-padded),
            default ``N``; the bins are ``k fs / nfft`` Hz.
        leave_one_out: return the delete-one-taper estimates (a leading axis
            of ``n_tapers``), the jackknife of Thomson and Chave (1991).

    Returns:
        :class:`CrossSpectra` with ``M = nfft // 2 + 1`` bins and
        ``n_segments = dof = n_tapers``.

    Raises:
        TactileInputError: ``too_short`` when ``N`` is too small for ``nw`` and
            ``n_tapers``; ``bad_setting`` for invalid settings.
    """
    x = _as_signals(signals)
    _check_fs(fs)
    n_samples = x.shape[-1]
    if not _is_concrete_number(nw) or not (math.isfinite(float(nw)) and float(nw) > 0):
        raise TactileInputError(f"nw must be a positive number; got {nw!r}", code="bad_setting")
    nw = float(nw)
    if n_tapers is None:
        n_tapers = max(1, int(math.floor(2.0 * nw)) - 3)
    n_tapers = _check_int("n_tapers", n_tapers, minimum=1)
    if n_samples < 2 or nw >= n_samples / 2 or n_tapers > n_samples:
        raise TactileInputError(
            f"recording has N={n_samples} samples, too short for multitaper with nw={nw:g} and n_tapers={n_tapers}"
            " (needs nw < N/2 and n_tapers <= N)",
            code="too_short",
        )
    if nfft is None:
        nfft = n_samples
    nfft = _check_int("nfft", nfft, minimum=1)
    if nfft < n_samples:
        raise TactileInputError(f"nfft={nfft} must be at least N={n_samples}", code="bad_setting")
    _check_leave_one_out(leave_one_out, n_tapers)
    tapers = dpss_tapers(n_samples, nw, n_tapers)
    freq, omega, psd, csd, xy = _multitaper_core(x, fs, tapers, nfft=nfft, leave_one_out=bool(leave_one_out))
    rho = bin_rho(tapers, nfft)
    return CrossSpectra(freq, omega, psd, csd, n_tapers, float(n_tapers), "multitaper",
                        adjacent_bin_factor(rho), spectral_kernel(tapers, nfft, math.ceil(nw * nfft / n_samples) + 1.0),
                        bin_corr=_bin_corr(rho), xy=xy)


_ESTIMATORS = {"welch": welch_spectra, "multitaper": multitaper_spectra}


def estimate_spectra(signals, fs, *, method="welch", prewhiten: int | None = None, **kw) -> CrossSpectra:
    """Spectra by the estimator named ``method`` (``"welch"`` or ``"multitaper"``).

    ``signals`` ``(..., 4, N)`` in signal units, ``fs`` in Hz; ``kw`` go to
    :func:`welch_spectra` or :func:`multitaper_spectra`. ``prewhiten``: the
    order of a Burg AR whitening filter applied to each pair before
    averaging (``prewhiten.whiten_pairs``) and divided out afterwards, which
    removes the spectral window's leakage bias on steep spectra; a pair's
    ratio and coherence are unchanged by the filter. ``None`` or 0: off.

    Raises:
        TactileInputError: ``bad_setting`` for an unknown ``method``.
    """
    try:
        estimator = _ESTIMATORS[method]
    except (KeyError, TypeError):
        raise TactileInputError(
            f"unknown spectral method {method!r}; expected one of {sorted(_ESTIMATORS)}", code="bad_setting"
        ) from None
    if not prewhiten:
        return estimator(signals, fs, **kw)
    order = _check_int("prewhiten", prewhiten, minimum=1)
    x = _as_signals(signals)
    if x.shape[-1] < 4 * order:
        raise TactileInputError(
            f"recording has N={x.shape[-1]} samples, too short for a prewhitening filter of order {order}",
            code="too_short")
    white, coeffs = whiten_pairs(x, order)
    if method == "welch" and kw.get("nperseg") is None and isinstance(kw.get("window", "hann"), (str, tuple)):
        # the segment of the recording's own length: the filter leaves N - order samples, and for a
        # power-of-two N their default segment is half as long (8192 samples: 512, not 1024), which
        # doubled the resolution bias of the log ratio (|v| RMSE 1.52 % against 0.36 % on the same records)
        kw = {**kw, "nperseg": default_nperseg(x.shape[-1])}
    spec = estimator(white, fs, **kw)
    return _unwhiten(spec, coeffs, jnp.asarray(fs, spec.psd.dtype))


@jax.jit
def _unwhiten(spec: CrossSpectra, coeffs, fs) -> CrossSpectra:
    gain = filter_gain(coeffs, spec.omega, fs).astype(spec.psd.dtype)     # (..., 2, M)
    xy = spec.xy
    if xy is not None:              # the pairs' filters differ: conj(A_x X) A_y Y = conj(A_x) A_y conj(X) Y
        resp = filter_response(coeffs, spec.omega, fs)
        xy = xy / jnp.repeat(jnp.conj(resp[..., 0:1, :]) * resp[..., 1:2, :], 4, axis=-2)
    return spec._replace(psd=spec.psd / jnp.repeat(gain, 2, axis=-2), csd=spec.csd / gain,
                         whitening=coeffs, fs=fs, xy=xy)


# ---------------------------------------------------------------------------
# derived quantities


def _safe_div(num: Array, den: Array, ok: Array) -> Array:
    return num / jnp.where(ok, den, jnp.ones_like(den))


def whitened_psd(spectra: CrossSpectra) -> Array:
    """``(..., 4, M)`` the auto-spectra as the estimator averaged them: ``psd |A|^2``.

    With prewhitening (``estimate_spectra(prewhiten=p)``) the spectral window
    acted on the filtered signals; a model of the window average of R weights it
    by this spectrum (``pair_fit.kernel_log_weights``). Without, ``psd``.
    """
    if spectra.whitening is None:
        return spectra.psd
    gain = filter_gain(spectra.whitening, spectra.omega, spectra.fs).astype(spectra.psd.dtype)
    return spectra.psd * jnp.repeat(gain, 2, axis=-2)


@jax.jit
def coherence(spectra: CrossSpectra) -> Array:
    """Magnitude-squared coherence ``|S12|^2 / (S11 S22)`` of the x and y pairs.

    Returns a ``(..., 2, M)`` dimensionless array in [0, 1] (up to rounding),
    the same as ``scipy.signal.coherence`` for Welch spectra; 0 where either
    auto-spectrum is exactly 0.
    """
    psd, csd = spectra.psd, spectra.csd
    s11 = psd[..., 0::2, :]
    s22 = psd[..., 1::2, :]
    mag = jnp.abs(csd)
    ok = (s11 > 0) & (s22 > 0)
    g2 = _safe_div(mag, s11, ok) * _safe_div(mag, s22, ok)
    return jnp.where(ok, g2, jnp.zeros_like(g2))


def conditioned_psd(spectra: CrossSpectra) -> Array:
    """Each pair's conditioned deep PSD ``S22.1 = S22 - |S12|^2 / S11``: ``(..., 2, M)``, units^2/Hz.

    The deep probe's power that the shallow one does not explain (Bendat & Piersol's
    conditioned spectrum; ``S22 (1 - g2)``). For Gaussian data its estimate is
    independent of ``S11`` and ``S12 / S11`` and is ``chi^2`` with ``2 (K - 1)``
    degrees of freedom. 0 where ``S11`` is 0. jnp.
    """
    s11 = spectra.psd[..., 0::2, :]
    s22 = spectra.psd[..., 1::2, :]
    ok = s11 > 0
    c22 = s22 - jnp.square(jnp.abs(spectra.csd)) / jnp.where(ok, s11, 1.0)
    return jnp.where(ok & jnp.isfinite(c22), c22, 0.0)


@jax.jit
def amplitude_ratio(spectra: CrossSpectra) -> AmplitudeRatio:
    """Log AMPLITUDE ratio ``log(|S12| / S11)`` of deep to shallow probe, with errors.

    ``|S12| / S11`` is the H1 estimate of ``|P2 / P1|``: uncorrelated noise on
    the deep channel does not bias it (unlike ``sqrt(S22 / S11)``). The
    one-sigma error of its log is ``sqrt((1 - g2) / (2 K g2))`` with ``K =
    spectra.dof`` (Bendat & Piersol). Exact zeros give ``-inf`` and an
    ``inf`` error, never NaN.

    Returns:
        :class:`AmplitudeRatio`; arrays ``(..., 2, M)`` for the x and y pairs,
        ``omega`` in rad/s, the log ratio dimensionless.
    """
    s11 = spectra.psd[..., 0::2, :]
    mag = jnp.abs(spectra.csd)
    ok = (mag > 0) & (s11 > 0)
    one = jnp.ones_like(mag)
    log_ratio = jnp.log(jnp.where(ok, mag, one)) - jnp.log(jnp.where(ok, s11, one))
    log_ratio = jnp.where(ok, log_ratio, jnp.full_like(log_ratio, -jnp.inf))

    g2 = coherence(spectra)
    err = coherence_log_ratio_err(g2, float(spectra.dof))
    return AmplitudeRatio(spectra.omega, log_ratio, err, g2, float(spectra.dof), float(spectra.bin_factor))


def coherence_log_ratio_err(g2: Array, dof: float) -> Array:
    """Bendat-Piersol one-sigma error of log|H1|, ``sqrt((1 - g2) / (2 K g2))``; ``inf`` where g2 == 0."""
    has = g2 > 0
    g2_safe = jnp.where(has, g2, jnp.ones_like(g2))
    err = jnp.sqrt(jnp.clip(1.0 - g2_safe, 0.0, None) / (2.0 * dof * g2_safe))
    return jnp.where(has, err, jnp.full_like(err, jnp.inf))


def usable_band(ratio: AmplitudeRatio, *, min_snr=1.0, max_err=0.5, fmin=None, fmax=None,
                neighbours: int = 0) -> Array:
    """Bins where the deep probe is above the noise: a ``(..., 2, M)`` bool mask.

    A bin of a pair is usable when all of these hold:

    - coherence ``g2 > min_snr / (1 + min_snr)``, i.e. the deep-probe
      signal-to-noise POWER ratio ``g2 / (1 - g2)`` exceeds ``min_snr``;
    - ``g2`` exceeds the level that zero coherence passes in fewer than 1 %
      of recordings anywhere in the band, ``1 - (0.01 / M) ** (1 / (K - 1))``
      for ``K = ratio.dof`` and ``M`` bins (with ``K <= 1`` the
      coherence is 1 by construction and no bin is usable);
    - ``log_ratio_err <= max_err`` (dimensionless, error of the log);
    - the bin is not DC (``omega > 0``);
    - ``fmin <= omega / (2 pi) <= fmax`` -- ``fmin`` and ``fmax`` in Hz, not
      rad/s (``None``: no limit);
    - ``log_ratio``, its error and ``g2`` are finite.

    ``neighbours = n > 0`` judges each bin by the mean coherence of the ``2 n``
    bins around it, not its own (and its error for ``max_err`` from that mean).
    A bin's own coherence is correlated with its own log ratio: near the band
    edge the bins that pass are those whose |S12| came out high, so the kept log
    ratios are biased up (Monte-Carlo: +0.066 at coherence 0.5 with 30
    averages, +0.09 at 0.75 with 6; +0.043 over a falling edge in
    ``tests/test_spectra.py``, -0.003 with 3 neighbours), which flattens the
    fitted slope. The neighbours' coherence is independent of the bin's
    own noise. Default 0 (own coherence), as before.

    ``min_snr``, ``max_err``, ``fmin`` and ``fmax`` may be traced; there is no
    Python branching on data, so this works under ``jit`` and ``vmap``.
    """
    g2 = ratio.coherence
    dof = float(ratio.dof)
    if dof <= 1.0:
        return jnp.zeros(g2.shape, dtype=bool)
    for name, value in (("min_snr", min_snr), ("max_err", max_err)):
        if _is_concrete_number(value) and not float(value) >= 0:
            raise TactileInputError(f"{name} must be >= 0; got {value!r}", code="bad_setting")
    neighbours = _check_int("neighbours", neighbours, minimum=0)
    fmin = -np.inf if fmin is None else fmin
    fmax = np.inf if fmax is None else fmax
    return _usable_band_core(ratio, min_snr, max_err, fmin, fmax, neighbours)


def neighbour_log_ratio_err(ratio: AmplitudeRatio, neighbours: int) -> Array:
    """The log ratio's one-sigma errors from the mean coherence of each bin's ``2 n`` neighbours, not its own.

    A bin's own coherence estimate rises and falls with its own |S12|, so errors
    taken from it give the bins whose ratio came out high the smaller errors and
    the larger weights: a weighted fit's slope is then pulled flat and the speed
    up. The neighbours' coherence carries none of the bin's own noise.
    ``neighbours = 0``: the bin's own errors (``ratio.log_ratio_err``).
    """
    neighbours = _check_int("neighbours", neighbours, minimum=0)
    if not neighbours:
        return ratio.log_ratio_err
    return coherence_log_ratio_err(neighbour_mean(_without_dc(ratio), neighbours), float(ratio.dof))


def _without_dc(ratio: AmplitudeRatio) -> Array:
    """The coherence with NaN at DC: the segments' mean removal leaves DC no coherence of the signal's, and
    spectra files often start above it, so a neighbour mean that counts it would differ between the two."""
    return jnp.where(ratio.omega > 0, ratio.coherence, jnp.nan)


def neighbour_mean(x: Array, n: int) -> Array:
    """Mean of the finite values among the n bins on each side of each bin (itself excluded), last axis."""
    ok = jnp.isfinite(x)
    kernel = jnp.ones(2 * n + 1, x.dtype).at[n].set(0.0)
    conv = jax.vmap(lambda v: jnp.convolve(v, kernel, mode="same"))
    flat = lambda v: v.reshape(-1, x.shape[-1])
    total = conv(flat(jnp.where(ok, x, 0.0)))
    count = conv(flat(ok.astype(x.dtype)))
    return jnp.where(count > 0, total / jnp.where(count > 0, count, 1.0), 0.0).reshape(x.shape)


@functools.partial(jax.jit, static_argnums=5)
def _usable_band_core(ratio, min_snr, max_err, fmin, fmax, neighbours=0):
    g2 = ratio.coherence
    dof = float(ratio.dof)
    err = ratio.log_ratio_err
    if neighbours:
        g2 = neighbour_mean(_without_dc(ratio), neighbours)
        err = coherence_log_ratio_err(g2, dof)
    # Bonferroni over the M bins: with thousands of multitaper bins a per-bin 1 % test
    # would admit dozens of pure-noise bins with small error bars
    n_bins = g2.shape[-1]
    significance = 1.0 - (COHERENCE_ALPHA / n_bins) ** (1.0 / (dof - 1.0))
    snr_level = min_snr / (1.0 + min_snr)
    freq = ratio.omega / (2.0 * np.pi)  # Hz
    return (
        (g2 > snr_level)
        & (g2 > significance)
        & (err <= max_err)
        & (ratio.omega > 0)
        & jnp.isfinite(ratio.log_ratio)
        & jnp.isfinite(ratio.log_ratio_err)
        & jnp.isfinite(ratio.coherence)
        & (freq >= fmin)
        & (freq <= fmax)
    )
