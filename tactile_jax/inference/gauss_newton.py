"""Fixed-iteration Levenberg-Marquardt for many small least-squares problems in lock-step.

``gauss_newton(residuals, theta0, args, free)`` minimises 0.5 * sum(r(theta)^2)
over the free entries of a small parameter vector (P of a few) with a fixed
number of damped Gauss-Newton (Levenberg-Marquardt) iterations and no
data-dependent control flow, so that ``jax.vmap`` over thousands of problems
(the B x 2 probe pairs of a batch chunk) runs them side by side as dense
arrays: residuals and the (K, P) Jacobian by forward mode, one P x P solve
per problem, Marquardt damping adapted per problem by accepting or rejecting
each step (``jnp.where``), Nielsen's update of the damping, and no parameter
moving by more than ``max_step`` per iteration. It returns the
same :class:`lsq.LsqResult` as ``lsq.least_squares`` (covariance, reduced
chi-square and condition number by the same ``lsq.fit_statistics``), with convergence as
data: converged when the remaining Gauss-Newton step is below ``gtol`` error
bars and the last accepted step changed no parameter by more than ``xtol``
(parameters in log space: a relative change).

Why hand-written rather than optimistix (the project's rule is to build on
it): for the 3-parameter pair model of a batch, optimistix's
Levenberg-Marquardt is a ``while_loop`` whose per-step overhead measured about
1 ms per pair on a 2-core CPU, and under ``vmap`` a while_loop runs every lane
until the slowest one stops, so a chunk of records was fitted one record at a
time (11-12 recordings/s, the fitting stage 6.7x the spectral stage). A fixed
number of iterations costs the same for every lane and vectorises the whole
chunk. ``lsq.least_squares`` stays the general solver (any P, priors, the
joint model); this one is for many tiny problems of the same shape.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

import jax
import jax.numpy as jnp

from .._numerics import tiny
from .lsq import LsqResult, fit_statistics

__all__ = ["N_ITERATIONS", "gauss_newton", "iterate"]

#: iterations of the batch pair fits (chosen from measurements: see benchmarks/README.md, "Throughput")
N_ITERATIONS = 20


def _value_and_jac(residuals, theta, args, free, value_and_jac=None):
    """Residuals (K,) and their Jacobian (K, P) (``value_and_jac``, else by forward mode), fixed columns zeroed."""
    if value_and_jac is not None:
        r, jac = value_and_jac(theta, args)
        return r, jac * free[None, :]

    def fn(th):
        r = residuals(th, args)
        return r, r

    jac, r = jax.jacfwd(fn, has_aux=True)(theta)
    return r, jac * free[None, :]


def damped_step(r, jac, free, lam):
    """The Marquardt step (J^T J + lam diag(J^T J)) delta = -J^T r, zero on fixed entries; and J^T r, J^T J."""
    g = jac.T @ r
    a = jac.T @ jac
    diag = jnp.clip(jnp.diag(a), tiny(a), None)
    both = free[:, None] & free[None, :]
    eye = jnp.eye(a.shape[0], dtype=a.dtype)
    a_damped = jnp.where(both, a + lam * eye * diag[:, None], eye)
    delta = jnp.linalg.solve(a_damped, jnp.where(free, -g, 0.0)[:, None])[:, 0]
    return jnp.where(free, delta, 0.0), g, a


def iterate(residuals, theta0, args, free, n_iter, lam0, value_and_jac=None, max_step=1.0):
    """``n_iter`` damped Gauss-Newton steps: theta, residuals, Jacobian, last accepted step, accepted steps.

    Iteration 0 only evaluates the start (its step is zero and it is always taken), so that the
    residuals and Jacobian appear once in the program: they dominate the compile time.
    """
    theta0 = jnp.asarray(theta0)
    free = jnp.asarray(free, bool)
    dtype = theta0.dtype

    def cost_of(r):
        c = 0.5 * jnp.sum(jnp.square(r))
        return jnp.where(jnp.isfinite(c), c, jnp.inf)

    def body(i, carry):
        theta, r, jac, cost, lam, nu, last_step, n_acc = carry
        start = i == 0
        delta, g, _ = damped_step(r, jac, free, lam)
        # no parameter moves by more than max_step per iteration (log space: a factor e): a nearly flat
        # direction (a speed or radius the data cannot bound) is not jumped onto a far plateau
        delta = delta * jnp.minimum(1.0, max_step / jnp.maximum(jnp.max(jnp.abs(delta)), tiny(delta)))
        delta = jnp.where(start, 0.0, delta)
        trial = theta + delta
        r_t, j_t = _value_and_jac(residuals, trial, args, free, value_and_jac)
        cost_t = cost_of(r_t)
        # the decrease the linearised model predicts, for the gain ratio rho
        pred = -jnp.dot(g, delta) - 0.5 * jnp.sum(jnp.square(jac @ delta))
        rho = (cost - cost_t) / jnp.where(pred > 0, pred, jnp.inf)
        ok = (cost_t < cost) & jnp.all(jnp.isfinite(trial)) & jnp.all(jnp.isfinite(j_t)) & (rho > 0)
        # Nielsen's damping update: shrink after a good step, double the growth after every rejection
        shrink = jnp.maximum(1.0 / 3.0, 1.0 - jnp.power(2.0 * jnp.clip(rho, 0.0, 1.0) - 1.0, 3))
        lam = jnp.where(start, lam, jnp.clip(jnp.where(ok, lam * shrink, lam * nu), 1e-12, 1e12))
        nu = jnp.where(start | ok, 2.0, jnp.minimum(nu * 2.0, 1e6))
        take = ok | start
        return (jnp.where(take, trial, theta), jnp.where(take, r_t, r), jnp.where(take, j_t, jac),
                jnp.where(take, cost_t, cost), lam, nu,
                jnp.where(ok & ~start, jnp.max(jnp.abs(delta)), last_step), n_acc + (ok & ~start).astype(jnp.int32))

    r_shape = jax.eval_shape(lambda t: residuals(t, args), theta0).shape
    carry = (theta0, jnp.zeros(r_shape, dtype), jnp.zeros(r_shape + theta0.shape, dtype), jnp.asarray(jnp.inf, dtype),
             jnp.asarray(lam0, dtype), jnp.asarray(2.0, dtype), jnp.asarray(jnp.inf, dtype), jnp.asarray(0, jnp.int32))
    theta, r, jac, _, _, _, last_step, n_acc = jax.lax.fori_loop(0, n_iter + 1, body, carry)
    return theta, r, jac, last_step, n_acc


@partial(jax.jit, static_argnames=("residuals", "n_iter", "n_prior", "value_and_jac"))
def gauss_newton(residuals: Callable, theta0, args, free, *, n_iter: int = N_ITERATIONS, lam0: float = 1e-3,
                 xtol: float = 1e-4, gtol: float = 1e-3, max_step: float = 1.0, bin_factor=1.0,
                 scale_covar: bool = True, n_prior: int = 0, value_and_jac: Callable | None = None) -> LsqResult:
    """Fit the ``free`` entries ((P,) bool) of ``theta0`` ((P,)) to ``residuals(theta, args)`` in ``n_iter`` steps.

    ``residuals`` returns a flat vector of weighted residuals (zero where a
    datum is masked out) and must be hashable (a module-level function).
    lam0: the initial Marquardt damping (relative to diag(J^T J)).
    xtol: the largest change of a parameter in the last accepted step for
        convergence (log-space parameters: a relative change).
    gtol: the remaining Gauss-Newton step, in units of the one-sigma error
        ellipsoid, below which the gradient counts as zero.
    max_step: the largest change of any parameter in one iteration (the step is scaled down).
    value_and_jac: optional ``(theta, args) -> (residuals, (K, P) Jacobian)`` (hashable), used
        instead of ``jax.jacfwd`` of ``residuals`` when the caller has a cheaper one.
    ``n_steps`` in the result is the number of accepted steps.
    """
    theta0 = jnp.asarray(theta0)
    free = jnp.asarray(free, bool)
    theta, r, jac, last_step, n_acc = iterate(residuals, theta0, args, free, n_iter, lam0, value_and_jac, max_step)
    cov, chi2, n_data, dof, redchi, cond, decrement, step_sigma = fit_statistics(
        theta, r, jac, free, bin_factor=bin_factor, scale_covar=scale_covar, n_prior=n_prior)
    # the undamped step still to go, in units of the error ellipsoid: g^T (J^T J)^-1 g / redchi
    remaining = decrement / jnp.maximum(redchi, tiny(redchi))
    small_step = (last_step <= xtol) | (jnp.sum(free) == 0)
    converged = (remaining <= gtol ** 2) & small_step & jnp.all(jnp.isfinite(theta)) & jnp.isfinite(chi2)
    return LsqResult(theta, cov, chi2, n_data, dof, redchi, n_acc, converged, cond, decrement, step_sigma=step_sigma)
