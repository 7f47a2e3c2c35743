"""One update of a slip that is followed over time: a pure, fixed-shape program (``update``).

A tracker fits a window of the recording every hop. Consecutive windows share
most of their samples, so the optimum moves little from one to the next: an
update goes on from the last one's parameters (``TrackState``) with ONE
Gauss-Newton step of the joint model under the window the acquisition chose
(``inference.analysis``), then the errors of ``core.errors`` (Laplace scaled by
the delete-one-group jackknife) at the new point.

The step is a chord (simplified Newton) step: the residuals are evaluated
afresh on the new window's spectra, the Jacobian is the one kept in the state,
refreshed where it is older than ``REFRESH_AGE`` updates, where the fit window's
first bin moved (its rows would belong to other bins), where the last step
moved a physical parameter by more than ``REFRESH_MOVE`` of its sigma, or where
the caller asks. Between refreshes a bin that leaves the band loses its rows
(its residual is zero) and one that enters it waits for the next refresh. The Jacobian is four times the residuals' cost under the
Gaussian window and nearly three times under the Hertz disk, so a chord update
costs a third of a full one; the Jacobian at the previous optimum is the
Jacobian at this one to first order in the step.

The errors and the chi-square are those at the new point to first order (the
Gauss-Newton model of its residuals, r + J delta): the next update evaluates
the residuals there. ``moved`` (the largest physical step in sigmas) says
whether the update had settled: a window in which the slip changed leaves a
large step, which refreshes the Jacobian, and the next updates go on from
there.

Texture knots and the weak priors' centre are held from the acquisition
(``TrackState.log_knots``, ``prior_center``): the knots are the texture's
coordinates, and ``core.prepare`` would otherwise move them with each window's
Eq. 6 speed. So are the sds of a lumpy texture's random effects where the
acquisition fitted them (``TrackState.lump_sd``; ``residuals.profile``): a 2 s
window's tapers all hear the same few texture modes. The state keeps the
Jacobian of the residuals without them, from which the effects' rows follow
(``forward.lump_basis``) wherever it is refreshed or loses a bin.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from ..inference.core import N_PHYS, INDEX, POOR_FIT_REDCHI, Errors, Record, Settings, errors, fit_status, prepare
from ..inference.data import N_LUMP_SD
from ..inference.forward import lump_basis
from ..inference.gauss_newton import damped_step
from ..inference.residuals import n_data_rows, profile, residuals_and_model

__all__ = ["TrackState", "Update", "update", "REFRESH_AGE", "REFRESH_MOVE", "MAX_STEP", "LAMBDA", "SETTLED", "SPREAD_GATE",
           "poor_fit_limit"]

#: the kept Jacobian is refreshed after this many chord updates
REFRESH_AGE = 4
#: ... or where the last step moved a physical parameter by more than this many of its sigmas
REFRESH_MOVE = 2.0
#: no parameter moves by more than this in one update (log space: a factor e^0.5)
MAX_STEP = 0.5
#: an update whose step moved every free physical parameter by at most this many sigmas has settled
SETTLED = 1.0
#: the standard normal's 99.9 % point
Z_999 = 3.0902
#: Marquardt damping of the step (relative to J^T J's diagonal)
LAMBDA = 1e-3
#: an update's errors come from the misfit's spread across frequency wherever its plain sandwich exceeds the
#: tapers' jackknife (``core.errors``' gate; a 16 s record's is ``core.SPREAD_GATE``): the jackknife of a window's
#: 5 tapers is a variance of 4 degrees of freedom, and the larger of two estimates is taken. On
#: benchmarks/track.py's paths, 8 `ok` updates beyond 3 sigma of 190 windows inside a piece against 13 with the
#: gate at 2, and 129 right against 128
SPREAD_GATE = 1.0


class TrackState(NamedTuple):
    """What an update goes on from (arrays).

    theta, free: (P,) the last optimum and the fitted parameters (the acquisition's choices held);
    log_knots: the texture knots (log rad/m); prior_center: (P,) the weak priors' centre; jac: (R, P) the
    residuals' Jacobian kept for chord steps; i0: the fit window's first bin where ``jac`` was computed;
    mask_xy: (2, L) the bins of the x-y chain's blocks; age: chord updates since; moved: the last step in
    sigmas; lump_sd: (``data.N_LUMP_SD``,) the sds of a lumpy texture's random effects (zeros: none).
    ``jac`` is that of the residuals without the random effects."""

    theta: jax.Array
    free: jax.Array
    log_knots: jax.Array
    prior_center: jax.Array
    jac: jax.Array
    i0: jax.Array
    mask_xy: jax.Array
    age: jax.Array
    moved: jax.Array
    lump_sd: jax.Array


class Update(NamedTuple):
    """One update (arrays): errors (``core.Errors`` at the new point), theta (P,), moved: the largest step of
    a free physical parameter in its sigmas; refreshed: whether the Jacobian was computed afresh; taken:
    whether the step and its residuals are finite; state: the ``TrackState`` to go on from; n_band (2,): each pair's
    usable bins; speed0 (2,): Eq. 6 speeds of the window (m/s, NaN where none)."""

    errors: Errors
    theta: jax.Array
    moved: jax.Array
    refreshed: jax.Array
    taken: jax.Array
    state: TrackState
    n_band: jax.Array
    speed0: jax.Array


def poor_fit_limit(n_data, bin_factor):
    """The reduced chi-square beyond which a window's fit is poor: ``core.POOR_FIT_REDCHI``, or the 99.9 %
    point of the reduced chi-square of noise where that is higher. A short window has few independent
    residuals (n_data over the bin factor: its spectral window correlates adjacent bins), whose reduced
    chi-square scatters widely: 2.27 is its 99.9 % point for 20 of them. Wilson-Hilferty's cube root."""
    n = jnp.maximum(n_data / jnp.maximum(bin_factor, 1.0), 1.0)
    c = 2.0 / (9.0 * n)
    return jnp.maximum(POOR_FIT_REDCHI, jnp.power(1.0 - c + Z_999 * jnp.sqrt(c), 3))


def update(record: Record, settings: Settings, state: TrackState, refresh=False) -> Update:
    """One update from ``state`` on ``record``'s window (see the module). Pure jnp, fixed shapes.

    settings: the window of the acquisition (``settings.hertz`` None: the Gaussian window, else the Hertz
    disk's table); refresh: (traced) compute the Jacobian afresh whatever its age."""
    prep = prepare(record, settings, False, pair_fits=False)
    b = prep.band
    data = prep.data._replace(log_k_knots=state.log_knots, prior_center=state.prior_center)
    args = (data, settings.hertz)
    # nothing measures the y pair's level where it has no band
    i_ay = INDEX["log_ay"]
    free = state.free.at[i_ay].set(state.free[i_ay] & prep.free[i_ay])
    stale = (state.age >= REFRESH_AGE) | (state.moved > REFRESH_MOVE) | (b.i0 != state.i0)
    stale = stale | jnp.asarray(refresh)

    def fresh(theta):
        jac, r = jax.jacfwd(lambda t: (lambda out: (out[0], out[0]))(residuals_and_model(t, args)),
                            has_aux=True)(theta)
        return r, jac

    def chord(theta):
        # a bin that left the band has a zero residual now: its rows go; one that entered it has no rows yet
        r = residuals_and_model(theta, args)[0]
        return r, jnp.where((r != 0.0)[:, None], state.jac, 0.0)

    r_raw, jac_raw = jax.lax.cond(stale, fresh, chord, state.theta)
    # a lumpy texture's random effects: their rows' derivatives are directions in the parameters (the knots, the
    # y level and the angular factor), read from the Jacobian as the analysis reads them
    rows = -jac_raw[:n_data_rows(data)] @ jnp.asarray(lump_basis(state.theta.shape[0]), jac_raw.dtype)
    data = data._replace(lump_sd=state.lump_sd, lump_rows=rows)
    r, jac = jax.lax.cond(jnp.any(state.lump_sd > 0), lambda: (profile(r_raw, data), profile(jac_raw, data)),
                          lambda: (r_raw, jac_raw))
    jm = jac * free
    delta, _, _ = damped_step(r, jm, free, LAMBDA)
    delta = delta * jnp.minimum(1.0, MAX_STEP / jnp.maximum(jnp.max(jnp.abs(delta)), 1e-30))
    # the new point's residuals to first order (Gauss-Newton's model of them): the next update evaluates them
    theta = state.theta + delta
    r_kept = r + jm @ delta
    taken = jnp.all(jnp.isfinite(theta)) & jnp.all(jnp.isfinite(r_kept))
    e = errors(record, data, free, b.i0, theta, r_kept, jac, settings.hertz, gate=SPREAD_GATE)
    physical = free & (jnp.arange(theta.shape[0]) < N_PHYS)
    sd = jnp.where(e.sd > 0, e.sd, jnp.inf)
    moved = jnp.max(jnp.where(physical, jnp.abs(delta) / sd, 0.0))
    moved = jnp.where(taken, moved, jnp.inf)
    # settled: the step moved no physical parameter by more than ``SETTLED`` sigma (the chord's decrement is
    # that of a frozen Jacobian, not the fit's)
    settled = moved <= SETTLED
    finite = jnp.all(jnp.isfinite(theta)) & jnp.isfinite(e.chi2)
    limit = poor_fit_limit(e.n_data, record.seg.bin_factor)
    e = e._replace(converged=finite & settled, settled=jnp.asarray(False), lumpy=e.lumpy & (e.redchi > limit),
                   status=fit_status(e.n_bins, finite, finite & settled, e.redchi, limit))
    new = TrackState(theta, free, state.log_knots, state.prior_center, jac_raw, b.i0, data.mask_xy,
                     jnp.where(stale, 0, state.age + 1).astype(jnp.int32), moved, state.lump_sd)
    return Update(e, theta, moved, stale, taken, new, b.n_band, b.speed0)


def state_from(record: Record, settings: Settings, theta, free, log_knots, prior_center, lump_sd=None,
               jac=None) -> TrackState:
    """The ``TrackState`` of an acquisition's fit (``theta``, ``free`` of the analysis on ``record``, with the
    texture knots, prior centre and random effects' sds of its ``JointData``; lump_sd None: none); ``jac``: None
    to compute it at the first update."""
    prep = prepare(record, settings, False, pair_fits=False)
    data = prep.data._replace(log_k_knots=log_knots, prior_center=prior_center)
    r_shape = jax.eval_shape(lambda t: residuals_and_model(t, (data, settings.hertz))[0], theta).shape
    p = theta.shape[0]
    return TrackState(jnp.asarray(theta), jnp.asarray(free, bool), jnp.asarray(log_knots), jnp.asarray(prior_center),
                      jnp.zeros(r_shape + (p,), theta.dtype) if jac is None else jac, prep.band.i0, data.mask_xy,
                      jnp.zeros((), jnp.int32), jnp.full((), jnp.inf, theta.dtype),
                      jnp.zeros(N_LUMP_SD, theta.dtype) if lump_sd is None else jnp.asarray(lump_sd, theta.dtype))
