"""Welch ``Segments`` of many records at once, in jnp: the batch's spectra on an accelerator.

The estimate of ``segments.segments`` with ``method="welch"`` (Burg
prewhitening of each pair by its shallow probe, half-overlapping Hann
segments, the 4x4 spectral matrix summed into ``N_GROUPS`` groups on the
``N_BINS`` grid), for a stack of records of one length, vmapped and compiled
once per (length, segment, prewhitening order). ``segments`` stays the
single-record path: numpy compiles nothing, which a first ``fit`` needs.
``tests/test_spectra.py`` holds the two to the same values.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from .prewhiten import burg_ar
from .segments import AR_ORDER, N_BINS, N_GROUPS, Segments, _estimator, _groups, _onesided, check_nperseg

__all__ = ["welch_many"]


@functools.partial(jax.jit, static_argnames=("nperseg", "order"))
def _welch(signals, fs, nperseg: int, order: int):
    """Grouped Welch products of ``signals`` (B, 4, N), sampled at ``fs`` (B,) Hz; see ``welch_many``."""
    b, _, n = signals.shape
    x = signals
    coeffs = jnp.zeros((b, 2, AR_ORDER + 1), signals.dtype).at[:, :, 0].set(1.0)
    if order:
        a = jnp.stack([burg_ar(x[:, 0], order), burg_ar(x[:, 2], order)], axis=1)           # (B, 2, p + 1)
        coeffs = coeffs.at[:, :, :order + 1].set(a)
        filt = jnp.repeat(a, 2, axis=1)                                                     # x1, x2 share x's
        x = sum(filt[:, :, k, None] * x[:, :, order - k:n - k] for k in range(order + 1))
    tapers, step, n_seg, _, _, _ = _estimator("welch", nperseg, x.shape[-1], 0.0, 0)
    idx = np.arange(n_seg)[:, None] * step + np.arange(nperseg)[None, :]
    seg = x[:, :, idx]                                                                      # (B, 4, K, n)
    seg = seg - jnp.mean(seg, axis=-1, keepdims=True)
    m = nperseg // 2 + 1
    scale = 1.0 / (fs * np.sum(tapers[0] ** 2))                                             # (B,)
    spec = jnp.fft.rfft(seg * tapers[0], axis=-1) * jnp.sqrt(scale[:, None, None, None] * _onesided(nperseg))
    # the filters' response at bin j is a function of j / nperseg alone, whatever fs
    phase = np.exp(-1j * np.outer(np.arange(AR_ORDER + 1), 2.0 * np.pi * np.arange(m) / nperseg))
    resp = coeffs.astype(phase.dtype) @ phase                                               # (B, 2, m)
    gain = jnp.abs(resp) ** 2
    m_out = min(m, N_BINS)
    spec, resp, gain = spec[..., :m_out], resp[..., :m_out], gain[..., :m_out]
    auto = jnp.abs(spec) ** 2 / jnp.repeat(gain, 2, axis=1)[:, :, None, :]
    csd = jnp.conj(spec[:, 0::2]) * spec[:, 1::2] / gain[:, :, None, :]
    xy = (jnp.conj(spec[:, 0:2, None]) * spec[:, None, 2:4]).reshape(b, 4, n_seg, m_out)
    xy = xy / (jnp.conj(resp[:, 0]) * resp[:, 1])[:, None, None, :]
    onehot = (_groups(n_seg)[0][None, :] == np.arange(N_GROUPS)[:, None]).astype(float)     # (G, K)

    def grouped(v):                                                                         # (B, C, K, m_out)
        g = jnp.einsum("gk,bckm->bgcm", onehot.astype(v.dtype), v)
        return jnp.pad(g, ((0, 0), (0, 0), (0, 0), (0, N_BINS - m_out)))

    return grouped(auto), grouped(csd), grouped(xy), coeffs


def welch_many(signals, fs, *, nperseg: int | None = None, prewhiten: int | None = 8) -> Segments:
    """``Segments`` of records ``signals`` (B, 4, N) of one length, at ``fs`` Hz (scalar or (B,)): each field
    with a leading axis B, as ``segments.segments(signals[i], fs[i], method="welch", ...)`` gives it.

    nperseg: samples per segment (None: ``estimate.default_nperseg(N)``); prewhiten: Burg order (None or 0:
    off). Raises ``TactileInputError`` for the settings ``segments`` refuses."""
    from .estimate import default_nperseg
    from .segments import segments

    x = jnp.asarray(signals)
    b, _, n = x.shape
    p = int(prewhiten or 0)
    if not 0 <= p <= AR_ORDER or n < max(32, 4 * p):        # ``segments`` raises the one-line error
        segments(np.asarray(signals[0]), float(np.ravel(fs)[0]), nperseg=nperseg, prewhiten=prewhiten)
    nperseg = check_nperseg(nperseg or default_nperseg(n), n - p)
    fs = np.broadcast_to(np.asarray(fs, float), (b,))
    auto, csd, xy, coeffs = _welch(x, jnp.asarray(fs, x.dtype), nperseg, p)
    tapers, step, n_seg, dof, bin_factor, kernel = _estimator("welch", nperseg, n - p, 0.0, 0)
    m_out = min(nperseg // 2 + 1, N_BINS)
    count = _groups(n_seg)[1]

    def each(v):
        return np.broadcast_to(np.asarray(v), (b,) + np.shape(v)).copy()

    return Segments(auto, csd, xy, each(count), 2.0 * np.pi * fs / nperseg, each(m_out), each(dof),
                    each(n_seg / dof), each(bin_factor), each(kernel), coeffs, fs.copy(), each(nperseg))
