"""Fixed-iteration Levenberg-Marquardt for the joint model: no data-dependent control flow, so it vmaps.

One loop body holds the residuals and their Jacobian once (they dominate the
compile time). The first ``n_first`` iterations move only the ``first``
parameters (the texture, with the physics held at its start), the rest move
every ``free`` one: one compiled program for both stages. Each iteration
takes a Marquardt step (J^T J + lam diag(J^T J)) delta = -J^T r, rescaled so
that no parameter moves by more than ``max_step`` (log space: a factor e),
accepts it if chi-square falls (Nielsen's damping update), and evaluates the
residuals and the Jacobian once, at the trial point.

Why not optimistix: under ``vmap`` its ``while_loop`` runs every record until
the slowest stops, and its per-step overhead on a CPU was about 1 ms per
record (``benchmarks/throughput.py``); a fixed iteration count costs the same
for every record of a chunk and keeps one program for fit and batch.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._numerics import tiny

__all__ = ["levenberg_marquardt"]


def _step(r, jac, free, lam):
    g = jac.T @ r
    a = jac.T @ jac
    diag = jnp.clip(jnp.diag(a), tiny(a), None)
    both = free[:, None] & free[None, :]
    eye = jnp.eye(a.shape[0], dtype=a.dtype)
    a_damped = jnp.where(both, a + lam * eye * diag[:, None], eye)
    delta = jnp.linalg.solve(a_damped, jnp.where(free, -g, 0.0)[:, None])[:, 0]
    return jnp.where(free, delta, 0.0), g


def levenberg_marquardt(residuals, theta0, args, free, first, n_iter: int, n_first: int = 0, *, lam0=1e-3,
                        max_step=1.0):
    """``n_iter`` iterations from ``theta0`` (P,): the first ``n_first`` over the ``first`` mask (P,), the
    rest over ``free`` (P,). Returns theta, residuals and their full Jacobian (R, P) at theta, and the
    number of accepted steps.
    """
    theta0 = jnp.asarray(theta0)

    def value_and_jac(theta):
        jac, r = jax.jacfwd(lambda t: (residuals(t, args),) * 2, has_aux=True)(theta)
        return r, jac

    def cost_of(r):
        c = 0.5 * jnp.sum(jnp.square(r))
        return jnp.where(jnp.isfinite(c), c, jnp.inf)

    def body(i, carry):
        theta, r, jac, cost, lam, nu, n_acc = carry
        start = i == 0
        mask = jnp.where(i <= n_first, first, free)
        jm = jac * mask
        delta, g = _step(r, jm, mask, lam)
        delta = delta * jnp.minimum(1.0, max_step / jnp.maximum(jnp.max(jnp.abs(delta)), tiny(delta)))
        delta = jnp.where(start, 0.0, delta)
        trial = theta + delta
        r_t, j_t = value_and_jac(trial)
        cost_t = cost_of(r_t)
        pred = -jnp.dot(g, delta) - 0.5 * jnp.sum(jnp.square(jm @ delta))
        rho = (cost - cost_t) / jnp.where(pred > 0, pred, jnp.inf)
        ok = (cost_t < cost) & jnp.all(jnp.isfinite(trial)) & jnp.all(jnp.isfinite(j_t)) & (rho > 0)
        shrink = jnp.maximum(1.0 / 3.0, 1.0 - jnp.power(2.0 * jnp.clip(rho, 0.0, 1.0) - 1.0, 3))
        lam = jnp.where(start | (i == n_first + 1), lam0, jnp.clip(jnp.where(ok, lam * shrink, lam * nu), 1e-12, 1e12))
        nu = jnp.where(start | ok, 2.0, jnp.minimum(nu * 2.0, 1e6))
        take = ok | start
        return (jnp.where(take, trial, theta), jnp.where(take, r_t, r), jnp.where(take, j_t, jac),
                jnp.where(take, cost_t, cost), lam, nu, n_acc + (ok & ~start).astype(jnp.int32))

    r_shape = jax.eval_shape(lambda t: residuals(t, args), theta0).shape
    dtype = theta0.dtype
    carry = (theta0, jnp.zeros(r_shape, dtype), jnp.zeros(r_shape + theta0.shape, dtype), jnp.asarray(jnp.inf, dtype),
             jnp.asarray(lam0, dtype), jnp.asarray(2.0, dtype), jnp.asarray(0, jnp.int32))
    theta, r, jac, _, _, _, n_acc = jax.lax.fori_loop(0, n_iter + 1, body, carry)
    return theta, r, jac, n_acc
