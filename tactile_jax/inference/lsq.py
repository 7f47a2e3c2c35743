"""Gradient least squares with free/fixed parameters, Gauss-Newton covariance and failure as data.

``least_squares`` minimises 0.5 * sum(r(theta)^2) over the free entries of a
flat parameter vector with optimistix Levenberg-Marquardt (or jaxopt's, for
comparison), never raising: non-convergence comes back in ``converged``. The
free mask is data, not a code path: one compiled program serves every
choice of free parameters for a given residual function and shapes.
The covariance is the Laplace / Gauss-Newton (J^T J)^-1 of the free block,
scaled by the reduced chi-square as in lmfit (``scale_covar``) and by
``bin_factor`` for correlated residuals; fixed entries have zero rows and
columns. The last ``n_prior`` residuals are priors (for example a
smoothness penalty): they are fitted but not counted as data.
"""

from __future__ import annotations

from functools import partial
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp

from .._numerics import tiny

__all__ = ["LsqResult", "equilibrated_inverse", "fit_statistics", "gauss_newton_decrement", "least_squares",
           "SOLVERS", "DECREMENT_TOL", "STEP_TOL"]

SOLVERS = ("optimistix", "jaxopt")
#: optimistix's Dogleg: not a user's choice, the fits' rescue where LM stops in a curved valley
DOGLEG = "optimistix-dogleg"
#: a solve stopped by ``max_steps`` still counts as converged below this Gauss-Newton decrement (chi2 units)
DECREMENT_TOL = 1e-2
#: a parameter is settled when the full Gauss-Newton step would move it by less than this many (unit) sigmas
STEP_TOL = 0.1


class LsqResult(NamedTuple):
    """Outcome of ``least_squares`` (arrays; usable under vmap).

    theta: (P,) best fit, fixed entries unchanged. cov: (P, P) covariance.
    chi2: sum of squared data residuals (priors excluded). n_data: data
    residuals with non-zero weight. dof: n_data - n_free. redchi: chi2 / dof.
    n_steps: solver steps. converged: the result is finite and the solver
    reported success, or it stopped at ``max_steps`` on a point where a full
    Gauss-Newton step would lower chi2 by less than ``DECREMENT_TOL`` (the
    parameters are within about 0.1 sigma of the optimum: a slow tail of LM
    steps, not a failure). cond: condition number of the free block's
    correlation matrix (large: a combination of parameters the data cannot
    tell apart). decrement: that predicted chi2 decrease, g^T (J^T J)^-1 g.
    jac: (R, P) Jacobian of ``residuals(theta, args)`` at ``theta`` (priors' rows included, all columns),
    for what needs it afterwards at the same data; None where not kept.
    step_sigma: (P,) the full Gauss-Newton step still to go, each parameter in units of its own
    sd from (J^T J)^-1 (0 for fixed ones): which parameters a stop at ``max_steps`` left moving
    (below ``STEP_TOL``: settled; its decrement can stay large while only ill-determined ones move).
    """

    theta: jax.Array
    cov: jax.Array
    chi2: jax.Array
    n_data: jax.Array
    dof: jax.Array
    redchi: jax.Array
    n_steps: jax.Array
    converged: jax.Array
    cond: jax.Array
    decrement: jax.Array | float = float("nan")
    jac: jax.Array | None = None
    step_sigma: jax.Array | None = None


def equilibrated_inverse(jtj, free):
    """(d, scaled, inv) of the free block of J^T J (P, P): unit-diagonal form and its pseudo-inverse.

    d: (P,) sqrt of the diagonal (1 for fixed entries); scaled = J^T J / (d d^T), identity rows
    and columns for fixed entries; inv its Hermitian pseudo-inverse. (J^T J)^-1 = inv / (d d^T).
    The information on log v and on log-texture knots can differ by decades: inverting
    the unit-diagonal form keeps the covariance accurate.
    """
    d = jnp.where(free, jnp.sqrt(jnp.clip(jnp.diag(jtj), tiny(jtj), None)), 1.0)
    both = free[:, None] & free[None, :]
    scaled = jnp.where(both, jtj / (d[:, None] * d[None, :]), jnp.eye(jtj.shape[0], dtype=jtj.dtype))
    return d, scaled, jnp.linalg.pinv(scaled, hermitian=True)


def _gauss_newton_step(r, jac, free, d, inv):
    """The Gauss-Newton step in the equilibrated variables (``equilibrated_inverse``'s d, inv) and its decrement,
    the chi2 decrease it predicts, g^T (J^T J)^-1 g. jac: fixed columns zeroed."""
    grad = jnp.where(free, (jac.T @ r) / d, 0.0)             # gradient of chi2 / 2, scaled variables
    step = -inv @ grad
    return step, -grad @ step


def gauss_newton_decrement(r, jac, free):
    """The Gauss-Newton decrement of residuals r (K,) with Jacobian jac (K, P) over ``free`` (chi2 units): the
    ``decrement`` of ``fit_statistics``."""
    jac = jac * free[None, :]
    d, _, inv = equilibrated_inverse(jac.T @ jac, free)
    return _gauss_newton_step(r, jac, free, d, inv)[1]


def fit_statistics(theta, r_all, jac_all, free, *, bin_factor=1.0, scale_covar: bool = True, n_prior: int = 0,
                   n_aux: int = 0, n_effects=0.0):
    """Fit statistics at ``theta``: (cov, chi2, n_data, dof, redchi, cond, decrement, step_sigma), as in
    ``LsqResult``.

    r_all: (K,) residuals, the last ``n_prior`` of them priors, the ``n_aux`` before those counted in chi2 but
    not as data (a random effect's rows), whose effects take ``n_effects`` degrees of freedom. jac_all: (K, P)
    their Jacobian (fixed columns are zeroed here). free: (P,) bool.
    """
    jac_all = jac_all * free[None, :]
    n_res = r_all.shape[0] - n_prior
    r, jac = r_all[:n_res], jac_all[:n_res]
    counted = r_all.shape[0] - n_prior - n_aux
    n_data = jnp.sum(jnp.any(jac[:counted] != 0, axis=1) | (r[:counted] != 0))
    n_free = jnp.sum(free)
    chi2 = jnp.sum(jnp.square(r))
    dof = jnp.maximum(n_data - n_free - n_effects, 1)
    redchi = chi2 / dof
    d, scaled, inv = equilibrated_inverse(jac_all.T @ jac_all, free)
    evals = jnp.linalg.eigvalsh(scaled)
    cond = evals[-1] / jnp.clip(evals[0], tiny(evals), None)
    cov = inv / (d[:, None] * d[None, :])
    factor = jnp.where(scale_covar, redchi, 1.0) * bin_factor
    cov = jnp.where(free[:, None] & free[None, :], cov * factor, 0.0)
    step, decrement = _gauss_newton_step(r_all, jac_all, free, d, inv)
    step_sigma = jnp.where(free, step / jnp.sqrt(jnp.clip(jnp.diag(inv), tiny(inv), None)), 0.0)
    return cov, chi2, n_data, dof, redchi, cond, decrement, step_sigma


def _optimistix_solver(name: str, rtol, atol):
    # optimistix and lineax (with equinox) are imported where a solver is made: 0.4-0.5 s that the compiled
    # analysis, which does not use them, would otherwise add to every command's start
    import lineax as lx
    import optimistix as optx

    if name == DOGLEG:
        # for an LM stopped at max_steps in a curved valley: on one coverage scene LM gained < 1.7 chi2 in
        # 512 steps from its stopping point where Dogleg converged in 48
        return optx.Dogleg(rtol=rtol, atol=atol)
    # The damped step solved by Cholesky on the normal equations, not optimistix's default QR of the
    # stacked [J; sqrt(lambda) I]: the same minimum (53 vs 60 steps), but 3.8x less time per step on the joint
    # model (39 vs 151 ms on 2 CPU cores, 128 bins, 19 parameters); the damping keeps J^T J +
    # lambda I positive definite, and the covariance below does not use this factorisation.
    return optx.LevenbergMarquardt(rtol=rtol, atol=atol, linear_solver=lx.Normal(lx.Cholesky()))


def _solve_optimistix(fn, y0, args, max_steps, solver):
    import optimistix as optx

    sol = optx.least_squares(fn, solver, y0, args, max_steps=max_steps, throw=False, options={"jac": "fwd"})
    return sol.value, sol.stats["num_steps"], sol.result == optx.RESULTS.successful


def _solve_jaxopt(fn, y0, args, max_steps, rtol, atol):
    # jaxopt is unmaintained; kept only as a second solver for comparisons
    import jaxopt

    lm = jaxopt.LevenbergMarquardt(residual_fun=fn, maxiter=max_steps, tol=atol, xtol=rtol, gtol=atol)
    params, state = lm.run(y0, args)
    ok = (state.iter_num < max_steps) & jnp.all(jnp.isfinite(params))
    return params, state.iter_num, ok


@partial(jax.jit, static_argnames=("residuals", "solver", "max_steps", "n_prior"))
def least_squares(residuals: Callable, theta0, args, free, *, solver: str = "optimistix", max_steps: int = 256,
                  rtol: float = 1e-8, atol: float = 1e-8, bin_factor=1.0, scale_covar: bool = True,
                  n_prior: int = 0) -> LsqResult:
    """Fit the ``free`` entries ((P,) bool, traced) of ``theta0`` ((P,)) to ``residuals(theta, args)``.

    ``residuals`` returns a flat vector of weighted residuals (zero where a
    datum is masked out) and must be hashable (a module-level function).
    ``solver``: ``"optimistix"`` (Levenberg-Marquardt, default), ``"jaxopt"`` or ``DOGLEG``.
    """
    theta0 = jnp.asarray(theta0)
    free = jnp.asarray(free, bool)

    def full(y):
        return jnp.where(free, y, theta0)

    def fn(y, a):
        # fixed entries get a zero-valued residual with unit slope: the Jacobian keeps full rank
        return jnp.concatenate([residuals(full(y), a), jnp.where(free, 0.0, y - theta0)])

    if solver in ("optimistix", DOGLEG):
        y, n_steps, ok = _solve_optimistix(fn, theta0, args, max_steps, _optimistix_solver(solver, rtol, atol))
    elif solver == "jaxopt":
        y, n_steps, ok = _solve_jaxopt(fn, theta0, args, max_steps, rtol, atol)
    else:
        raise ValueError(f"unknown solver {solver!r}; expected one of {SOLVERS}")
    theta = full(y)
    r_all = residuals(theta, args)
    jac_all = jax.jacfwd(residuals)(theta, args)
    cov, chi2, n_data, dof, redchi, cond, decrement, step_sigma = fit_statistics(
        theta, r_all, jac_all, free, bin_factor=bin_factor, scale_covar=scale_covar, n_prior=n_prior)
    ok = (ok | (decrement < DECREMENT_TOL)) & jnp.all(jnp.isfinite(theta)) & jnp.isfinite(chi2)
    return LsqResult(theta, cov, chi2, n_data, dof, redchi, n_steps, ok, cond, decrement, jac_all, step_sigma)
