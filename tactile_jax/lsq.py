"""Gradient least squares with free/fixed parameters, Gauss-Newton covariance and failure as data.

``least_squares`` minimises 0.5 * sum(r(theta)^2) over the free entries of a
flat parameter vector with optimistix Levenberg-Marquardt (or jaxopt's, for
comparison), never raising: non-convergence comes back in ``converged`` and
``result``. The covariance is the Laplace / Gauss-Newton (J^T J)^-1 of the
free block, scaled by ``max(redchi, 1)`` as in lmfit and by ``bin_factor``
for correlated residuals; fixed entries have zero rows and columns.
"""

from __future__ import annotations

from functools import partial
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

__all__ = ["LsqResult", "least_squares", "SOLVERS"]

SOLVERS = ("optimistix", "jaxopt")


class LsqResult(NamedTuple):
    """Outcome of ``least_squares`` (arrays; usable under vmap).

    theta: (P,) best fit, fixed entries unchanged. cov: (P, P) covariance.
    chi2: sum of squared residuals. n_data: residuals with non-zero weight.
    dof: n_data - n_free. redchi: chi2 / dof. n_steps: solver steps.
    converged: solver reported success. cond: condition number of the free
    block's correlation matrix (large: a parameter the data cannot tell).
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


def _embed(theta_free, theta0, idx):
    return theta0.at[idx].set(theta_free)


def _solve_optimistix(fn, y0, args, max_steps, rtol, atol):
    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)
    sol = optx.least_squares(fn, solver, y0, args, max_steps=max_steps, throw=False)
    return sol.value, sol.stats["num_steps"], sol.result == optx.RESULTS.successful


def _solve_jaxopt(fn, y0, args, max_steps, rtol, atol):
    # jaxopt is unmaintained; kept only as a second solver for comparisons
    import jaxopt

    lm = jaxopt.LevenbergMarquardt(residual_fun=fn, maxiter=max_steps, tol=atol, xtol=rtol, gtol=atol)
    params, state = lm.run(y0, args)
    ok = (state.iter_num < max_steps) & jnp.all(jnp.isfinite(params))
    return params, state.iter_num, ok


@partial(jax.jit, static_argnames=("residuals", "free", "solver", "max_steps"))
def least_squares(residuals: Callable, theta0, args, *, free: tuple[bool, ...], solver: str = "optimistix",
                  max_steps: int = 256, rtol: float = 1e-10, atol: float = 1e-10, bin_factor=1.0) -> LsqResult:
    """Fit the ``free`` entries of ``theta0`` (a flat (P,) vector) to ``residuals(theta, args)``.

    ``residuals`` returns a flat vector of weighted residuals (zero where a
    datum is masked out); it must be a hashable function (module level). The
    other entries of ``theta0`` stay fixed. ``solver``: ``"optimistix"``
    (default) or ``"jaxopt"``.
    """
    theta0 = jnp.asarray(theta0)
    idx = np.flatnonzero(np.asarray(free, bool))
    fn = lambda tf, a: residuals(_embed(tf, theta0, idx), a)  # noqa: E731
    y0 = theta0[idx]
    if solver == "optimistix":
        y, n_steps, ok = _solve_optimistix(fn, y0, args, max_steps, rtol, atol)
    elif solver == "jaxopt":
        y, n_steps, ok = _solve_jaxopt(fn, y0, args, max_steps, rtol, atol)
    else:
        raise ValueError(f"unknown solver {solver!r}; expected one of {SOLVERS}")
    r = fn(y, args)
    jac = jax.jacfwd(fn)(y, args)
    n_data = jnp.sum(jnp.any(jac != 0, axis=1) | (r != 0))   # masked residuals are 0 with 0 gradient
    n_free = idx.size
    chi2 = jnp.sum(jnp.square(r))
    dof = jnp.maximum(n_data - n_free, 1)
    redchi = chi2 / dof
    jtj = jac.T @ jac
    d = jnp.sqrt(jnp.clip(jnp.diag(jtj), 1e-300, None))
    corr_inv = jtj / (d[:, None] * d[None, :])          # scaled so the condition number is scale-free
    evals = jnp.linalg.eigvalsh(corr_inv)
    cond = evals[-1] / jnp.clip(evals[0], 1e-300, None)
    cov_free = jnp.linalg.pinv(corr_inv, hermitian=True) / (d[:, None] * d[None, :])
    cov_free = cov_free * jnp.maximum(redchi, 1.0) * bin_factor
    p = theta0.shape[0]
    cov = jnp.zeros((p, p), cov_free.dtype).at[np.ix_(idx, idx)].set(cov_free)
    ok = ok & jnp.all(jnp.isfinite(y)) & jnp.isfinite(chi2)
    return LsqResult(_embed(y, theta0, idx), cov, chi2, n_data, dof, redchi, n_steps, ok, cond)
