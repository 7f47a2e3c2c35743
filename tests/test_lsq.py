"""lsq.least_squares: convergence as data (the Gauss-Newton decrement) and agreement with scipy."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tactile_jax.inference.lsq import DECREMENT_TOL, DOGLEG, least_squares

jax.config.update("jax_enable_x64", True)


def _decay(theta, args):
    """Weighted residuals of y = A exp(-t / tau), theta = (log A, log tau)."""
    t, y, sd = args
    return (y - jnp.exp(theta[0] - t / jnp.exp(theta[1]))) / sd


@pytest.fixture(scope="module")
def problem():
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 5.0, 60)
    sd = 0.02 * np.ones_like(t)
    y = 2.0 * np.exp(-t / 1.3) + sd * rng.standard_normal(t.size)
    return (jnp.asarray(t), jnp.asarray(y), jnp.asarray(sd)), np.array([np.log(0.5), np.log(4.0)])


def test_converged_fit_matches_scipy_and_has_tiny_decrement(problem):
    from scipy.optimize import least_squares as scipy_lsq

    args, theta0 = problem
    res = least_squares(_decay, jnp.asarray(theta0), args, jnp.array([True, True]))
    ref = scipy_lsq(lambda th: np.asarray(_decay(jnp.asarray(th), args)), theta0, method="lm", xtol=1e-12)
    assert bool(res.converged)
    assert float(res.decrement) < 1e-6
    sd = np.sqrt(np.diag(np.asarray(res.cov)))
    np.testing.assert_allclose(np.asarray(res.theta), ref.x, atol=1e-4 * sd.min())


def test_capped_solve_far_from_the_optimum_is_not_converged(problem):
    args, theta0 = problem
    res = least_squares(_decay, jnp.asarray(theta0), args, jnp.array([True, True]), max_steps=2)
    assert int(res.n_steps) == 2
    assert float(res.decrement) > DECREMENT_TOL
    assert not bool(res.converged)


def test_capped_solve_at_the_optimum_counts_as_converged(problem):
    """Stopped by max_steps where a full Gauss-Newton step gains < DECREMENT_TOL in chi2: converged."""
    args, theta0 = problem
    best = least_squares(_decay, jnp.asarray(theta0), args, jnp.array([True, True]))
    res = least_squares(_decay, best.theta, args, jnp.array([True, True]), max_steps=2, rtol=0.0, atol=0.0)
    assert int(res.n_steps) == 2                       # zero tolerances: the solver itself never stops
    assert float(res.decrement) < DECREMENT_TOL
    assert bool(res.converged)


def test_step_sigma_is_the_remaining_gauss_newton_step_in_sigmas(problem):
    """``step_sigma``: the undamped step still to go over each parameter's (J^T J)^-1 sd, by numpy."""
    args, theta0 = problem
    res = least_squares(_decay, jnp.asarray(theta0), args, jnp.array([True, True]), max_steps=2)
    th = np.asarray(res.theta)
    r = np.asarray(_decay(jnp.asarray(th), args))
    jac = np.asarray(jax.jacfwd(_decay)(jnp.asarray(th), args))
    h_inv = np.linalg.inv(jac.T @ jac)
    step = -h_inv @ jac.T @ r
    np.testing.assert_allclose(np.asarray(res.step_sigma), step / np.sqrt(np.diag(h_inv)), rtol=1e-6)
    np.testing.assert_allclose(float(res.decrement), step @ jac.T @ jac @ step, rtol=1e-6)
    assert np.max(np.abs(np.asarray(res.step_sigma))) > 1.0          # far from the optimum: still moving


def test_a_fixed_parameter_has_no_step(problem):
    args, theta0 = problem
    res = least_squares(_decay, jnp.asarray(theta0), args, jnp.array([True, False]), max_steps=2)
    assert float(res.step_sigma[1]) == 0.0 and np.isfinite(float(res.step_sigma[0]))


@pytest.mark.slow
def test_dogleg_goes_on_from_a_capped_solve_to_the_same_optimum(problem):
    """``DOGLEG`` from where a capped LM stopped reaches LM's own optimum."""
    args, theta0 = problem
    free = jnp.array([True, True])
    best = least_squares(_decay, jnp.asarray(theta0), args, free)
    capped = least_squares(_decay, jnp.asarray(theta0), args, free, max_steps=2)
    res = least_squares(_decay, capped.theta, args, free, solver=DOGLEG)
    assert bool(res.converged) and float(res.decrement) < 1e-6
    sd = np.sqrt(np.diag(np.asarray(best.cov)))
    np.testing.assert_allclose(np.asarray(res.theta), np.asarray(best.theta), atol=1e-4 * sd.min())
