"""The compiled fitting program for a chunk of same-shape recordings (``batch``'s engine).

``fit_chunk(signals, meta, options, model=...)`` fits B recordings of shape
(4, N) at once with two jit-compiled, vmapped stages:

1. spectral stage (one program per (B, N) and options): spectra of every
   record (``spectra.estimate_spectra``, prewhitened as in ``fit``), H1 log
   amplitude ratios, usable-band masks (``spectra.usable_band`` minus
   leakage-only bins), Eq. 6 starting values (``closed_form.slope_speed``) and
   Eq. 4 dominant wavenumbers, all as arrays;
2. fitting stage (one program per (B, K) and solver, K a power of two: the
   window of bins that holds every fitted pair's band, or the most usable
   bins of a pair compacted, whichever needs fewer R evaluations, for the
   pair model; the window of bins that holds every record's band for the
   joint model; a batch of similar records compiles it once or twice): the
   exact-R pair model of ``pair_fit`` for both pairs of every record, by
   default with ``gauss_newton`` (a fixed number of Levenberg-Marquardt
   iterations over all B x 2 pairs at once; ``solver="optimistix"`` or
   ``"jaxopt"``: ``lsq.least_squares`` record by record, for comparison) and,
   for ``model="joint"``, the 2-D joint model of ``joint_model`` started from
   the pair fits (texture-only stage, then all parameters; two speed starts,
   the smaller chi-square kept; optimistix), mapped in sub-batches to bound
   memory.

Statuses are computed as arrays (``ok``, ``no_band``, ``not_converged``,
``poor_fit`` when the reduced chi-square exceeds 4, ``failed`` for non-finite
values); errors are the Gauss-Newton ones scaled as in ``fit``: the pair model's
by max(redchi, 1) x bin_factor, the joint model's by its delete-one-segment
jackknife (never below redchi; ``jackknife``). Unlike ``fit.fit_recording`` the batch uses one
Welch segment length for the whole chunk: the default for the recordings' N
(not for the N - p samples prewhitening leaves), refined for slow slips by
``fit``'s rule applied to the chunk's median record (``resolution_nperseg``; a
second spectral pass only then); a record that segment leaves ``no_band`` but
that wants a longer one is refitted at its own (``_refit_narrow``). The batch
reports no profile-likelihood bounds.
"""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ._numerics import tiny
from . import joint_model as jm
from .closed_form import radius_from_offset, slope_speed
from .fit import (MIN_PAIR_BAND_BINS, OWN_SCALE_PARAMS, FitOptions, conditioned_fields, dominant_line,
                  joint_jackknife, leakage_only, physics_settled, resolution_wants)
from .gauss_newton import N_ITERATIONS, gauss_newton
from .lsq import SOLVERS as LSQ_SOLVERS, STEP_TOL, least_squares
from .prewhiten import filter_gain
from .r_curve import log_g, log_r_exact
from jax.scipy.special import logsumexp
from .spectra import (amplitude_ratio, conditioned_psd, default_nperseg, estimate_spectra, neighbour_log_ratio_err, usable_band,
                      whitened_psd)

__all__ = ["MODELS", "SOLVERS", "ChunkMeta", "ChunkFit", "fit_chunk", "chunk_rows", "FitProgram", "resolution_nperseg"]

#: models the batch can fit
MODELS = ("pair", "joint")
#: solvers of the pair fits: "gauss_newton" (fixed-iteration LM over the whole chunk, the default) or
#: ``lsq.least_squares``'s ("optimistix", "jaxopt": one record after another on CPU)
SOLVERS = ("gauss_newton",) + tuple(LSQ_SOLVERS)

_MIN_PAIR_BINS = 5          # a pair needs this many usable bins to be fitted
_MIN_BINS = 6               # the record needs this many in all (as ``fit``)
_POOR_FIT_REDCHI = 4.0
_A_CLIP = (2e-5, 0.05)      # m: starting contact radii
_GRID_MARGIN = 6.0          # bins of model grid beyond the fitted bins (joint model)
_V_MAX = 10.0              # m/s: a pair's fitted speed above this has run away (as ``fit._V_BOUNDS``)
_MAX_SPAN = 48             # bins: a pair's window of fitted bins from its first usable one (the fitting stage's
                           # cost grows with it; bins beyond, the weakest, add little to |v| and a)
_JOINT_SUBBATCH = 8         # records per vmapped group inside the joint fit (memory bound)


def default_group(model: str, solver: str = "gauss_newton") -> int:
    """Records fitted side by side (vmapped) inside a chunk; the groups run one after another.

    ``gauss_newton`` runs a fixed number of iterations: the whole chunk side by side (0). With
    optimistix (a while_loop) every fit of a vmapped group takes as many LM steps as the slowest
    one. On CPU the step overhead dominates and one record at a time is fastest (measured: 32
    records in 0.9 s one at a time vs 2.3 s in groups of 8 and 3.7 s all at once, 2-core
    x86-64); on an accelerator the whole chunk side by side.
    """
    if model == "pair" and solver == "gauss_newton":
        return 0
    if jax.default_backend() == "cpu":
        return 1
    return _JOINT_SUBBATCH if model == "joint" else 0
#: LM steps of a pair fit: under vmap the slowest fit of a chunk sets everyone's pace, and a fit
#: that needs more (a pair hearing only leakage, its speed running away) is reported not_converged
PAIR_MAX_STEPS = 48


class ChunkMeta(NamedTuple):
    """Per-record inputs besides the signals, arrays with a leading B axis (SI units).

    fs: (B,) Hz. depths: (B, 2) m. gains: (B, 2) deep/shallow gain ratios (start values
    when fitted). velocity: (B, 2) known |vx|, |vy| in m/s (ignored where not ``known``).
    known: (B,) bool, the velocity is held fixed. curvature_radius: (B,) m.
    """

    fs: np.ndarray
    depths: np.ndarray
    gains: np.ndarray
    velocity: np.ndarray
    known: np.ndarray
    curvature_radius: np.ndarray


class ChunkFit(NamedTuple):
    """Per-record results as numpy arrays with a leading B axis (NaN: not determined).

    vx, vx_err, vy, vy_err: m/s. a, a_err: m. gx, gx_err, gy, gy_err: gain ratios.
    k0: (B, 2) rad/m. redchi, chi2, cond: fit statistics. n_bins: usable bins fitted.
    converged: bool. status: (B,) str. message: (B,) str. error_scale: the variance scale
    of the joint model's Laplace covariance from its jackknife, pooled over vx, vy, a (each
    of which has its own, as in ``fit``) (NaN: the pair model's
    max(redchi, 1) x bin_factor, or the joint one's max(redchi, 1) when the jackknife failed).
    """

    vx: np.ndarray
    vx_err: np.ndarray
    vy: np.ndarray
    vy_err: np.ndarray
    a: np.ndarray
    a_err: np.ndarray
    gx: np.ndarray
    gx_err: np.ndarray
    gy: np.ndarray
    gy_err: np.ndarray
    k0: np.ndarray
    redchi: np.ndarray
    chi2: np.ndarray
    cond: np.ndarray
    n_bins: np.ndarray
    converged: np.ndarray
    status: np.ndarray
    message: np.ndarray
    error_scale: np.ndarray | None = None


# --------------------------------------------------------------------------- stage 1: spectra and bands


def _spectra(x, fs, options: FitOptions, nperseg, leave_one_out: bool = False):
    kw = {"nperseg": nperseg} if (nperseg and options.method == "welch") else {}
    return estimate_spectra(x, fs, method=options.method, prewhiten=options.prewhiten, leave_one_out=leave_one_out,
                            **kw)


def _main_band(band):
    """The usable bins minus strays: the Nyquist bin, and every bin from the first one that lies
    beyond 3 x (the previous usable bin) + 4 bins (a lone coherent noise bin far above the band,
    frequent with long segments, would set the fit's window of bins and can capture the speed;
    a grating's harmonics, at most 2 x apart, are kept). band: (..., M) bool."""
    m = band.shape[-1]
    idx = jnp.arange(m)
    band = band & (idx < m - 1)
    last = jax.lax.cummax(jnp.where(band, idx, -1), axis=band.ndim - 1)
    prev = jnp.concatenate([jnp.full(band.shape[:-1] + (1,), -1, last.dtype), last[..., :-1]], axis=-1)
    jump = band & (prev >= 0) & (idx > 3 * prev + 4)
    return band & ~(jnp.cumsum(jump, axis=-1) > 0)



def resolution_nperseg(speed0, line_ok, fs, depths, n_samples: int, nperseg0: int, n_band=None,
                       min_band_bins: int = MIN_PAIR_BAND_BINS) -> int:
    """The chunk's Welch segment length: the median of ``resolution_wants`` over the records that want one.

    One length per chunk (one compiled shape); ``nperseg0`` when no record has anything to go by.
    A record the median leaves with too few bins is refitted at its own (``fit_chunk``).
    """
    return _median_want(resolution_wants(speed0, line_ok, fs, depths, n_samples, nperseg0, n_band, min_band_bins),
                        nperseg0)


def _median_want(wants, nperseg0: int) -> int:
    wants = np.sort(wants[wants > 0])
    return int(wants[(wants.size - 1) // 2]) if wants.size else nperseg0


@partial(jax.jit, static_argnames=("options", "nperseg", "joint"))
def _spectral_stage(signals, fs, depths, gains, *, options: FitOptions, nperseg, joint: bool = False):
    """Per record: spectra, ratio, band and the pair fits' starts; with ``joint``, also what the joint
    model alone reads (its errors, the conditioned deep PSDs, the jackknife's delete-one spectra)."""
    def one(x, f, d, g):
        spec = _spectra(x, f, options, nperseg)
        ratio = amplitude_ratio(spec)
        band = usable_band(ratio, min_snr=options.min_snr, max_err=options.max_err, fmin=options.fmin,
                           fmax=options.fmax, neighbours=options.band_neighbours)
        shallow = spec.psd[0::2]
        band = _main_band(band & ~leakage_only(shallow, 3, options.leakage_db))
        d1, d2 = d[0], d[1]
        line = slope_speed(ratio.omega, ratio.log_ratio, ratio.log_ratio_err, band, d1, d2)
        a_off = radius_from_offset(line.intercept - jnp.log(g), d1, d2)
        speed0 = jnp.where(line.ok & jnp.isfinite(line.speed), line.speed, 0.01)
        a0 = jnp.clip(jnp.where(jnp.isfinite(a_off), a_off, 2e-3), *_A_CLIP)
        k0 = jax.vmap(dominant_line, in_axes=(0, 0, 0, 0, None, None))(shallow, ratio.log_ratio, band, jnp.log(g),
                                                                     d1, d2)
        m = ratio.omega.shape[-1]
        any_band = band.any(axis=0)
        idx = jnp.arange(m)
        i_lo = jnp.maximum(jnp.min(jnp.where(any_band, idx, m)), 1)
        i_hi = jnp.max(jnp.where(any_band, idx, 0))
        white = spec.whitening if spec.whitening is not None else jnp.zeros((2, 1), shallow.dtype).at[:, 0].set(1.0)
        # the shallow spectra as the Welch average saw them (prewhitened): the pair model's kernel weights
        log_seen = jnp.log(jnp.clip(whitened_psd(spec)[0::2], tiny(x), None))
        out = dict(omega=ratio.omega, log_ratio=ratio.log_ratio, err=ratio.log_ratio_err, band=band,
                   shallow=shallow, log_seen=log_seen, speed0=speed0, a0=a0, k0=k0, i_lo=i_lo, i_hi=i_hi, white=white,
                   line_ok=line.ok & jnp.isfinite(line.speed) & (line.speed > 0))
        if not joint:
            return out
        # the joint model's errors from the neighbours' coherence, as fit.py's (``spectra.neighbour_log_ratio_err``);
        # the pair model keeps each bin's own: with the neighbours', the flat pair of a fast slip along x
        # (tests/test_batch.py) stopped reading as a runaway and left its record not_converged
        out.update(err_joint=neighbour_log_ratio_err(ratio, options.band_neighbours))
        # the delete-one-segment spectra of the jackknife
        loo = _spectra(x, f, options, nperseg, leave_one_out=True)
        out.update(loo_log_ratio=amplitude_ratio(loo).log_ratio, loo_shallow=loo.psd[:, 0::2])
        if options.conditioned:             # the conditioned deep PSDs (``fit.conditioned_fields``)
            out.update(c22=conditioned_psd(spec), psd=spec.psd, loo_c22=conditioned_psd(loo))
        return out

    return jax.vmap(one)(signals, fs, depths, gains)


def _kept_kernel(kernel):
    """The spectral kernel's (offsets in bins, weights) that matter to the pair model.

    Offsets whose weight is below 1e-20 of the largest (the Hann kernel's +/-2 and +/-3 bins:
    2e-33) change the model's logsumexp by < 1e-20: not evaluated (13 -> 9 per bin).
    """
    offsets, weights = (np.asarray(k, float) for k in kernel)
    keep = weights > 1e-20 * weights.max()
    return offsets[keep], weights[keep]


def _pair_span(band, kernel, n_fit: int) -> int:
    """The window of bins for the pair fits (``_pair_problems_grid``), or 0 for compacted bins.

    band: (B, 2, M) host array. Windows from each fitted pair's first usable bin, as long as the
    widest fitted band of the chunk (rounded up by ``_bucket``, at most ``_MAX_SPAN``), need 2 L + 4 h - 1 R values
    against ``n_fit`` J for compacted bins; the cheaper layout wins (the same residuals either way,
    except that a window drops the bins of a band wider than ``_MAX_SPAN``).
    """
    offsets, _ = _kept_kernel(kernel)
    if not np.allclose(2 * offsets, np.rint(2 * offsets)):
        return 0
    counts = band.sum(axis=-1)
    fitted = counts >= _MIN_PAIR_BINS
    if not fitted.any():
        return 0
    m = band.shape[-1]
    first = np.argmax(band, axis=-1)
    last = m - 1 - np.argmax(band[..., ::-1], axis=-1)
    span = min(_bucket(int(np.max(np.where(fitted, last - first + 1, 1))), 16), _MAX_SPAN, m)
    grid = 2 * span + 4 * float(np.max(np.abs(offsets)))
    return span if grid < n_fit * offsets.size else 0


def _bucket(n: int, least: int = 32) -> int:
    """A bin count rounded up to a power of two (at least ``least``): few shapes, few compilations."""
    return max(least, 1 << (max(int(n), 1) - 1).bit_length())


# --------------------------------------------------------------------------- stage 2: the fits


def _window(stage, i0, length):
    """Gather the L bins from ``i0`` of one record: bins (L,) rad/s, index (L,), valid (L,)."""
    omega = stage["omega"]
    m = omega.shape[-1]
    d_omega = omega[1] - omega[0]
    idx = i0 + jnp.arange(length)
    valid = idx < m
    idx = jnp.where(valid, idx, m - 1)
    om = d_omega * (i0 + jnp.arange(length))          # extrapolated past the end where not valid
    return om, idx, valid


def _kernel_weights(log_seen, pos, log_w):
    """Normalised log kernel weights (..., J) at kernel positions ``pos`` (..., J) in bins (any sign):
    ``pair_fit.kernel_log_weights`` in JAX. log_seen (M,): a pair's prewhitened shallow spectrum,
    taken log-linearly between bins at |pos|, the DC bin (notched by detrending) left out."""
    m = log_seen.shape[-1]
    w = log_w + jnp.interp(jnp.abs(pos), jnp.arange(1, m, dtype=log_seen.dtype), log_seen[1:])
    return w - logsumexp(w, axis=-1, keepdims=True)


def _pair_residuals(theta, args):
    """``pair_fit._residuals`` on any set of bins: the spectral-window average of R around each bin.

    args: omega (K,) rad/s (need not be contiguous), y, err, mask (K,), d1, d2 (m), offsets (J,)
    in rad/s (kernel offsets times the bin width), log_w (K, J) normalised log kernel weights
    times the prewhitened shallow spectrum there (``_kernel_weights``).
    """
    omega, y, err, mask, d1, d2, offsets, log_w = args
    log_v, log_a, log_g = theta[0], theta[1], theta[2]
    om = jnp.abs(omega[:, None] + offsets[None, :])
    log_r = log_r_exact(om / jnp.exp(log_v), d1, d2, jnp.exp(log_a))
    model = logsumexp(log_r + log_w, axis=-1) + log_g
    safe_err = jnp.where(mask, err, 1.0)
    return jnp.where(mask, (jnp.where(mask, y, 0.0) - model) / safe_err, 0.0)


def _pair_problems(stage, d, g, vel, known, n_fit, options, offsets, log_w):
    """Both pairs' least-squares problems on their usable bins, compacted to ``n_fit`` bins each.

    Returns theta0 (2, 3) = log|v|, log a, log g; args, ``_pair_residuals``'s, with a leading pair
    axis; free (2, 3) bool (nothing free for a pair with fewer than ``_MIN_PAIR_BINS`` bins).
    """
    omega = stage["omega"]
    d_omega = omega[1] - omega[0]
    band = stage["band"]
    order = jnp.argsort(~band, axis=-1, stable=True)[:, :n_fit]          # the usable bins first, in order
    mask = jnp.take_along_axis(band, order, axis=-1)
    om = omega[order]
    y = jnp.take_along_axis(stage["log_ratio"], order, axis=-1)
    err = jnp.take_along_axis(stage["err"], order, axis=-1)
    v0 = jnp.where(known, jnp.maximum(vel, 1e-4), stage["speed0"])
    theta0 = jnp.stack([jnp.log(v0), jnp.log(stage["a0"]), jnp.log(g)], axis=-1)         # (2, 3)
    free = jnp.stack([~known & jnp.ones(2, bool), jnp.ones(2, bool),
                      jnp.full(2, options.fit_gain)], axis=-1)
    # a pair with too few bins is not fitted (nothing free): under vmap the slowest fit sets the pace
    free = free & (jnp.sum(band, axis=-1) >= _MIN_PAIR_BINS)[:, None]
    two = jnp.ones(2)
    pos = om[:, :, None] / d_omega + offsets                                 # (2, n_fit, J) bins
    args = (om, y, err, mask, d[0] * two, d[1] * two, jnp.broadcast_to(offsets * d_omega, (2,) + offsets.shape),
            jax.vmap(_kernel_weights, in_axes=(0, 0, None))(stage["log_seen"], pos, log_w))
    return theta0, args, free


@dataclasses.dataclass(frozen=True)
class _GridResiduals:
    """``_pair_residuals`` for a window of L consecutive bins, R evaluated once per half bin.

    shifts: (J,) static grid index of each kernel offset for the window's first bin; the kernel
    offsets lie on half bins, so neighbouring bins share their R values: G = 2 L + 4 h - 1
    evaluations (h: the kernel's half width in bins) instead of L J. Bin l's offset j is grid
    entry 2 l + shifts[j], taken as static strided slices (an XLA gather here would evaluate R
    again for every gathered entry: measured 7x slower on CPU).
    args: omega_grid (G,) rad/s, |the half-bin grid| under the window and its kernel; y, err,
    mask (L,); d1, d2 (m); log_w (L, J) normalised log kernel weights with the prewhitened shallow
    spectrum in them (``_kernel_weights``). Hashable: a static solver argument.
    """

    shifts: tuple

    def _at(self, q, length):
        """(L, J): grid values q (G,) at each bin's kernel offsets."""
        return jnp.stack([q[k:k + 2 * length - 1:2] for k in self.shifts], axis=-1)

    def __call__(self, theta, args):
        omega_grid, y, err, mask, d1, d2, log_w = args
        log_v, log_a, log_g = theta[0], theta[1], theta[2]
        length = y.shape[-1]
        log_r = log_r_exact(omega_grid / jnp.exp(log_v), d1, d2, jnp.exp(log_a))
        model = logsumexp(self._at(log_r, length) + log_w, axis=-1) + log_g
        safe_err = jnp.where(mask, err, 1.0)
        return jnp.where(mask, (jnp.where(mask, y, 0.0) - model) / safe_err, 0.0)

    def value_and_jac(self, theta, args):
        """The residuals (L,) and their Jacobian (L, 3), R's two partials by forward mode per grid point.

        (About 3x faster than ``jax.jacfwd`` of ``__call__``, which carries three tangents
        through the kernel average; the test checks the two agree.)
        """
        omega_grid, y, err, mask, d1, d2, log_w = args
        log_v, log_a, log_g = theta[0], theta[1], theta[2]
        length = y.shape[-1]
        ones = jnp.ones_like(omega_grid)

        def curve(u, w):
            return log_r_exact(omega_grid / jnp.exp(u), d1, d2, jnp.exp(w))

        u, w = log_v * ones, log_a * ones
        log_r, d_v = jax.jvp(lambda u_: curve(u_, w), (u,), (ones,))
        _, d_a = jax.jvp(lambda w_: curve(u, w_), (w,), (ones,))

        def at(q):
            return self._at(q, length)

        z = at(log_r) + log_w
        lse = logsumexp(z, axis=-1)
        p = jnp.exp(z - lse[:, None])                                       # the kernel's softmax weights
        safe_err = jnp.where(mask, err, 1.0)
        r = jnp.where(mask, (jnp.where(mask, y, 0.0) - lse - log_g) / safe_err, 0.0)
        dm = jnp.stack([jnp.sum(p * at(d_v), axis=-1), jnp.sum(p * at(d_a), axis=-1), jnp.ones_like(lse)], axis=-1)
        jac = jnp.where(mask[:, None], -dm / safe_err[:, None], 0.0)
        return r, jac


def _grid_shifts(offsets) -> tuple:
    """``_GridResiduals.shifts`` for kernel offsets (bins, multiples of 1/2)."""
    half = float(np.max(np.abs(offsets)))
    return tuple(int(q) for q in np.rint(2 * (np.asarray(offsets) + half)))


def _pair_problems_grid(stage, d, g, vel, known, span, options, offsets, log_w):
    """``_pair_problems`` on each pair's window of ``span`` bins from its first usable bin (``_GridResiduals``).

    offsets: (J,) kernel offsets in bins, multiples of 1/2 (numpy, static).
    """
    theta0, _, free = _pair_problems(stage, d, g, vel, known, 1, options, jnp.asarray(offsets), log_w)
    omega = stage["omega"]
    m = omega.shape[-1]
    d_omega = omega[1] - omega[0]
    band = stage["band"]
    first = jnp.argmax(band, axis=-1)                                       # (2,): 0 where no band
    idx = first[:, None] + jnp.arange(span)[None, :]
    valid = idx < m
    idx = jnp.minimum(idx, m - 1)
    mask = jnp.take_along_axis(band, idx, axis=-1) & valid
    y = jnp.take_along_axis(stage["log_ratio"], idx, axis=-1)
    err = jnp.take_along_axis(stage["err"], idx, axis=-1)
    half = float(np.max(np.abs(offsets)))
    n_grid = 2 * (span - 1) + round(4 * half) + 1
    pos = first[:, None] + (jnp.arange(n_grid)[None, :] * 0.5 - half)        # in bins
    omega_grid = jnp.abs(pos * d_omega)
    two = jnp.ones(2)
    at = first[:, None, None] + jnp.arange(span)[None, :, None] + jnp.asarray(offsets)      # (2, L, J) bins
    args = (omega_grid, y, err, mask, d[0] * two, d[1] * two,
            jax.vmap(_kernel_weights, in_axes=(0, 0, None))(stage["log_seen"], at, log_w))
    return theta0, args, free


def _pair_fits(stage, d, g, vel, known, n_fit, options, offsets, log_w, bin_factor, solver, span=0):
    """Exact-R fits of both pairs of one record with ``solver``: on windows of ``span`` bins
    (``_pair_problems_grid``) when ``span`` > 0, else on ``n_fit`` compacted bins (``_pair_problems``).

    offsets: (J,) kernel offsets in bins (numpy). Returns an ``LsqResult`` with a leading pair
    axis: theta (2, 3) = log|v|, log a, log g.
    """
    if span:
        theta0, args, free = _pair_problems_grid(stage, d, g, vel, known, span, options, offsets, log_w)
        residuals = _GridResiduals(_grid_shifts(offsets))
    else:
        theta0, args, free = _pair_problems(stage, d, g, vel, known, n_fit, options, jnp.asarray(offsets), log_w)
        residuals = _pair_residuals

    def one(th0, a, fr):
        if solver == "gauss_newton":
            return gauss_newton(residuals, th0, a, fr, n_iter=N_ITERATIONS, bin_factor=bin_factor,
                                value_and_jac=getattr(residuals, "value_and_jac", None))
        return least_squares(residuals, th0, a, fr, solver=solver, bin_factor=bin_factor,
                             max_steps=PAIR_MAX_STEPS)

    return jax.vmap(one)(theta0, args, free)


def _knot_start(log_k_obs, phi_obs, sel, log_knots):
    """log Phi at the knots: a Gaussian-weighted mean (in log k) of the observed values."""
    h = log_knots[1] - log_knots[0]
    out = []
    for width in (h, 100.0 * h):
        w = jnp.where(sel[None, :], jnp.exp(-0.5 * jnp.square((log_k_obs[None, :] - log_knots[:, None]) / width)), 0.0)
        sw = jnp.sum(w, axis=-1)
        out.append((jnp.sum(w * jnp.where(sel, phi_obs, 0.0)[None, :], axis=-1) / jnp.where(sw > 0, sw, 1.0), sw))
    (near, sw_near), (far, _) = out
    return jnp.where(sw_near > 1e-6, near, far)


def _joint_fit(stage, d, g, vel, known, i0, pair, options, length, kernel, banded, rel_grid, dof, bin_factor,
               overlap):
    """The joint 2-D model of one record from the pair fits' starts; the best of two speed starts."""
    om, idx, valid = _window(stage, i0, length)
    d1, d2 = d[0], d[1]
    d_omega = stage["omega"][1] - stage["omega"][0]
    band = stage["band"]
    mask = band[:, idx] & valid[None, :]
    shallow = stage["shallow"]
    log_s11 = jnp.log(jnp.clip(shallow[:, idx], tiny(shallow), None))
    lr = jnp.where(mask, stage["log_ratio"][:, idx], 0.0)
    lr_err = jnp.where(mask, stage["err_joint"][:, idx], 1.0)
    n_band = jnp.sum(band, axis=-1)
    # starts from the pair fits (as fit.py): speeds where a pair was fitted, a from the better-determined pair
    theta_p, cov_p = pair.theta, pair.cov
    v_pair = jnp.exp(theta_p[:, 0])
    fitted = (n_band >= _MIN_PAIR_BINS) & pair.converged & jnp.isfinite(v_pair)
    any_fit = jnp.any(fitted)
    fallback = jnp.where(any_fit, 0.05 * jnp.max(jnp.where(fitted, v_pair, 0.0)), 0.02)
    v0 = jnp.where(known, vel, jnp.where(fitted, v_pair, fallback))
    rel_a = jnp.sqrt(jnp.clip(cov_p[:, 1, 1], 0, None))
    rel_a = jnp.where(fitted & (rel_a > 0), rel_a, jnp.inf)
    a0 = jnp.exp(theta_p[jnp.argmin(rel_a), 1])
    a0 = jnp.clip(jnp.where(jnp.isfinite(a0) & jnp.any(jnp.isfinite(rel_a)), a0, 2e-3), *_A_CLIP)
    v_scale = jnp.maximum(jnp.max(v0), 1e-4)
    log_v0 = jnp.log(jnp.maximum(v0, 1e-3 * v_scale))
    # texture knots from the shallow spectrum of the faster pair that has a band
    main = jnp.argmax(jnp.where(n_band > 0, v0, -jnp.inf))
    k_lo = 0.5 * om[0] / jnp.max(v0)
    k_hi = 25.0 / (2.0 * d1)
    log_knots = jnp.linspace(jnp.log(k_lo), jnp.log(jnp.maximum(k_hi, 4 * k_lo)), options.n_knots)
    sel = band[main]
    k_obs = stage["omega"] / v0[main]
    log_k_obs = jnp.log(jnp.where(k_obs > 0, k_obs, 1.0))
    phi_obs = (jnp.log(jnp.clip(shallow[main], tiny(shallow), None)) + jnp.log(v0[main]) - 2 * log_g(k_obs, d1, a0)
               - jnp.log(jnp.sqrt(3 * jnp.pi) / a0))
    log_phi0 = _knot_start(log_k_obs, phi_obs, sel & (k_obs > 0), log_knots)
    m = shallow.shape[-1]
    noise0 = jnp.log(jnp.median(shallow[:, m - m // 4:]) + tiny(shallow))
    theta0 = jnp.concatenate([log_v0, jnp.stack([jnp.log(a0), jnp.log(g[0]), jnp.log(g[1]), 0.0,
                                                 noise0 if options.noise_floor else -700.0]), log_phi0])
    n_par = theta0.shape[0]
    free = jnp.ones(n_par, bool)
    free = free.at[:2].set(~known)
    free = free.at[3:5].set(options.fit_gain)
    free = free.at[6].set(options.noise_floor)
    free = free.at[5].set(n_band[1] > 0)
    prior_inv_sd = jnp.zeros(n_par).at[:3].set(1.0 / 3.0).at[3:5].set(0.5)
    prior_inv_sd = jnp.where(free, prior_inv_sd, 0.0)
    grid = jnp.abs(om[0] + d_omega * rel_grid)
    fs = stage["fs"]
    white_grid = jnp.log(filter_gain(stage["white"], grid, fs))
    white_bin = jnp.log(filter_gain(stage["white"], om, fs))
    s11_weight = jnp.sqrt(dof / max(bin_factor, 1.0))
    data = jm.ModelData(om, log_s11, lr, lr_err, mask, mask, s11_weight, grid, kernel, log_knots,
                        jnp.stack([d1, d2]), theta0, prior_inv_sd, jnp.asarray(1.0 / options.smoothness),
                        white_grid, white_bin, *banded)
    if options.conditioned:
        data = data._replace(**conditioned_fields(stage["c22"][:, idx], om, stage["psd"], stage["omega"], dof, mask,
                                                  use=True, noise_floor=options.noise_floor))
    n_prior = jm.n_prior_residuals(n_par)
    # second start: the axis with more shallow power as the major one, the other at 0.15 of it
    power = jnp.sum(jnp.where(band, shallow, 0.0), axis=-1)
    major = jnp.argmax(power)
    v_major = v0[major]
    alt = jnp.where(jnp.arange(2) == major, jnp.log(v_major), jnp.log(0.15 * v_major))
    starts = jnp.stack([log_v0, jnp.where(known, log_v0, alt)])
    stage1 = free.at[:5].set(False).at[6].set(False)

    def from_start(lv):
        th0 = theta0.at[:2].set(lv)
        fit1 = least_squares(jm.residuals, th0, data, stage1, solver="optimistix", max_steps=256, n_prior=n_prior)
        th1 = jnp.where(jnp.isfinite(fit1.theta), fit1.theta, th0)
        return least_squares(jm.residuals, th1, data, free, solver=options.solver, max_steps=256, n_prior=n_prior)

    fits = jax.vmap(from_start)(starts)
    chi2 = jnp.where(jnp.isfinite(fits.chi2), fits.chi2, jnp.inf)
    best = jnp.argmin(chi2)
    fit = jax.tree_util.tree_map(lambda t: t[best], fits)
    # the error bars' variance scale from the delete-one-segment jackknife, as ``fit_recording``'s
    *_, scale = joint_jackknife(fit.theta, free, data, stage["loo_log_ratio"], stage["loo_shallow"], idx, overlap,
                                fit.redchi, c22_k=stage["loo_c22"] if options.conditioned else None, jac=fit.jac)
    return fit, free, scale


def _summarise_pair(pair, n_band, known, vel, options):
    """Per-record estimates from the two pair fits (arrays)."""
    redchi = pair.redchi
    inflate = jnp.where(redchi > 0, jnp.maximum(redchi, 1.0) / jnp.where(redchi > 0, redchi, 1.0), 1.0)
    sd = jnp.sqrt(jnp.clip(jnp.diagonal(pair.cov, axis1=-2, axis2=-1) * inflate[..., None], 0, None))   # (2, 3)
    th = jnp.exp(pair.theta)
    fitted = n_band >= _MIN_PAIR_BINS
    # a pair whose ratio is flat (no slip along it: the fitted speed runs away, unconverged, with an
    # error bar beyond half its value or a speed above 10 m/s) determines nothing; it does not make
    # the record not_converged when the other pair converged
    runaway = fitted & ~known & ~pair.converged & ((sd[:, 0] > 0.5) | (th[:, 0] > _V_MAX) | ~jnp.isfinite(sd[:, 0]))
    runaway = runaway & jnp.any(fitted & ~runaway)
    speed = jnp.where(known, vel, jnp.where(fitted & ~runaway, th[:, 0], jnp.nan))
    speed_err = jnp.where(known | ~fitted | runaway, jnp.nan, th[:, 0] * sd[:, 0])
    a_rel = jnp.where(fitted & ~runaway & (th[:, 1] > 0), sd[:, 1], jnp.inf)
    best = jnp.argmin(a_rel)
    a = jnp.where(jnp.any(fitted), th[best, 1], jnp.nan)
    a_err = jnp.where(jnp.any(fitted), th[best, 1] * sd[best, 1], jnp.nan)
    weak = jnp.any(fitted) & ((a_err > 0.5 * a) | (a > 0.05))     # the window is too weak to measure a (as fit.py)
    a, a_err = jnp.where(weak, jnp.nan, a), jnp.where(weak, jnp.nan, a_err)
    gain = th[:, 2]
    gain_err = jnp.where(options.fit_gain & fitted, gain * sd[:, 2], jnp.nan)
    f = fitted.astype(redchi.dtype)
    n_f = jnp.maximum(jnp.sum(f), 1.0)
    used = fitted & ~runaway
    return dict(speed=speed, speed_err=speed_err, a=a, a_err=a_err, a_weak=weak, gain=gain, gain_err=gain_err,
                redchi=jnp.sum(f * redchi) / n_f, chi2=jnp.sum(f * pair.chi2),
                cond=jnp.max(jnp.where(used, pair.cond, 0.0)), runaway=runaway,
                converged=jnp.all(pair.converged | ~used) & jnp.any(used),
                finite=jnp.all(jnp.isfinite(jnp.where(used[:, None], pair.theta, 0.0)))
                & jnp.all(jnp.isfinite(jnp.where(fitted, pair.chi2, 0.0))),
                n_bins=jnp.sum(jnp.where(fitted, pair.n_data, 0)), enough=jnp.any(fitted))


def _summarise_joint(fit, free, known, vel, n_band, scale):
    redchi = fit.redchi
    # the jackknife's scales (P,) (``fit.joint_jackknife``: vx, vy, a each their own, the rest the pooled
    # one), else max(redchi, 1); lsq's cov carries redchi
    used = jnp.where(jnp.isfinite(scale), scale, jnp.maximum(redchi, 1.0))
    inflate = jnp.where(redchi > 0, used / jnp.where(redchi > 0, redchi, 1.0), 1.0)
    sd = jnp.sqrt(jnp.clip(jnp.diagonal(fit.cov) * inflate, 0, None))
    th = jnp.exp(fit.theta[:5])
    speed = jnp.where(known, vel, th[:2])
    speed_err = jnp.where(known, jnp.nan, th[:2] * sd[:2])
    a, a_err = th[2], th[2] * sd[2]
    weak = (a_err > 0.5 * a) | (a > 0.05)                    # the window is too weak to measure a (as fit.py)
    gain = th[3:5]
    gain_err = jnp.where(free[3:5], gain * sd[3:5], jnp.nan)
    # stopped at max_steps with only texture knots still moving: the physics stands (fit._settled_physics)
    settled = ~fit.converged & physics_settled(fit, free)
    return dict(speed=speed, speed_err=speed_err, a=jnp.where(weak, jnp.nan, a),
                a_err=jnp.where(weak, jnp.nan, a_err), a_weak=weak, gain=gain, gain_err=gain_err,
                redchi=redchi, chi2=fit.chi2, cond=fit.cond, converged=fit.converged | settled, settled=settled,
                finite=jnp.all(jnp.isfinite(fit.theta)) & jnp.isfinite(fit.chi2),
                n_bins=jnp.sum(n_band), enough=jnp.sum(n_band) >= _MIN_BINS,
                error_scale=scale[len(OWN_SCALE_PARAMS)])            # the pooled one (NaN: no jackknife)


@partial(jax.jit, static_argnames=("options", "model", "length", "n_fit", "kernel", "dof", "bin_factor", "group",
                                   "solver", "span", "overlap"))
def _fit_stage(stage, depths, gains, velocity, known, *, options: FitOptions, model: str, length: int, n_fit: int,
               kernel: tuple, dof: float, bin_factor: float, group: int, solver: str, span: int = 0,
               overlap: float = 1.0):
    offsets, weights = (np.asarray(k, float) for k in kernel)
    offsets_k, weights_k = _kept_kernel(kernel)
    log_w = jnp.asarray(np.log(weights_k))
    half = max(float(np.max(np.abs(offsets))), _GRID_MARGIN)
    rel_grid = np.arange(-half, (length - 1) + half + 0.25, 0.5)               # in bins, from the first bin
    kmat = np.zeros((length, rel_grid.size))
    for o, w in zip(offsets, weights):
        pos = np.rint((np.arange(length) + o + half) / 0.5).astype(int)
        kmat[np.arange(length), pos] += w
    banded = tuple(jnp.asarray(v) for v in jm.banded_kernel(kmat))
    kmat = jnp.asarray(kmat)
    rel_grid = jnp.asarray(rel_grid)

    def one(st, d, g, vel, kn):
        n_band = jnp.sum(st["band"], axis=-1)
        any_band = n_band.sum() > 0
        i0 = jnp.where(any_band, st["i_lo"], 1)
        pair = _pair_fits(st, d, g, vel, kn, n_fit, options, offsets_k, log_w, bin_factor, solver, span)
        if model == "pair":
            return _summarise_pair(pair, n_band, kn, vel, options)
        fit, free, scale = _joint_fit(st, d, g, vel, kn, i0, pair, options, length, kmat, banded, rel_grid, dof,
                                      bin_factor, overlap)
        return _summarise_joint(fit, free, kn, vel, n_band, scale)

    xs = (stage, depths, gains, velocity, known)
    return jax.lax.map(lambda args: one(*args), xs, batch_size=group)


# --------------------------------------------------------------------------- the program


@dataclasses.dataclass
class FitProgram:
    """The compiled chunk program and what it has compiled (for a batch: reuse one instance).

    options: ``fit.FitOptions`` (spectral settings, band selection, gains, solver).
    model: ``"pair"`` or ``"joint"``. nperseg: Welch segment length (None: the default for N).
    solver: the pair fits' solver, one of ``SOLVERS``: ``"gauss_newton"`` (default: a fixed
    number of Levenberg-Marquardt iterations over the whole chunk, ``gauss_newton``) or
    ``"optimistix"`` / ``"jaxopt"`` (``lsq.least_squares``, for comparison). The joint
    model's own fits always use ``options.solver``.
    group: records vmapped side by side in the fitting stage (0: the whole chunk; None:
    ``default_group``).
    layout: how the pair fits see their bins: ``"auto"`` (a window of consecutive bins with R
    evaluated once per half bin, when that is cheaper) or ``"compact"`` (the usable bins
    gathered, R evaluated at every bin's kernel offsets); the same residuals either way.
    resolution: without ``nperseg``, refine the segment length per chunk for slow slips
    (``resolution_nperseg``: a second spectral pass when the chunk's median record wants it).
    ``timings`` accumulates seconds per stage; ``last_nperseg`` is the last chunk's segment length.
    """

    options: FitOptions = FitOptions()
    model: str = "pair"
    nperseg: int | None = None
    group: int | None = None
    solver: str = "gauss_newton"
    layout: str = "auto"
    resolution: bool = True
    timings: dict = dataclasses.field(default_factory=lambda: {"spectra": 0.0, "fit": 0.0})
    last_nperseg: int | None = None

    def __post_init__(self):
        if self.model not in MODELS:
            raise ValueError(f"unknown model {self.model!r}; expected one of {MODELS}")
        if self.solver not in SOLVERS:
            raise ValueError(f"unknown solver {self.solver!r}; expected one of {SOLVERS}")
        if self.nperseg is None and self.options.nperseg:
            self.nperseg = int(self.options.nperseg)
        if self.group is None:
            self.group = default_group(self.model, self.solver)

    def __call__(self, signals, meta: ChunkMeta) -> ChunkFit:
        return fit_chunk(signals, meta, self)


def fit_chunk(signals, meta: ChunkMeta, program: FitProgram) -> ChunkFit:
    """Fit a chunk of B records (``signals``: (B, 4, N), float32 or float64) with ``program``.

    Returns a :class:`ChunkFit` of numpy arrays. Precision: float64 when
    ``jax_enable_x64`` is on (the signals are cast), else float32.
    """
    import time

    options = program.options
    dtype = jnp.float64 if jax.config.jax_enable_x64 else jnp.float32
    x = jnp.asarray(signals, dtype)
    fs = jnp.asarray(meta.fs, dtype)
    depths = jnp.asarray(meta.depths, dtype)
    gains = jnp.asarray(meta.gains, dtype)
    velocity = jnp.abs(jnp.asarray(meta.velocity, dtype))
    known = jnp.asarray(meta.known, bool)
    t0 = time.perf_counter()
    nperseg, wants = program.nperseg, None
    if program.resolution and nperseg is None and options.method == "welch":
        # the default for the recording's N, not for the N - p samples that prewhitening leaves
        # (8192 -> 1024, not 512: coarse bins bias the speed of slow slips, see benchmarks/README.md)
        nperseg = default_nperseg(x.shape[-1])
    joint = program.model == "joint"
    stage = _spectral_stage(x, fs, depths, gains, options=options, nperseg=nperseg, joint=joint)
    if program.resolution and program.nperseg is None and options.method == "welch":
        nperseg0 = nperseg
        # the pair model wants MIN_PAIR_BAND_BINS usable bins, the joint model FitOptions.min_band_bins
        floor = MIN_PAIR_BAND_BINS if program.model == "pair" else options.min_band_bins
        wants = resolution_wants(np.asarray(stage["speed0"]), np.asarray(stage["line_ok"]), np.asarray(meta.fs),
                                 np.asarray(meta.depths), x.shape[-1], nperseg0,
                                 n_band=np.asarray(stage["band"]).sum(axis=-1) if floor else None,
                                 min_band_bins=floor)
        finer = _median_want(wants, nperseg0)
        if finer > nperseg0:
            nperseg = finer
            stage = _spectral_stage(x, fs, depths, gains, options=options, nperseg=nperseg, joint=joint)
    program.last_nperseg = 2 * (stage["omega"].shape[-1] - 1)
    stage["fs"] = fs
    i_lo, i_hi, band = (np.asarray(stage[k]) for k in ("i_lo", "i_hi", "band"))
    t1 = time.perf_counter()
    program.timings["spectra"] += t1 - t0
    has = band.any(axis=(1, 2))
    span = int(np.max(np.where(has, i_hi - i_lo + 1, 1))) if has.size else 1
    length = _bucket(span) if program.model == "joint" else 0        # the joint model's window of bins
    n_fit = min(_bucket(int(band.sum(axis=-1).max())), band.shape[-1])  # the pair fits' bins per pair
    spec_meta = jax.eval_shape(lambda s, f: _spectra(s, f, options, nperseg), x[0], fs[0])
    kernel = tuple(map(tuple, spec_meta.kernel))
    pair_span = _pair_span(band, kernel, n_fit) if program.layout == "auto" else 0
    out = _fit_stage(stage, depths, gains, velocity, known, options=options, model=program.model,
                     length=length, n_fit=n_fit, kernel=kernel, dof=float(spec_meta.dof),
                     bin_factor=float(spec_meta.bin_factor), group=int(program.group), solver=program.solver,
                     span=pair_span, overlap=float(spec_meta.n_segments / spec_meta.dof))
    out = {k: np.asarray(v) for k, v in out.items()}
    program.timings["fit"] += time.perf_counter() - t1
    k0 = np.asarray(stage["k0"])
    fit = _statuses(out, k0, np.asarray(meta.known, bool), program)
    if wants is not None:
        fit = _refit_narrow(signals, meta, program, fit, wants, nperseg)
    return fit


def _refit_narrow(signals, meta: ChunkMeta, program: FitProgram, fit: ChunkFit, wants, nperseg: int) -> ChunkFit:
    """Records that the chunk's segment left ``no_band`` but that want a longer one, refitted at theirs.

    The chunk shares one segment length, its median record's; a slow, noisy record among faster ones
    has a band of 1-3 bins there. Those records are fitted again, grouped by the segment they want
    (one more compiled shape per group), and their rows say so.
    """
    redo = (fit.status == "no_band") & (wants > nperseg)
    if not redo.any():
        return fit
    merged = {k: None if v is None else np.array(v, copy=True) for k, v in fit._asdict().items()}
    for want in np.unique(wants[redo]):
        sel = np.flatnonzero(redo & (wants == want))
        sub = dataclasses.replace(program, nperseg=int(want), resolution=False, timings=program.timings)
        part = fit_chunk(np.asarray(signals)[sel], ChunkMeta(*(np.asarray(m)[sel] for m in meta)), sub)
        for k, v in part._asdict().items():
            if merged[k] is not None:
                merged[k][sel] = v
        notes = [f"refitted with {int(want)}-sample segments (the chunk's {nperseg} left {int(n)} usable bins)"
                 for n in fit.n_bins[sel]]
        merged["message"][sel] = [f"{note}; {m}" if m else note for note, m in zip(notes, part.message)]
    return ChunkFit(**merged)


def _statuses(out: dict, k0, known, program: FitProgram) -> ChunkFit:
    b = out["redchi"].shape[0]
    status = np.full(b, "ok", dtype=object)
    message = np.full(b, "", dtype=object)
    model = program.model
    solver = program.solver if model == "pair" else f"{program.options.solver}, pair starts {program.solver}"
    for i in range(b):
        notes = []
        if not out["enough"][i]:
            status[i] = "no_band"
            message[i] = (f"only {int(out['n_bins'][i])} usable bins (coherent, deep probe above noise, not leakage): "
                          "too few to fit; check the gains, the SNR or the band limits")
            continue
        if not out["finite"][i]:
            status[i] = "failed"
            message[i] = "the fit produced non-finite values"
            continue
        if not out["converged"][i]:
            status[i] = "not_converged"
            notes.append(f"the solver did not converge ({solver})")
        elif "settled" in out and out["settled"][i]:
            notes.append("the solver stopped at its step limit with texture knots still moving; the speeds, radius "
                         f"and gains were settled (a full Gauss-Newton step moves them by < {STEP_TOL} sigma)")
        if out["redchi"][i] > _POOR_FIT_REDCHI and status[i] == "ok":
            status[i] = "poor_fit"
            notes.insert(0, f"poor fit: reduced chi-square {out['redchi'][i]:.1f}; the {model} model does not describe "
                            "these spectra: check the plot before trusting the numbers")
        if out["a_weak"][i]:
            notes.append("the contact window is too weak to measure a")
        if model == "pair" and not known[i]:
            for p, name in ((0, "vx"), (1, "vy")):
                if "runaway" in out and out["runaway"][i, p]:
                    notes.append(f"{name} not determined: its pair's log ratio is flat (the fitted speed runs away)")
                elif not np.isfinite(out["speed"][i, p]):
                    notes.append(f"{name} not determined: fewer than {_MIN_PAIR_BINS} usable bins in its pair")
        if out["cond"][i] > 1e10:
            notes.append(f"near-degenerate parameters (condition number {out['cond'][i]:.2g})")
        message[i] = "; ".join(notes)
    bad = np.isin(status, ("no_band", "failed"))
    def blank(v):
        v = np.array(v, dtype=float)
        v[bad] = np.nan
        return v
    return ChunkFit(vx=blank(out["speed"][:, 0]), vx_err=blank(out["speed_err"][:, 0]),
                    vy=blank(out["speed"][:, 1]), vy_err=blank(out["speed_err"][:, 1]),
                    a=blank(out["a"]), a_err=blank(out["a_err"]),
                    gx=blank(out["gain"][:, 0]), gx_err=blank(out["gain_err"][:, 0]),
                    gy=blank(out["gain"][:, 1]), gy_err=blank(out["gain_err"][:, 1]),
                    k0=np.asarray(k0, float), redchi=blank(out["redchi"]), chi2=blank(out["chi2"]),
                    cond=blank(out["cond"]), n_bins=np.asarray(out["n_bins"], int),
                    converged=np.asarray(out["converged"], bool) & ~bad, status=status, message=message,
                    error_scale=blank(out["error_scale"]) if "error_scale" in out else np.full(b, np.nan))


def chunk_rows(fit: ChunkFit, meta: ChunkMeta, files, indices, *, model: str, options: FitOptions,
               solver: str | None = None) -> list[dict]:
    """Data-contract rows (``fit.RESULT_FIELDS`` plus fit statistics) for the records of a chunk.

    solver: the name written to the rows (the program's pair solver for the pair model; default
    ``options.solver``).
    """
    from .fit import RESULT_FIELDS

    precision = "float64" if jax.config.jax_enable_x64 else "float32"

    def num(v):
        v = float(v)
        return v if np.isfinite(v) else None

    rows = []
    for i, (src, index) in enumerate(zip(files, indices)):
        row = dict.fromkeys(RESULT_FIELDS)
        r = float(meta.curvature_radius[i])
        a, a_err = num(fit.a[i]), num(fit.a_err[i])
        row.update(file=str(src), index=int(index), vx=num(fit.vx[i]), vx_err=num(fit.vx_err[i]),
                   vy=num(fit.vy[i]), vy_err=num(fit.vy_err[i]), a=a, a_err=a_err,
                   contact_depth=None if a is None else a * a / r,
                   contact_depth_err=None if (a is None or a_err is None) else 2 * a * a_err / r,
                   gain_ratio=num(fit.gx[i]), gain_ratio_err=num(fit.gx_err[i]),
                   k0x=num(fit.k0[i, 0]), k0y=num(fit.k0[i, 1]), model=model, window=options.window,
                   converged=bool(fit.converged[i]), status=str(fit.status[i]), message=str(fit.message[i]))
        row.update(gain_ratio_y=num(fit.gy[i]), gain_ratio_y_err=num(fit.gy_err[i]), redchi=num(fit.redchi[i]),
                   n_bins=int(fit.n_bins[i]), cond=num(fit.cond[i]), solver=solver or options.solver, precision=precision)
        scale = None if fit.error_scale is None else num(fit.error_scale[i])
        row.update(error_scale=scale, error_method=(
            "laplace x jackknife (vx, vy, a each their own)" if scale is not None else
            "laplace x max(redchi, 1) x bin_factor" if model == "pair" else "laplace x max(redchi, 1)"))
        rows.append(row)
    return rows
