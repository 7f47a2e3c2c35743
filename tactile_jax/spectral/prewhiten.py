"""AR prewhitening: flatten steep probe spectra before Welch/multitaper averaging.

Texture spectra fall by decades across the band, so the spectral window's
sidelobes (and even its main lobe) carry power from strong low-frequency
bins into weak high-frequency ones and bias the deep/shallow ratio upward.
Filtering both probes of a pair with the same whitening filter A(z) leaves
their ratio S12 / S11 exactly unchanged while flattening what the window
sees (Percival & Walden, ch. 9). A(z) is the Burg AR(p) error filter of the
pair's shallow probe. Spectra are divided by |A(exp(i omega / fs))|^2 after
estimation to undo the filter.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp

__all__ = ["burg_ar", "whiten_pairs", "filter_gain", "filter_response"]


def burg_ar(x, order: int):
    """Burg estimate of the AR error filter [1, a1, ..., ap] of ``x`` (..., N); ``order`` static.

    The AR model x[n] + sum_k a_k x[n-k] = e[n]. A silent channel gives [1, 0, ..., 0].
    """
    x = x - jnp.mean(x, axis=-1, keepdims=True)
    ef, eb = x, x
    a = jnp.ones(x.shape[:-1] + (1,), x.dtype)
    for _ in range(order):
        f, b = ef[..., 1:], eb[..., :-1]
        num = -2.0 * jnp.sum(f * b, axis=-1)
        den = jnp.sum(f * f, axis=-1) + jnp.sum(b * b, axis=-1)
        k = jnp.where(den > 0, num / jnp.where(den > 0, den, 1.0), 0.0)
        ef, eb = f + k[..., None] * b, b + k[..., None] * f
        a_pad = jnp.concatenate([a, jnp.zeros_like(a[..., :1])], axis=-1)
        a = a_pad + k[..., None] * jnp.flip(a_pad, axis=-1)
    return a


def _fir(x, a):
    """y[n] = sum_k a[k] x[n - k] for n >= p (valid part), (..., N - p)."""
    p = a.shape[-1] - 1
    n = x.shape[-1]
    return sum(a[..., k, None] * x[..., p - k:n - k] for k in range(p + 1))


@partial(jax.jit, static_argnames="order")
def whiten_pairs(signals, order: int):
    """Whiten each probe pair with its shallow probe's Burg filter.

    signals: (..., 4, N) channels [x1, x2, y1, y2]. Returns the filtered
    signals (..., 4, N - order) and the filters (..., 2, order + 1) of the x
    and y pairs. The ratio of a pair's spectra is unchanged by construction.
    """
    coeffs = jnp.stack([burg_ar(signals[..., 0, :], order), burg_ar(signals[..., 2, :], order)], axis=-2)
    per_channel = jnp.repeat(coeffs, 2, axis=-2)          # x1, x2 share the x filter; y1, y2 the y filter
    return _fir(signals, per_channel), coeffs


@jax.jit
def filter_response(coeffs, omega, fs):
    """A(exp(i omega / fs)) = sum_k a_k exp(-i k omega / fs) of filters (..., order + 1) at omega (M,) rad/s:
    complex, shape (..., M)."""
    k = jnp.arange(coeffs.shape[-1])
    phase = jnp.exp(-1j * jnp.outer(omega / fs, k))          # (M, p + 1)
    return jnp.einsum("...k,mk->...m", coeffs.astype(phase.dtype), phase)


@jax.jit
def filter_gain(coeffs, omega, fs):
    """|A(exp(i omega / fs))|^2 of filters (..., order + 1) at omega (M,) rad/s: shape (..., M)."""
    return jnp.abs(filter_response(coeffs, omega, fs)) ** 2
