"""The usable band and closed-form starts on the fixed grid (jnp; ``core`` runs it under jit and vmap).

From one record's ``segments.Segments``: the spectra, each pair's H1 log
amplitude ratio with its errors, the usable bins as masks, the Eq. 6 slope
speeds and intercepts, the Eq. 4 dominant wavenumbers, and the window of
``core.N_FIT`` bins that the fit models. A bin of a pair is usable when the
mean coherence of its 2 n neighbours (its own would select the bins whose
ratio came out high) passes the SNR and zero-coherence tests and gives an
error below ``max_err``, it is not DC, lies in [fmin, fmax], and is not mere
spectral leakage between texture lines (``leakage_db`` below the highest bin
within +/- 3) nor a stray coherent bin far above the band.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from .._numerics import tiny
from ..model.closed_form import dominant_wavenumber, radius_from_offset, slope_speed
from .estimate import COHERENCE_ALPHA, coherence_log_ratio_err, neighbour_mean

__all__ = ["Spectra", "Band", "spectra", "coherence", "select"]

#: the fewest usable bins a fit takes (fewer: ``no_band``)
MIN_BINS = 6

class Spectra(NamedTuple):
    """Averaged spectra on the grid: psd (4, M), csd (2, M) and xy (4, M) complex, omega (M,) rad/s,
    valid (M,) bins of the estimate; dof (effective segments)."""

    psd: jax.Array
    csd: jax.Array
    xy: jax.Array
    omega: jax.Array
    valid: jax.Array
    dof: jax.Array


class Band(NamedTuple):
    """What ``select`` finds (arrays).

    log_ratio, err, coherence: (2, M) H1 log amplitude ratio, its one-sigma error from the
    neighbours' coherence, the coherence. band: (2, M) usable bins. n_band: (2,). speed0, a0: (2,)
    Eq. 6 speeds (m/s) and Eq. 26 radii (m), NaN where a pair has none. k0: (2,) Eq. 4 dominant
    wavenumbers (rad/m) or NaN. i0: first bin of the fit's window. n_leak: coherent bins dropped as
    leakage between lines.
    """

    log_ratio: jax.Array
    err: jax.Array
    coherence: jax.Array
    band: jax.Array
    n_band: jax.Array
    speed0: jax.Array
    a0: jax.Array
    k0: jax.Array
    i0: jax.Array
    n_leak: jax.Array


def spectra(seg) -> Spectra:
    """The spectra of all segments (``seg``: a ``Segments`` of jnp arrays)."""
    total = jnp.maximum(jnp.sum(seg.count), 1.0)
    m = seg.auto.shape[-1]
    omega = seg.d_omega * jnp.arange(m)
    return Spectra(jnp.sum(seg.auto, 0) / total, jnp.sum(seg.csd, 0) / total, jnp.sum(seg.xy, 0) / total, omega,
                   jnp.arange(m) < seg.n_valid, seg.dof)


def coherence(spec: Spectra):
    """Each pair's magnitude-squared coherence |S12|^2 / (S11 S22): (2, M), 0 where a PSD is 0."""
    s11, s22 = spec.psd[0::2], spec.psd[1::2]
    both = (s11 > 0) & (s22 > 0)
    return jnp.where(both, jnp.square(jnp.abs(spec.csd)) / jnp.where(both, s11 * s22, 1.0), 0.0)


def leakage_only(psd, half_width: int = 3, drop_db=20.0):
    """Bins whose PSD lies ``drop_db`` below the highest within +/- ``half_width`` bins: (..., M) bool.

    Between the lines of a periodic texture the bins hold only the spectral window's
    leakage from the lines: coherent, but their ratio is the lines'.
    """
    m = psd.shape[-1]
    pad = jnp.pad(psd, [(0, 0)] * (psd.ndim - 1) + [(half_width, half_width)], mode="edge")
    local_max = pad[..., 0:m]
    for k in range(1, 2 * half_width + 1):
        local_max = jnp.maximum(local_max, pad[..., k:k + m])
    return psd < local_max * 10.0 ** (-drop_db / 10.0)


def _main_band(band):
    """The usable bins minus strays: every bin from the first one beyond 3 x (the previous usable bin) + 4.

    A lone coherent noise bin far above the band would set the fit's window and can capture
    the speed; a grating's harmonics (at most 2 x apart) are kept.
    """
    idx = jnp.arange(band.shape[-1])
    last = jax.lax.cummax(jnp.where(band, idx, -1), axis=band.ndim - 1)
    prev = jnp.concatenate([jnp.full(band.shape[:-1] + (1,), -1, last.dtype), last[..., :-1]], axis=-1)
    jump = band & (prev >= 0) & (idx > 3 * prev + 4)
    return band & ~(jnp.cumsum(jump, axis=-1) > 0)


def dominant_line(psd, log_ratio, band, log_gain, d1, d2):
    """Eq. 4 / 17 at the spectral peak when one line carries most of the band's power: k0 (rad/m) or NaN.

    A line: at least half the band's power within +/- 2 bins of the peak, at least 3 band bins,
    and a peak 10x above the bins 3 away. One pair's (M,) arrays.
    """
    m = psd.shape[-1]
    p = jnp.where(band, psd, 0.0)
    i = jnp.argmax(p)
    near = jnp.abs(jnp.arange(m) - i) <= 2
    line = jnp.sum(jnp.where(near, p, 0.0)) >= 0.5 * jnp.sum(p)
    lo, hi = psd[jnp.clip(i - 3, 0, m - 1)], psd[jnp.clip(i + 3, 0, m - 1)]
    ok = line & (jnp.sum(band) >= 3) & (i >= 3) & (i + 3 < m) & (psd[i] > 10 * lo) & (psd[i] > 10 * hi)
    return jnp.where(ok, dominant_wavenumber(1.0, jnp.exp(log_ratio[i] - log_gain), d1, d2), jnp.nan)


def select(spec: Spectra, depths, log_gains, *, min_snr, max_err, fmin, fmax, leakage_db, neighbours: int = 3,
           n_fit: int = 48) -> Band:
    """The usable band, closed-form starts and the fit's window of ``n_fit`` bins (see the module).

    depths: (2,) m. log_gains: (2,) log deep/shallow gain ratios of the pairs (known or 0).
    min_snr, max_err, fmin, fmax (Hz), leakage_db: ``fit.FitOptions``'s band settings (data).
    """
    s11 = spec.psd[0::2]
    mag = jnp.abs(spec.csd)
    ok = (mag > 0) & (s11 > 0) & spec.valid
    log_ratio = jnp.where(ok, jnp.log(jnp.where(ok, mag, 1.0)) - jnp.log(jnp.where(ok, s11, 1.0)), -jnp.inf)
    g2 = coherence(spec)
    live = spec.valid & (spec.omega > 0)
    g2_nb = neighbour_mean(jnp.where(live, g2, jnp.nan), neighbours)           # the live bins' neighbours'
    err = coherence_log_ratio_err(g2_nb, spec.dof)
    n_bins = jnp.maximum(jnp.sum(live), 1)
    significance = 1.0 - (COHERENCE_ALPHA / n_bins) ** (1.0 / jnp.maximum(spec.dof - 1.0, 1e-3))
    freq = spec.omega / (2.0 * jnp.pi)
    band = ((g2_nb > min_snr / (1.0 + min_snr)) & (g2_nb > significance) & (err <= max_err) & live & ok
            & (freq >= fmin) & (freq <= fmax) & (spec.dof > 1.0))
    leak = leakage_only(s11, 3, leakage_db)
    n_leak = jnp.sum(band & leak)
    band = _main_band(band & ~leak & (jnp.arange(band.shape[-1]) < spec.valid.sum() - 1))
    d1, d2 = depths[0], depths[1]
    line = slope_speed(spec.omega, log_ratio, err, band, d1, d2)
    speed0 = jnp.where(line.ok & jnp.isfinite(line.speed) & (line.speed > 0), line.speed, jnp.nan)
    a0 = radius_from_offset(line.intercept - log_gains, d1, d2)
    k0 = jax.vmap(dominant_line, in_axes=(0, 0, 0, 0, None, None))(s11, log_ratio, band, log_gains, d1, d2)
    any_band = band.any(axis=0)
    m = band.shape[-1]
    first = jnp.min(jnp.where(any_band, jnp.arange(m), m))
    i0 = jnp.clip(jnp.where(first < m, first, 1), 1, m - n_fit)
    return Band(log_ratio, err, g2, band, band.sum(-1), speed0, jnp.where(jnp.isfinite(speed0), a0, jnp.nan), k0,
                i0, n_leak)


def noise_floors(spec: Spectra):
    """(2, 2) log white-noise PSDs [[x1, x2], [y1, y2]]: medians above 3/4 of the estimate's top bin."""
    top = spec.omega[jnp.maximum(spec.valid.sum() - 1, 0)]
    tail = jnp.where((spec.omega >= 0.75 * top) & spec.valid, spec.psd, jnp.nan)
    return jnp.log(jnp.nanmedian(tail, axis=-1) + tiny(spec.psd)).reshape(2, 2)
