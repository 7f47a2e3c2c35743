"""Levenberg-Marquardt over several starts in ONE loop, with a fixed schedule that vmaps.

The loop runs ``S`` starts one after another for ``n_start`` iterations each
(the first ``n_first`` of them over the ``first`` parameters only: the
texture, with the physics held at the start), keeps the one that ends with
the lowest cost, and goes on from it for ``n_final`` iterations over every
``free`` parameter. One loop body holds the residuals and their Jacobian
once: they dominate the compile time, and a separate loop per stage would
compile them again. Each iteration takes a Marquardt step
(J^T J + lam diag(J^T J)) delta = -J^T r, rescaled so that no parameter moves
by more than its ``max_step`` (a scalar or one bound a parameter), accepts it if the cost
falls (Nielsen's damping update), and evaluates the residuals and the
Jacobian once, at the trial point. The final iterations end early once the
Gauss-Newton decrement still to go is below ``stop_tol``: a refit from near
an optimum (a profile point, a held slip direction) takes a few iterations
instead of the full count. A solve that is only needed to beat a given
chi-square can also give up (``give_up_chi2``): once its own chi-square, less
that decrement, stays above the bound, more iterations cannot change the
decision it serves. A start being explored can likewise be left once its cost
stands far above the cost an earlier start ended at (``scout_give_up``): its
end is then where it stood.

Why not optimistix: its solvers stop per problem too, but with a per-step
overhead of about 1 ms per record on a CPU, and the multi-start schedule
(explore each start, then go on from the best, texture-only first steps)
would be several solves, each compiling the residuals again. Here one
program serves ``fit`` and ``batch``; under ``vmap`` a chunk iterates until
its slowest record stops, each record keeping the point where it stopped.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._numerics import tiny
from .gauss_newton import damped_step
from .lsq import gauss_newton_decrement

__all__ = ["levenberg_marquardt"]


def levenberg_marquardt(fun, starts, args, free, first, *, n_start, n_first: int, n_final,
                        n_explore=None, skip_starts=False, lam0=1e-3, max_step=1.0, ends: bool = False,
                        stop_tol=None, count: bool = False, soft_after=None, soft_tol=None, give_up_chi2=None,
                        give_up_after=None, jac_use=None, scout_give_up=None, scout_after: int = 1,
                        end_costs: bool = False):
    """Minimise 0.5 |r|^2 for ``fun(theta, args) -> (r, aux)`` from ``starts`` (S, P) (see the module).

    free, first: (P,) bool. n_explore: (traced) how many of the starts to explore, the first ones (None:
    all); n_start and n_final may be traced too (n_start 1: each start is only evaluated, and the final
    iterations go on from the one of lowest cost). skip_starts: (traced) go straight to the final
    iterations from ``starts[0]``. Returns theta (P,), r, the Jacobian of r (R, P) and aux at theta; with
    ``ends``, also where each start ended (S, P) (non-finite ones as they are; a start not explored as it
    was given). stop_tol: the final iterations end early once the Gauss-Newton decrement still to go (chi2
    units, ``lsq.fit_statistics``'s) is below it (None: they all run); under ``vmap`` each record keeps the
    point where it stopped. soft_after, soft_tol: after this many final iterations (traced), a decrement
    below ``soft_tol`` ends them too (a fit that has converged, though not to ``stop_tol``). give_up_chi2:
    (traced; with ``stop_tol`` and ``soft_after``) after ``give_up_after`` final iterations (None:
    ``soft_after``), the solve also ends once |r|^2 less the decrement still to go is above it (inf: never). A negative
    ``n_final`` with ``skip_starts`` runs nothing (the starts' first row is returned, with zero residuals).
    count: also return how many iterations ran (evaluations of the residuals and their Jacobian).
    jac_use: ``jac_use(args, used) -> args`` for each evaluation, told (traced bool) whether its Jacobian
    will be used: not where the next iteration starts afresh (a start only evaluated, as H1's are, or the
    last of a start's exploration), so that ``fun`` may skip its costly columns there (None: ``args``).
    scout_give_up, scout_after: a start being explored is left (its end is where it stands) once, from its
    ``scout_after``-th evaluation on (1: the start itself), its cost is above ``scout_give_up`` times the lowest cost an earlier start
    ended at (None: every start runs its ``n_start`` iterations). end_costs: with ``ends``, also the cost
    0.5 |r|^2 each start ended at (S,) (inf: not finite, or not explored).
    """
    starts = jnp.asarray(starts)
    n_starts = starts.shape[0]
    explore = n_start * (n_starts if n_explore is None else n_explore)
    offset = jnp.where(skip_starts, explore, 0)

    def value_and_jac(theta, used):
        given = args if jac_use is None else jac_use(args, used)
        jac, (r, aux) = jax.jacfwd(lambda t: (lambda out: (out[0], out))(fun(t, given)), has_aux=True)(theta)
        return r, jac, aux

    def cost_of(r):
        c = 0.5 * jnp.sum(jnp.square(r))
        return jnp.where(jnp.isfinite(c), c, jnp.inf)

    def body(i, k, state, best, last, last_cost):
        theta, r, jac, aux, cost, lam, nu = state
        exploring = k < explore
        local = k % n_start
        # a new start: evaluate it afresh; the end of the starts: go on from the best
        fresh = (i == 0) | (exploring & (local == 0)) | (k == explore)
        ended = (k > 0) & (k <= explore) & (local == 0)                              # a start ends here
        best = jax.tree.map(lambda b, s: jnp.where(ended & (cost < best[4]), s, b), best, state[:5])
        j = jnp.clip(k // n_start - 1, 0, n_starts - 1)                              # the start that ends at k
        last = last.at[j].set(jnp.where(ended, state[0], last[j]))
        last_cost = last_cost.at[j].set(jnp.where(ended, cost, last_cost[j]))
        restart = jnp.where(k == explore, best[0], starts[jnp.minimum(k // n_start, n_starts - 1)])
        mask = jnp.where(exploring & (local < n_first), first, free)
        jm = jac * mask
        delta, g, _ = damped_step(r, jm, mask, lam)
        delta = delta * jnp.minimum(1.0, jnp.min(max_step / jnp.maximum(jnp.abs(delta), tiny(delta))))
        trial = jnp.where(fresh, jnp.where(i == 0, starts[0], restart), theta + delta)
        # the next iteration starts afresh (a new start, or the best one's final iterations): no step uses this
        # Jacobian (the best start is evaluated again)
        used = ~((k + 1 <= explore) & ((k + 1) % n_start == 0))
        r_t, j_t, aux_t = value_and_jac(trial, used)
        cost_t = cost_of(r_t)
        pred = -jnp.dot(g, delta) - 0.5 * jnp.sum(jnp.square(jm @ delta))
        rho = (cost - cost_t) / jnp.where(pred > 0, pred, jnp.inf)
        ok = (cost_t < cost) & jnp.all(jnp.isfinite(trial)) & jnp.all(jnp.isfinite(j_t)) & (rho > 0)
        shrink = jnp.maximum(1.0 / 3.0, 1.0 - jnp.power(2.0 * jnp.clip(rho, 0.0, 1.0) - 1.0, 3))
        switch = exploring & (local == n_first)          # the texture-only iterations end: damping afresh
        lam = jnp.where(fresh | switch, lam0, jnp.clip(jnp.where(ok, lam * shrink, lam * nu), 1e-12, 1e12))
        nu = jnp.where(fresh | ok, 2.0, jnp.minimum(nu * 2.0, 1e6))
        take = ok | fresh
        new = jax.tree.map(lambda a, b: jnp.where(take, a, b), (trial, r_t, j_t, aux_t, cost_t),
                           (theta, r, jac, aux, cost))
        done = False
        if stop_tol is not None:
            dec = gauss_newton_decrement(new[1], new[2], free)
            done = (k >= explore) & (dec < stop_tol)
            if soft_after is not None:
                late = k >= explore + soft_after
                done = done | late & (dec < soft_tol)
                if give_up_chi2 is not None:
                    after = soft_after if give_up_after is None else give_up_after
                    done = done | (k >= explore + after) & (jnp.sum(jnp.square(new[1])) - dec > give_up_chi2)
        k_next = k + 1
        if scout_give_up is not None:
            # a start far above the best end so far: its remaining iterations cannot make it the best
            behind = exploring & (local + 1 >= scout_after) & (local + 1 < n_start) & (new[4] > scout_give_up * best[4])
            k_next = jnp.where(behind, (k // n_start + 1) * n_start, k_next)
        return (*new, lam, nu), best, last, last_cost, jnp.asarray(done), k_next

    r_shape, aux_shape = jax.eval_shape(fun, starts[0], args)     # a caller's earlier shapes of ``fun`` serve
    dtype = starts.dtype
    zeros = lambda s: jnp.zeros(s.shape, s.dtype)        # noqa: E731
    state = (starts[0], jnp.zeros(r_shape.shape, dtype), jnp.zeros(r_shape.shape + starts.shape[1:], dtype),
             jax.tree.map(zeros, aux_shape), jnp.asarray(jnp.inf, dtype), jnp.asarray(lam0, dtype),
             jnp.asarray(2.0, dtype))
    best = state[:5]
    n_total = jnp.where(skip_starts, n_final, explore + n_final)

    def step(loop):
        i, k, _, *carry = loop
        *carry, done, k_next = body(i, k, *carry)
        return i + 1, k_next, done, *carry

    n_iter, _, _, (theta, r, jac, aux, _, _, _), _, last, last_cost = jax.lax.while_loop(
        lambda loop: (loop[1] < offset + n_total + 1) & ~loop[2], step,
        (0, offset, jnp.asarray(False), state, best, starts, jnp.full(n_starts, jnp.inf, dtype)))
    out = (theta, r, jac, aux) + ((last,) if ends else ()) + ((last_cost,) if ends and end_costs else ())
    return out + (n_iter,) if count else out
