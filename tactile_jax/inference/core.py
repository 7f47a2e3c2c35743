"""The joint fit's steps as pure, fixed-shape functions: what ``analysis`` composes into one program.

``core(record, settings)`` goes from grouped periodogram products
(``segments``) to a ``Summary`` of arrays:

1. spectra, the usable band and the closed-form starts on the fixed grid (``band.select``);
2. the fit's window of ``N_FIT`` bins from the first usable one, and on it the measured
   blocks, their masks and weights (``data``);
3. starting values: each pair fitted alone with the exact R curve (from its Eq. 6 speed and
   Eq. 26 radius; the Hertz disk's own starts from each pair's Hertz curve), and two more
   speed starts that take each axis in turn as the major one (a pair that hears only window
   leakage mimics a fast slip along it); the texture knots from the shallow spectrum
   (``prepare``; with ``both_windows`` for both windows at once);
4. each start: the texture alone with the physics held, then every parameter; the lowest
   cost goes on (``solve.levenberg_marquardt``: one loop of fixed iterations, no
   data-dependent control flow, so records vmap side by side);
5. the Laplace covariance and the delete-one-group jackknife of the data blocks pushed
   through the Gauss-Newton map: vx, vy and a each take their own variance ratio, the
   other parameters the three pooled, none below the reduced chi-square; where the
   misfit's spread across frequency (``_spread``) is over twice that (in a poor fit: larger), it sets
   the ratio (``errors``);
6. an integer status (``STATUS``) and the reported values (``finish``).

``analysis.analyse`` runs steps 1-3 once and then a schedule of solves (step 4) with every
model choice; ``core`` is one window's single solve, from its own starts or a given ``Start``.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import digamma

from .._numerics import tiny
from .gauss_newton import gauss_newton
from .lsq import equilibrated_inverse, fit_statistics
from .pair_fit import exact_residuals, hertz_table_residuals
from ..spectral.prewhiten import filter_response
from ..model.r_curve import log_g
from ..spectral import band as band_mod
from ..spectral.band import MIN_BINS as MIN_BINS
from .data import N_DATA_ROWS, N_FIT, N_LUMP, N_LUMP_SD, JointData, grid_offsets, half_offsets, measure
from .forward import ANISO, INDEX, N_PHYS, ModelSpectra, spectra_at_bins
from .residuals import N_LUMP_SERIES, blocks, lump_dof, n_lump_rows, n_prior, residuals_and_model, row_bins, row_series
from .solve import levenberg_marquardt
from ..spectral.segments import KERNEL_OFFSETS, Segments
from ..model.spline import log_phi_at

__all__ = ["STATUS", "Settings", "Record", "Start", "Summary", "Located", "Prepared", "core", "no_start", "start_at",
           "candidates", "scouting", "prepare",
           "finish", "errors", "Errors", "fit_status", "summary_at", "band_bins", "N_KNOTS", "ITERATIONS", "step_bounds",
           "PHYS_STEP", "KNOT_STEP"]

#: integer status codes of ``Summary.status``
STATUS = ("ok", "no_band", "not_converged", "poor_fit", "failed")
N_KNOTS = 12
#: fixed iterations: per start on the texture alone, per start in all, then from the best start
ITERATIONS = (3, 7, 18)
#: the speed starts of ``prepare`` (step 3 of the module), and how many of them each window's program explores
N_STARTS = 5
OWN_STARTS = {"gaussian": 3, "hertz": 5}
POOR_FIT_REDCHI = 2.0
#: a stop counts as converged when a full Gauss-Newton step would lower chi2 by less than this...
DECREMENT_TOL = 1e-2
#: ... or move every free non-texture parameter by less than this many of its sigmas
STEP_TOL = 0.1
#: the largest move of a parameter in one iteration (log space): a factor e for the physics, gains and levels, whose
#: larger steps jump between basins, and e^3 for the texture's knots. A knot the data barely constrain (the spline's
#: end beyond the band) asks for steps of 6-20; held to the physics' bound, it scales every other parameter's step
#: down as much, and a solve crawls. With the knots' own bound the 128 oblique records of benchmarks/throughput.py's
#: pool take 4,697 iterations against 5,212, with the same statuses and windows and values within 0.02 of their
#: errors (docs/speed.md)
PHYS_STEP, KNOT_STEP = 1.0, 3.0
#: the final iterations stop once the decrement still to go is below this (chi2 units): the parameters are then
#: within about 0.03 of their sigmas of where the full count of iterations would take them
STOP_TOL = 1e-3
_A_CLIP = (2e-5, 0.05)
_OWN = 3          # vx, vy, a: each its own jackknife scale
#: adjacent bins per cluster of the spread across frequency (``_spread``), and the variance ratio over the
#: jackknife's scale beyond which that spread (its plain sandwich) sets a parameter's error; in a poor fit the
#: larger of the two errors stands
SPREAD_BINS = 2
SPREAD_GATE = 2.0
#: largest leverage of one cluster in the spread's delete-one-cluster shifts (1 / (1 - h) at most 10)
MAX_LEVERAGE = 0.9
#: the misfit's trend test (``_roughness``): the degree of its smooth part and the fewest rows a series needs.
#: A poor fit is a lumpy texture's (``Summary.lumpy``) where at least ``LUMPY_SERIES`` series have a trend ratio,
#: their median at most ``LUMPY_F`` bin factors and their largest at most ``LUMPY_F_MAX`` ones: its misfit has no
#: trend in any block; the analysis refits it with the texture at each bin as random effects (``residuals``).
#: Three series are enough for the test: a 2 s window of a slip along x (``track``, 3 cm/s, 2 mm disk) has 3 such
#: series where others have 12-15; asking 8 leaves such windows' right fits ``poor_fit`` (``benchmarks/track.py``'s
#: constant slips: 24 of 1,220 windows, all of them right)
ROUGHNESS_DEGREE = 5
ROUGHNESS_MIN_ROWS = 14
LUMPY_SERIES = 3
LUMPY_F = 2.0
LUMPY_F_MAX = 5.0
#: a Hertz disk's radius per Gaussian window radius of the same second moment along a probe (a^2/5 = a_g^2/3)
HERTZ_PER_GAUSS = (5.0 / 3.0) ** 0.5


class Settings(NamedTuple):
    """The fit's options as data (scalars; one compiled program for every choice).

    min_snr, max_err, fmin, fmax (Hz), leakage_db: band selection (``band.select``).
    smoothness: prior sd of the log texture spectrum's second differences between knots.
    noise_floor, fit_gain: fit a shallow white-noise floor / the pairs' gain ratios.
    conditioned: fit the conditioned deep PSDs. chain: blocks of the y pair conditioned on the x pair
    (0: none, 1: y1 on (x1, x2) in place of y1's PSD, 2: also y2 on (x1, x2, y1) in place of the y
    ratio and S22.1). directional: fit the texture's angular factor (``forward.ANISO``; held at 0 otherwise).
    hertz: the contact window: None for the Gaussian, or the Hertz window's table coefficients
    (``model.hertz.hertz_table().coef``: data, so that every record of a window shares one program).
    """

    min_snr: float = 1.0
    max_err: float = 0.5
    fmin: float = -np.inf
    fmax: float = np.inf
    leakage_db: float = 20.0
    smoothness: float = 1.0
    noise_floor: bool = False
    fit_gain: bool = False
    conditioned: bool = True
    chain: int = 2
    directional: bool = False
    hertz: jax.Array | None = None

    @property
    def window(self) -> str:
        """The contact window these settings fit: "gaussian" or "hertz" (one compiled program each)."""
        return "gaussian" if self.hertz is None else "hertz"


class Record(NamedTuple):
    """One record's inputs: ``seg`` (``Segments``), depths (2,) m, gains (2,) deep/shallow gain ratios
    (known, or the start when fitted), velocity (2,) |vx|, |vy| m/s held fixed where ``known``."""

    seg: Segments
    depths: jax.Array
    gains: jax.Array
    velocity: jax.Array
    known: jax.Array


class Summary(NamedTuple):
    """What ``core`` returns (arrays; a leading batch axis under ``vmap``).

    theta: (P,) fitted parameters (``model.PARAMS`` then the knots); cov: (P, P) covariance with
    the error scales applied; sd: (P,) its root diagonal; free: (P,) fitted ones. scales: (P,)
    variance scales of the unit Laplace covariance (jackknife or fallback); pooled: the pooled
    one. chi2, redchi, n_data, cond, decrement, step_sigma: fit statistics (``lsq``). converged,
    settled: the solve's stop, and whether only texture knots were still moving. status: index
    into ``STATUS``. n_bins: usable bins fitted. located: ``Located``. jackknife: whether the
    scales came from the jackknife. model: ``model.ModelSpectra`` at theta. jac: (R, P) the
    residuals' Jacobian there. texture: (3, 2, L) the texture cross-sections of Eq. 18 / 19 along x and y
    (``texture_sections``). data: the ``JointData`` (for what ``fit`` layers on top). spread: (P,) where
    the misfit's spread across frequency (``_spread``) set the variance scale. roughness: the misfit's trend
    ratio (``_roughness``, the median); lumpy: a poor fit whose misfit has no trend, a lumpy texture's. ends:
    (``N_STARTS``, P) where each start's exploration ended (``Start``; a start not explored as it began).
    """

    theta: jax.Array
    cov: jax.Array
    sd: jax.Array
    free: jax.Array
    scales: jax.Array
    pooled: jax.Array
    chi2: jax.Array
    redchi: jax.Array
    n_data: jax.Array
    cond: jax.Array
    decrement: jax.Array
    step_sigma: jax.Array
    converged: jax.Array
    settled: jax.Array
    status: jax.Array
    n_bins: jax.Array
    located: "Located"
    jackknife: jax.Array
    model: ModelSpectra
    jac: jax.Array
    texture: jax.Array
    data: JointData
    spread: jax.Array
    roughness: jax.Array
    lumpy: jax.Array
    ends: jax.Array | None = None


def _window(x, i0):
    """x (..., M) -> (..., N_FIT) from bin i0."""
    start = (0,) * (x.ndim - 1) + (i0,)
    return jax.lax.dynamic_slice(x, start, x.shape[:-1] + (N_FIT,))


def _log_kernel(kernel):
    return jnp.where(kernel > 0, jnp.log(jnp.clip(kernel, tiny(kernel), None)), -2e4)


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


def _pair_fits(om, log_ratio, err, band, depths, log_gains, speed0, a0, log_kernel, fit_gain, hertz=None):
    """Each pair alone with the exact R curve (the starts of the joint fit): (speed, a, a's relative error,
    usable) per pair. A pair that hears only window leakage (slip across it) has a flat ratio: its speed
    runs away or its fit does not settle, and it is not usable. hertz: the Hertz table's coefficients, for
    the Hertz disk's curve (None: the Gaussian window's). The Gaussian curve cannot follow a large disk's
    ratio at a slow slip (its radius runs away), so the Hertz program's own starts use the disk's."""
    def one(y, e, m, g, v, a):
        theta0 = jnp.stack([jnp.log(v), jnp.log(a), g])
        free = jnp.array([True, True, False]) | (jnp.arange(3) == 2) & fit_gain
        # pair_fit's exact-R model, averaged by the spectral window on the fixed kernel grid
        args = (om, y, e, m, depths[0], depths[1], jnp.asarray(KERNEL_OFFSETS, om.dtype), log_kernel)
        if hertz is None:
            fit = gauss_newton(exact_residuals, theta0, args, free)
        else:
            fit = gauss_newton(hertz_table_residuals, theta0, args + (hertz,), free)
        sd = jnp.sqrt(jnp.clip(jnp.diag(fit.cov) * jnp.maximum(fit.redchi, 1.0) / jnp.maximum(fit.redchi, tiny(
            fit.redchi)), 0.0, None))
        speed = jnp.exp(fit.theta[0])
        # the Hertz curve's last steps creep (its edge term): within STEP_TOL sigma of its optimum it has settled
        settled = fit.converged | ((hertz is not None) & jnp.all(jnp.abs(fit.step_sigma) < STEP_TOL))
        ok = settled & jnp.all(jnp.isfinite(fit.theta)) & (jnp.sum(m) >= 5) & (speed < 10.0) & (sd[0] < 0.5)
        return speed, jnp.exp(fit.theta[1]), sd[1], ok

    v = jnp.where(jnp.isfinite(speed0), speed0, 0.02)
    a = jnp.where(jnp.isfinite(a0), a0, 2e-3)
    return jax.vmap(one)(log_ratio, err, band, log_gains, v, jnp.clip(a, *_A_CLIP))


class Prepared(NamedTuple):
    """``prepare``'s output: data (``JointData``), starts (``N_STARTS``, P) parameter vectors, free (P,) the
    fitted parameters, first (P,) those of the texture-only iterations, band (``band.Band``)."""

    data: JointData
    starts: jax.Array
    free: jax.Array
    first: jax.Array
    band: band_mod.Band


def _speed_radius(v_pair, a_pair, a_rel, have, known, velocity):
    """The start's speeds (2,) and radius from the pairs' fits (``_pair_fits``): each usable pair's speed (a
    known one as given; a pair with none at 0.05 of the fastest), the radius of the best-measured pair."""
    v_any = jnp.where(have.any(), jnp.max(jnp.where(have, v_pair, 0.0)), 0.02)
    v0 = jnp.where(known, velocity, jnp.where(have, v_pair, 0.05 * v_any))
    v0 = jnp.maximum(v0, 1e-3 * jnp.maximum(jnp.max(v0), 1e-4))
    a_rel = jnp.where(have & (a_rel > 0), a_rel, jnp.inf)
    return v0, jnp.clip(jnp.where(jnp.isfinite(a_rel).any(), a_pair[jnp.argmin(a_rel)], 2e-3), *_A_CLIP)


def prepare(record: Record, settings: Settings, own_starts=True, both_windows: bool = False, pair_fits: bool = True):
    """Steps 1-3 of the module. own_starts: (traced) whether the program's own starts are wanted (not where a
    start is given); the Hertz program then fits each pair with the Hertz curve for them. pair_fits: False
    for a caller that brings its own parameters, knots and prior (``track``): the starts are then Eq. 6's
    speeds and Eq. 26's radius, without the pairs' fits. both_windows: the
    ``Prepared`` of each window, (Gaussian, Hertz), and a function that gives the Hertz disk's own starts
    (each pair fitted with the disk's curve: call it only where they are wanted, they cost ten times the
    rest); ``settings.hertz`` holds the table, or None for the Gaussian window's alone."""
    seg = record.seg
    spec = band_mod.spectra(seg)
    depths = record.depths
    log_gains = jnp.log(record.gains)
    b = band_mod.select(spec, depths, log_gains, min_snr=settings.min_snr, max_err=settings.max_err,
                        fmin=settings.fmin, fmax=settings.fmax, leakage_db=settings.leakage_db, n_fit=N_FIT)
    i0 = b.i0
    d_omega = seg.d_omega
    om = d_omega * (i0 + jnp.arange(N_FIT))
    band_w = _window(b.band, i0)
    psd_w, csd_w, xy_w = _window(spec.psd, i0), _window(spec.csd, i0), _window(spec.xy, i0)
    meas, w1, w2 = measure(psd_w, csd_w, xy_w, spec.dof)
    dof = spec.dof
    low = om >= 1.5 * d_omega
    c22 = psd_w[1::2] - jnp.square(jnp.abs(csd_w)) / jnp.where(psd_w[0::2] > 0, psd_w[0::2], 1.0)
    mask_h = band_w
    mask_c22 = band_w & (c22 > 0) & low & settings.conditioned & (dof > 2.0)
    both = band_w[0].any() & band_w[1].any()
    blocks_on = (jnp.asarray(settings.chain) >= jnp.array([1, 2]))[:, None]
    mask_xy = jnp.stack([band_w[1], band_w[1]]) & meas.chain_ok & low & blocks_on & both
    mask_s11 = band_w.at[1].set(band_w[1] & ~mask_xy[0])
    mask_h = mask_h.at[1].set(mask_h[1] & ~mask_xy[1])
    mask_c22 = mask_c22.at[1].set(mask_c22[1] & ~mask_xy[1])
    n_reg = jnp.array([2.0, 3.0])
    k_xy = jnp.maximum(dof - n_reg, 1.0)
    k1 = jnp.maximum(dof - 1.0, 1.0)
    # the prewhitening filters on the half-bin grid of the kernel and at the bins
    offsets = half_offsets()
    half = d_omega * (i0 + offsets)
    resp_h = filter_response(seg.whitening, half, seg.fs)
    resp_b = filter_response(seg.whitening, om, seg.fs)
    d1 = depths[0]

    # ---- starting values: Eq. 6 speeds, Eq. 26 radius, texture knots from the faster pair's shallow spectrum
    known = record.known
    data_kernel = _log_kernel(seg.kernel)
    pair_args = (om, _window(b.log_ratio, i0), _window(b.err, i0), band_w, depths, log_gains, b.speed0, b.a0,
                 data_kernel, settings.fit_gain)
    _build = functools.partial(_build_prepared, b=b, spec=spec, om=om, i0=i0, band_w=band_w, depths=depths,
                               log_gains=log_gains, known=known, settings=settings, meas=meas, w1=w1, w2=w2,
                               d_omega=d_omega, data_kernel=data_kernel, resp_h=resp_h, resp_b=resp_b,
                               offsets=offsets, mask_h=mask_h, mask_c22=mask_c22, mask_xy=mask_xy,
                               mask_s11=mask_s11, dof=dof, k1=k1, k_xy=k_xy, d1=d1)
    if pair_fits:
        v0, a0 = _speed_radius(*_pair_fits(*pair_args), known, record.velocity)
    else:
        have = jnp.isfinite(b.speed0) & jnp.isfinite(b.a0)
        v0, a0 = _speed_radius(jnp.where(have, b.speed0, 0.02), jnp.where(have, b.a0, 2e-3), jnp.ones(2), have,
                               known, record.velocity)

    def hertz_starts():     # each pair fitted with the Hertz curve
        return _speed_radius(*_pair_fits(*pair_args, settings.hertz), known, record.velocity)

    if both_windows:            # (the Gaussian window's twice in a program without the Hertz disk)
        gauss = _build(False, v0, a0, v0, a0)
        if settings.hertz is None:
            return gauss, gauss, lambda: gauss.starts
        a_h = a0 * HERTZ_PER_GAUSS
        return gauss, _build(True, v0, a_h, v0, a_h), lambda: _build(True, v0, a_h, *hertz_starts()).starts
    if settings.hertz is None:
        return _build(False, v0, a0, v0, a0)
    # the pair fits give Gaussian radii: a Hertz disk of equal second moment; the program's own starts,
    # wanted only where no start is given
    a_h = a0 * HERTZ_PER_GAUSS
    return _build(True, v0, a_h, *jax.lax.cond(own_starts, hertz_starts, lambda: (v0, a_h)))


def band_bins(record: Record, settings: Settings):
    """The usable bins a fit of ``record`` would have (``Summary.n_bins``: both pairs' band in the fit's window,
    as ``prepare`` places it) and the ``Located`` band, without the fit: a record with fewer than ``MIN_BINS``
    is ``no_band`` whatever the fit."""
    b = band_mod.select(band_mod.spectra(record.seg), record.depths, jnp.log(record.gains), min_snr=settings.min_snr,
                        max_err=settings.max_err, fmin=settings.fmin, fmax=settings.fmax,
                        leakage_db=settings.leakage_db, n_fit=N_FIT)
    return jnp.sum(_window(b.band, b.i0)), Located(b.i0, b.n_leak, b.k0, b.speed0)


def _build_prepared(hertz_window, v0, a0, v_s, a_s, *, b, spec, om, i0, band_w, depths, log_gains, known, settings,
                    meas, w1, w2, d_omega, data_kernel, resp_h, resp_b, offsets, mask_h, mask_c22, mask_xy, mask_s11,
                    dof, k1, k_xy, d1) -> Prepared:
    """The rest of ``prepare`` for one window: the starts' texture, the data and the starts (v0, a0: the
    prior's centre; v_s, a_s: the starts' speeds and radius)."""
    main = jnp.argmax(jnp.where(b.n_band > 0, v0, -jnp.inf))
    k_lo = 0.5 * om[0] / jnp.max(v0)
    k_hi = 25.0 / (2.0 * d1)
    log_knots = jnp.linspace(jnp.log(k_lo), jnp.log(jnp.maximum(k_hi, 4 * k_lo)), N_KNOTS)
    shallow = spec.psd[0::2]

    def texture_start(v, axis, a):
        """log Phi at the knots from the shallow spectrum of ``axis``'s pair, read at k = omega / v."""
        k_obs = spec.omega / v
        sel = b.band[axis] & (k_obs > 0)
        log_k_obs = jnp.log(jnp.where(k_obs > 0, k_obs, 1.0))
        phi_obs = (jnp.log(jnp.clip(shallow[axis], tiny(shallow), None)) + jnp.log(v) - 2 * log_g(k_obs, d1, a)
                   - jnp.log(jnp.sqrt(3 * jnp.pi) / a))
        return _knot_start(log_k_obs, phi_obs, sel, log_knots)

    log_phi0 = texture_start(v0[main], main, a0)
    floors = band_mod.noise_floors(spec)
    noise = jnp.where(settings.noise_floor, floors.at[:, 0].set(-700.0), floors)
    noise0 = jnp.where(settings.noise_floor, jnp.log(jnp.mean(jnp.exp(floors[:, 0]))), -700.0)
    i = INDEX
    theta0 = jnp.zeros(N_PHYS + N_KNOTS, log_phi0.dtype)
    theta0 = theta0.at[jnp.array([i["log_vx"], i["log_vy"]])].set(jnp.log(v0)).at[i["log_a"]].set(jnp.log(a0))
    theta0 = theta0.at[i["log_gx"]].set(log_gains[0]).at[i["log_gy"]].set(log_gains[1])
    theta0 = theta0.at[i["log_noise"]].set(noise0).at[N_PHYS:].set(log_phi0)
    p = theta0.shape[0]
    idx = jnp.arange(p)
    speed = (idx == i["log_vx"]) | (idx == i["log_vy"])
    gain = (idx == i["log_gx"]) | (idx == i["log_gy"])
    aniso = jnp.isin(idx, jnp.array([i[name] for name in ANISO]))
    free = jnp.ones(p, bool)
    free = jnp.where(speed, ~known, free)
    free = jnp.where(gain, settings.fit_gain, free)
    free = jnp.where(idx == i["log_noise"], settings.noise_floor, free)
    free = jnp.where(aniso, settings.directional, free)
    free = jnp.where(idx == i["log_ay"], band_w[1].any(), free)    # nothing measures the y level without a band
    # weak priors: log speeds and log a (sd 3), log gains (sd 2), the angular factor (sd 2)
    prior_inv_sd = jnp.where(speed | (idx == i["log_a"]), 1.0 / 3.0, jnp.where(gain | aniso, 0.5, 0.0))
    # a fixed parameter's prior residual is constant; the angular factor's prior stays on for a refit that frees it
    prior_inv_sd = jnp.where(free | aniso, prior_inv_sd, 0.0)
    data = JointData(
        meas=meas, omega=om,
        grid_abs=jnp.abs(d_omega * (i0 + (offsets if hertz_window else jnp.asarray(grid_offsets())))),
        log_kernel=data_kernel,
        white_half=jnp.log(jnp.abs(resp_h) ** 2), white_bin=jnp.log(jnp.abs(resp_b) ** 2),
        xy_white_half=jnp.conj(resp_h[0]) * resp_h[1], xy_white_bin=jnp.conj(resp_b[0]) * resp_b[1],
        depths=depths, log_k_knots=log_knots, h_err=jnp.where(mask_h | band_w, _window(b.err, i0), 1.0),
        w1=w1, w2=w2, mask_s11=mask_s11, mask_h=mask_h, mask_c22=mask_c22, mask_xy=mask_xy,
        s11_weight=jnp.sqrt(dof), c22_weight=jnp.sqrt(k1), c22_offset=digamma(k1) - digamma(k1 + 1.0),
        xy_c_weight=jnp.sqrt(k_xy), xy_c_offset=digamma(k_xy) - digamma(dof), log_noise=noise,
        prior_center=theta0, prior_inv_sd=prior_inv_sd, smooth_inv_sd=1.0 / jnp.asarray(settings.smoothness),
        lump_sd=jnp.zeros(N_LUMP_SD, theta0.dtype), lump_rows=jnp.zeros((N_DATA_ROWS, N_LUMP), theta0.dtype))
    # speed starts: as found, and each axis in turn as the major one at its own pair's speed, the other at
    # 0.15 of it (a pair that hears only window leakage, slip across it, reads as a fast slip along it); then
    # each axis with the other at 0.01 of it, which the Hertz window, whose sharp edge leaks more, explores too
    alt = [jnp.where(jnp.arange(2) == m, jnp.log(v_s[m]), jnp.log(f * v_s[m])) for f in (0.15, 0.01) for m in (0, 1)]
    iv = jnp.array([i["log_vx"], i["log_vy"]])
    starts = jnp.stack([jnp.log(v_s)] + [jnp.where(known, jnp.log(v_s), s) for s in alt])

    def start(lv):          # each start's texture read at its own major speed
        axis = jnp.argmax(lv)
        return (theta0.at[iv].set(lv).at[i["log_a"]].set(jnp.log(a_s))
                .at[N_PHYS:].set(texture_start(jnp.exp(lv[axis]), axis, a_s)))

    stage1 = free & ((idx >= N_PHYS) | (idx == i["log_ay"]))          # the texture and the y level, physics held
    return Prepared(data, jax.vmap(start)(starts), free, stage1, b)


def statistics(theta, r, jac, free, data: JointData):
    """``lsq.fit_statistics`` of the joint residuals: cov (unit x redchi), chi2, n_data, dof, redchi, cond,
    decrement, step_sigma. The texture random effects' rows count in chi2 (the penalty of their marginal
    quadratic form), not as data, and the effects take their degrees of freedom (``residuals.lump_dof``)."""
    return fit_statistics(theta, r, jac, free, n_prior=n_prior(theta.shape[0]), n_aux=n_lump_rows(data),
                          n_effects=lump_dof(data))


def settled_physics(step_sigma, free):
    """Every free non-texture parameter's remaining Gauss-Newton step is below ``STEP_TOL`` sigma."""
    step = jnp.abs(step_sigma)
    physics = free & (jnp.arange(step.shape[-1]) < N_PHYS)
    return jnp.all(jnp.isfinite(step)) & jnp.all(jnp.where(physics, step < STEP_TOL, True))


def _jackknife(record: Record, theta, jac, free, unit, data: JointData, i0, redchi, hertz):
    """Variance scales (P,) from the delete-one-group jackknife, the pooled one, and whether it ran; unit: the
    unit Laplace covariance (``_unit_inverse``)."""
    seg = record.seg
    total = jnp.sum(seg.count)
    n_groups = jnp.sum(seg.count > 0)

    def one(g):
        c = jnp.maximum(total - seg.count[g], 1.0)
        psd = _window(jnp.sum(seg.auto, 0) - seg.auto[g], i0) / c
        csd = _window(jnp.sum(seg.csd, 0) - seg.csd[g], i0) / c
        xy = _window(jnp.sum(seg.xy, 0) - seg.xy[g], i0) / c
        m, _, _ = measure(psd, csd, xy, seg.dof)
        ok = m.chain_ok
        full = data.meas
        return m._replace(beta1=jnp.where(ok[0][:, None], m.beta1, full.beta1),
                          beta2=jnp.where(ok[1][:, None], m.beta2, full.beta2),
                          log_c=jnp.where(ok, m.log_c, full.log_c), chain_ok=full.chain_ok)

    meas_k = jax.vmap(one)(jnp.arange(seg.count.shape[0]))
    # the blocks are linear in the measured side with the weights held: the model cancels from the change
    zero = jax.tree.map(jnp.zeros_like, jax.eval_shape(spectra_at_bins, theta, data, hertz))
    r0 = blocks(zero, data.meas, data)
    d_r = jax.vmap(lambda m: blocks(zero, m, data))(meas_k) - r0                   # (G, R_data)
    jac_d = jac[:d_r.shape[1]] * free                                               # the data rows
    shifts = -(d_r @ jac_d) @ unit                                                  # (G, P)
    use = seg.count > 0
    g = jnp.maximum(n_groups, 2)
    per_group = total / g
    overlap = 1.0 + (seg.overlap - 1.0) / per_group
    scales, pooled = _ratios(shifts, use, g, unit, free, overlap)
    scales = jnp.maximum(scales, redchi)
    ran = (n_groups >= 5) & jnp.isfinite(pooled) & (pooled > 0) & jnp.all(jnp.isfinite(scales))
    return scales, jnp.maximum(pooled, redchi), ran


def _unit_inverse(jac, free):
    """(J^T J)^-1 over ``free`` (P, P), zero elsewhere: the unit Laplace covariance."""
    d, _, inv = equilibrated_inverse(jac.T @ jac * (free[:, None] & free[None, :]), free)
    return jnp.where(free[:, None] & free[None, :], inv / (d[:, None] * d[None, :]), 0.0)


def _ratios(shifts, use, g, unit, free, factor=1.0):
    """Variance ratios (P,) over the unit Laplace variances of the delete-one shifts (G, P) of the ``g`` groups
    where ``use``: vx, vy and a each their own, the others the three's mean (the pooled one, returned too)."""
    mean = jnp.sum(jnp.where(use[:, None], shifts, 0.0), 0) / g
    dev = jnp.where(use[:, None], shifts - mean, 0.0)
    var = (g - 1) / g * jnp.sum(dev * dev, 0) * factor
    var_unit = jnp.diag(unit)
    own = free & (jnp.arange(free.shape[0]) < _OWN) & (var_unit > 0)
    ratio = var / jnp.where(own, var_unit, 1.0)
    n_own = jnp.sum(own)
    pooled = jnp.where(n_own > 0, jnp.sum(jnp.where(own, ratio, 0.0)) / jnp.maximum(n_own, 1), jnp.nan)
    return jnp.where(own, ratio, pooled), pooled


def _cluster_rows(data: JointData) -> np.ndarray:
    """(C, R) the rows of ``blocks`` in each cluster of ``SPREAD_BINS`` adjacent bins, -1 padding (static:
    from the shapes alone)."""
    cluster = row_bins(data) // SPREAD_BINS
    counts = np.bincount(cluster)
    idx = np.full((counts.size, int(counts.max())), -1)
    for c, rows in enumerate(np.split(np.argsort(cluster, kind="stable"), np.cumsum(counts)[:-1])):
        idx[c, :rows.size] = rows
    return idx


def _spread(r, jac, free, unit, data: JointData):
    """The misfit's spread across frequency: the delete-one-cluster jackknife, linearised, over clusters of
    ``SPREAD_BINS`` adjacent bins, each cluster holding every block's rows at its bins; unit: the unit Laplace
    covariance. The segment jackknife cannot see a misfit that every segment shares: a texture of a few
    hundred modes has the same lumpy spectrum in every segment. Returns the variance ratios (P,) and the
    pooled one of the bias-reduced cluster sandwich (CR3), then those of the plain sandwich (CR1). For a
    model that fits, each scatters about the reduced chi-square.

    Leaving cluster c out moves the solution by U J_c^T (I - H_c)^-1 r_c (Woodbury; U the unit covariance,
    H_c = J_c U J_c^T the cluster's leverage, each eigenvalue capped at ``MAX_LEVERAGE``); the plain sandwich
    takes H_c = 0, and runs low where the clusters are few for the parameters. On 50 scenes of 300
    plane-wave modes (24 clusters, a dozen free parameters; Gaussian window) its pulls have a robust sd of
    1.2 and a 1-sigma coverage of vx, vy, a of 60 / 56 / 54 %, the corrected one's 1.0 and 64 / 58 / 72 %.
    The plain one is the steadier test of whether a misfit is shared (``finish``)."""
    idx = _cluster_rows(data)
    valid = jnp.asarray(idx >= 0)
    take = jnp.asarray(np.maximum(idx, 0))
    jc = jnp.where(valid[..., None], (jac * free)[take], 0.0)                       # (C, R, P)
    rc = jnp.where(valid, r[take], 0.0)                                             # (C, R)
    lev, vec = jnp.linalg.eigh(jnp.einsum("crp,pq,csq->crs", jc, unit, jc))
    lev = jnp.clip(lev, 0.0, MAX_LEVERAGE)
    e = jnp.einsum("crk,ck,csk,cs->cr", vec, 1.0 / (1.0 - lev), vec, rc)           # (I - H_c)^-1 r_c
    use = jnp.sum(rc != 0, -1) > 0
    g = jnp.maximum(jnp.sum(use), 2)
    # the shifts U J_c^T e_c; _ratios' (g - 1) / g times their centred sum of squares is the jackknife's, and
    # (g / (g - 1))^2 of that the plain sandwich's g / (g - 1)
    corrected = _ratios(jnp.einsum("crp,cr->cp", jc, e) @ unit, use, g, unit, free)
    plain = _ratios(jnp.einsum("crp,cr->cp", jc, rc) @ unit, use, g, unit, free, jnp.square(g / (g - 1)))
    return corrected + plain


def _lumpy(poor, r, data: JointData, bin_factor):
    """The misfit's trend ratio (``_roughness``'s median) and whether a poor fit is a lumpy texture's: no trend
    across frequency in any block (at least ``LUMPY_SERIES`` series tested, their median at most ``LUMPY_F`` bin
    factors, their largest at most ``LUMPY_F_MAX``)."""
    roughness, largest, n_series = _roughness(r, data)
    factor = jnp.maximum(bin_factor, 1.0)
    flat = (roughness <= LUMPY_F * factor) & (largest <= LUMPY_F_MAX * factor)
    return roughness, poor & (n_series >= LUMPY_SERIES) & flat


def _roughness(r, data: JointData):
    """Whether a misfit is lumpy or systematic: for each series of the residuals across frequency (``row_series``),
    the F ratio of its smooth part (a Legendre polynomial of degree ``ROUGHNESS_DEGREE`` in the bin, fitted to the
    series' rows in use) per degree of freedom over what is left per degree of freedom. Returns the median and
    the largest over the series with at least ``ROUGHNESS_MIN_ROWS`` rows (nan where none has), and their number.
    A model that describes the spectra leaves residuals whose smooth part is their share, scaled by the bins'
    correlation: about the bin factor. A wrong model (another window, a wrong basin) leaves a trend across
    frequency: medians of 3.05-64 on ``benchmarks/lumpy.py``'s scenes fitted with the wrong window. A lumpy
    texture (persistent modes every segment hears) scatters the spectra from bin to bin, far above the segments'
    noise, and leaves no trend (medians of 0.29-2.93), except where a solve ended in a wrong basin: there one
    block keeps a trend (its largest ratio 9-30)."""
    idx = row_series(data)[:-N_LUMP_SERIES]                                          # the data's series
    y = r[jnp.asarray(idx)]                                                         # (S, L)
    use = y != 0
    n = jnp.sum(use, -1)
    b = jnp.arange(idx.shape[1], dtype=r.dtype)
    lo = jnp.min(jnp.where(use, b, idx.shape[1]), -1, keepdims=True)
    hi = jnp.max(jnp.where(use, b, 0), -1, keepdims=True)
    t = 2.0 * (b - lo) / jnp.maximum(hi - lo, 1) - 1.0
    # Legendre polynomials by their recurrence, orthonormalised over the rows in use (modified Gram-Schmidt:
    # a small fixed basis; a batched QR per series would be a LAPACK call under vmap)
    basis = [jnp.ones_like(t), t]
    for k in range(1, ROUGHNESS_DEGREE):
        basis.append(((2 * k + 1) * t * basis[k] - k * basis[k - 1]) / (k + 1))
    proj = jnp.zeros(y.shape[:-1], r.dtype)
    done = []
    for v in basis[:ROUGHNESS_DEGREE + 1]:
        v = jnp.where(use, v, 0.0)
        for q in done:
            v = v - jnp.sum(q * v, -1, keepdims=True) * q
        q = v / jnp.sqrt(jnp.maximum(jnp.sum(v * v, -1, keepdims=True), tiny(r)))
        done.append(q)
        proj = proj + jnp.square(jnp.sum(q * y, -1))
    k = ROUGHNESS_DEGREE + 1
    rest = jnp.maximum(jnp.sum(y * y, -1) - proj, tiny(r))
    ratio = jnp.where(n >= ROUGHNESS_MIN_ROWS, (proj / k) / (rest / jnp.maximum(n - k, 1)), jnp.nan)
    return jnp.nanmedian(ratio), jnp.nanmax(ratio), jnp.sum(n >= ROUGHNESS_MIN_ROWS)


class Start(NamedTuple):
    """Where ``core`` starts its final solve.

    use: from ``theta`` (``N_STARTS``, P) over ``free`` (P,) instead of exploring the program's own starts:
    from the first row, or, of the first ``n`` rows, from the one of lowest cost under the program's window
    (a refit: ``start_at``; the Hertz window from the Gaussian program's ends: ``candidates``). scout:
    explore all ``N_STARTS`` of the program's own starts and stop at their ends (``Summary.ends``), with no
    final iterations (``scouting``). lumps, lump_rows: the texture random effects' sds and the data rows'
    derivatives by them that a refit keeps (``JointData.lump_sd``, ``JointData.lump_rows``).
    """

    theta: jax.Array
    free: jax.Array
    use: jax.Array
    n: jax.Array
    scout: jax.Array
    lumps: jax.Array
    lump_rows: jax.Array


def step_bounds(n_params: int = N_PHYS + N_KNOTS) -> np.ndarray:
    """(P,) the largest step of each parameter in one iteration of a solve (``PHYS_STEP``, ``KNOT_STEP``)."""
    return np.concatenate([np.full(N_PHYS, PHYS_STEP), np.full(n_params - N_PHYS, KNOT_STEP)])


def no_start(n_params: int = N_PHYS + N_KNOTS) -> Start:
    """The ``Start`` that lets ``core`` explore its own starts."""
    return Start(np.zeros((N_STARTS, n_params)), np.zeros(n_params, bool), np.asarray(False), np.asarray(1),
                 np.asarray(False), np.zeros(N_LUMP_SD), np.zeros((N_DATA_ROWS, N_LUMP)))


def start_at(theta, free, lumps=None, lump_rows=None) -> Start:
    """Refit from ``theta`` (P,) over ``free`` (P,), with the texture random effects of sds ``lumps`` and rows'
    derivatives ``lump_rows`` (None: none)."""
    theta = np.asarray(theta, float)
    lumps = np.zeros(N_LUMP_SD) if lumps is None else np.asarray(lumps, float)
    lump_rows = np.zeros((N_DATA_ROWS, N_LUMP)) if lump_rows is None else np.asarray(lump_rows, float)
    return Start(np.broadcast_to(theta, (N_STARTS,) + theta.shape).copy(), np.asarray(free, bool),
                 np.asarray(True), np.asarray(1), np.asarray(False), lumps, lump_rows)


def candidates(thetas, free) -> Start:
    """Go on from the one of ``thetas`` (..., ``N_STARTS``, P) of lowest cost, over ``free`` (..., P); leading
    axes batch records (a vmapped ``core``)."""
    thetas = np.asarray(thetas, float)
    batch = thetas.shape[:-2]
    return Start(thetas, np.asarray(free, bool), np.full(batch, True), np.full(batch, thetas.shape[-2]),
                 np.full(batch, False), np.zeros(batch + (N_LUMP_SD,)), np.zeros(batch + (N_DATA_ROWS, N_LUMP)))


def scouting(n_params: int = N_PHYS + N_KNOTS) -> Start:
    """The ``Start`` that explores every one of the program's starts and returns their ends."""
    return no_start(n_params)._replace(scout=np.asarray(True))


def core(record: Record, settings: Settings, start: Start | None = None) -> Summary:
    """The joint fit of one record (see the module). Pure jnp, fixed shapes: jit and vmap freely.

    start: a ``Start`` (None: ``no_start()``); ``fit``'s extras run through this same program from one.
    """
    start = no_start() if start is None else start
    prep = prepare(record, settings, ~jnp.asarray(start.use))
    b = prep.band
    free = jnp.where(start.use, start.free, prep.free)
    n_first, n_start, n_final = ITERATIONS
    # candidates are the starts, each only evaluated (the loop's own evaluation: no second program to compile)
    pick = start.use & (start.n > 1)
    theta, r, jac, model, ends = levenberg_marquardt(
        residuals_and_model, jnp.where(start.use, start.theta.astype(prep.starts.dtype), prep.starts),
        (prep.data, settings.hertz), free, prep.first, n_start=jnp.where(pick, 1, n_start), n_first=n_first,
        n_final=jnp.where(start.scout, 0, n_final),
        n_explore=jnp.where(start.scout, N_STARTS, jnp.where(pick, start.n, OWN_STARTS[settings.window])),
        skip_starts=start.use & ~pick, ends=True, stop_tol=STOP_TOL, max_step=step_bounds(prep.starts.shape[-1]))
    return finish(record, prep.data, free, Located(b.i0, b.n_leak, b.k0, b.speed0), theta, r, jac, model,
                  settings.hertz)._replace(ends=ends)


class Located(NamedTuple):
    """What ``finish`` keeps of ``band.select``: the window's first bin, bins dropped as leakage, Eq. 4
    wavenumbers (2,) and Eq. 6 speeds (2,)."""

    i0: jax.Array
    n_leak: jax.Array
    k0: jax.Array
    speed0: jax.Array


def texture_sections(theta, cov, jac, model: ModelSpectra, data: JointData):
    """Eq. 18 / 19: each pair's shallow PSD over the model's, times the model texture spectrum, at
    k = omega / |v_axis|: (3, 2, L) k (rad/m), log power (relative units^2 per rad/m) and its one-sigma
    error (the spectral noise and the parameters' covariance). Meaningful on ``data.mask_s11``."""
    n_fit = data.omega.shape[0]
    p = theta.shape[0]
    v = jnp.exp(theta[jnp.array([INDEX['log_vx'], INDEX['log_vy']])])
    k = data.omega[None, :] / v[:, None]
    log_phi = lambda th: log_phi_at(jnp.log(k), data.log_k_knots, th[N_PHYS:])      # noqa: E731
    # d log Phi(omega / v) / d theta, less d log S11 / d theta (from the Jacobian's first 2 L rows)
    iv = jnp.array([INDEX["log_vx"], INDEX["log_vy"]])
    d = jax.jacfwd(lambda th: log_phi_at(jnp.log(data.omega[None, :] / jnp.exp(th[iv])[:, None]),
                                         data.log_k_knots, th[N_PHYS:]))(theta)
    d = d + jac[:2 * n_fit].reshape(2, n_fit, p) / data.s11_weight
    var = jnp.einsum("plk,km,plm->pl", d, cov, d)
    logp = log_phi(theta) - model.log_s11 + data.meas.log_s11
    return jnp.stack([k, logp, jnp.sqrt(jnp.clip(var, 0.0, None) + 1.0 / jnp.square(data.s11_weight))])


class Errors(NamedTuple):
    """Step 5 and the status at a solution (``errors``): the fields of ``Summary`` of the same names."""

    cov: jax.Array
    sd: jax.Array
    scales: jax.Array
    pooled: jax.Array
    chi2: jax.Array
    redchi: jax.Array
    n_data: jax.Array
    cond: jax.Array
    decrement: jax.Array
    step_sigma: jax.Array
    converged: jax.Array
    settled: jax.Array
    status: jax.Array
    n_bins: jax.Array
    jackknife: jax.Array
    spread: jax.Array
    roughness: jax.Array
    lumpy: jax.Array


def errors(record: Record, data: JointData, free, i0, theta, r, jac, hertz=None, gate=SPREAD_GATE) -> Errors:
    """Step 5 of the module and the status at the solution ``theta`` (fitted over ``free``), with its residuals
    and their Jacobian there; i0: the window's first bin; gate: in a fit that is not poor, the misfit's spread
    sets an error where its plain sandwich exceeds the jackknife this many times."""
    cov, chi2, n_data, _, redchi, cond, decrement, step_sigma = statistics(theta, r, jac, free, data)
    finite = jnp.all(jnp.isfinite(theta)) & jnp.isfinite(chi2)
    settled = settled_physics(step_sigma, free)
    converged = finite & ((decrement < DECREMENT_TOL) | settled)
    unit = _unit_inverse(jac, free)
    scales, pooled, ran = _jackknife(record, theta, jac, free, unit, data, i0, redchi, hertz)
    fallback = jnp.maximum(redchi, 1.0) * jnp.maximum(record.seg.bin_factor, 1.0)
    scales = jnp.where(ran, scales, fallback)
    pooled = jnp.where(ran, pooled, fallback)
    spread_scales, spread_pooled, plain_scales, plain_pooled = _spread(r, jac, free, unit, data)
    # the plain sandwich tests for a shared misfit, the corrected one sizes it; a poor fit's misfit is beyond
    # the segments' noise by definition: there the larger of the two errors stands
    poor = redchi > POOR_FIT_REDCHI

    def shared(corrected, plain, jackknife):      # where the spread sets the error
        return jnp.where(poor, corrected > jackknife, plain > gate * jackknife)

    spread = free & shared(spread_scales, plain_scales, scales)
    scales = jnp.where(spread, spread_scales, scales)
    pooled = jnp.where(shared(spread_pooled, plain_pooled, pooled), spread_pooled, pooled)
    # lsq's cov carries redchi; the scales replace it
    cov = cov * jnp.sqrt(jnp.outer(scales, scales)) / jnp.where(redchi > 0, redchi, 1.0)
    sd = jnp.sqrt(jnp.clip(jnp.diag(cov), 0.0, None))
    n_bins = jnp.sum(data.mask_s11[0]) + jnp.sum(data.mask_s11[1] | data.mask_xy[0])
    roughness, lumpy = _lumpy(poor, r, data, record.seg.bin_factor)
    status = fit_status(n_bins, finite, converged, redchi)
    return Errors(cov, sd, scales, pooled, chi2, redchi, n_data, cond, decrement, step_sigma, converged,
                  settled & ~(decrement < DECREMENT_TOL), status, n_bins, ran, spread, roughness, lumpy)


def fit_status(n_bins, finite, converged, redchi, limit=POOR_FIT_REDCHI):
    """The integer status (``STATUS``) of a solution: poor beyond the reduced chi-square ``limit``."""
    return jnp.where(n_bins < MIN_BINS, 1, jnp.where(~finite, 4, jnp.where(~converged, 2,
                     jnp.where(redchi > limit, 3, 0))))


def finish(record: Record, data: JointData, free, b: Located, theta, r, jac, model: ModelSpectra,
           hertz=None) -> Summary:
    """Steps 5-6 of the module at the solution ``theta`` (fitted over ``free``) with its residuals, their
    Jacobian and the model's spectra there."""
    return summary_at(theta, free, errors(record, data, free, b.i0, theta, r, jac, hertz), b, model, jac, data)


def summary_at(theta, free, e: Errors, b: Located, model: ModelSpectra, jac, data: JointData) -> Summary:
    """The ``Summary`` of a solution ``theta`` over ``free`` from its ``Errors``, with the texture sections."""
    return Summary(theta, e.cov, e.sd, free, e.scales, e.pooled, e.chi2, e.redchi, e.n_data, e.cond, e.decrement,
                   e.step_sigma, e.converged, e.settled, e.status, e.n_bins, b, e.jackknife,
                   model, jac, texture_sections(theta, e.cov, jac, model, data), data, e.spread, e.roughness,
                   e.lumpy)
