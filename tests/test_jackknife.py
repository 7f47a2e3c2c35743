"""The linearised delete-one jackknife (``jackknife``) against a problem whose answer is known."""

import jax.numpy as jnp
import numpy as np
import pytest
from typing import NamedTuple

from tactile_jax import jackknife


class _Line(NamedTuple):
    x: jnp.ndarray
    y: jnp.ndarray
    sigma: jnp.ndarray


def _residuals(theta, data):
    return (data.y - (theta[0] + theta[1] * data.x + theta[2] * data.x ** 2)) / data.sigma


def test_linear_model_shifts_are_exact_refits_and_variance_is_the_real_one():
    # K replicate measurements of a quadratic; the fit sees their mean with an error stated 2x too large
    rng = np.random.default_rng(4)
    k, n, s = 400, 30, 0.3
    x = np.linspace(-1, 1, n)
    reps = 1.0 + 0.5 * x - 0.2 * x ** 2 + s * rng.standard_normal((k, n))
    mean = reps.mean(axis=0)
    loo = (reps.sum(axis=0) - reps) / (k - 1)
    sigma = 2.0 * s / np.sqrt(k)
    data = _Line(jnp.asarray(x), jnp.asarray(mean), jnp.asarray(sigma))
    design = np.stack([np.ones(n), x, x ** 2], axis=1)
    free = np.array([True, True, False])                 # the curvature held: zero shifts, zero rows
    theta = np.append(np.linalg.lstsq(design[:, :2], mean + 0.2 * x ** 2, rcond=None)[0], -0.2)
    shifts, unit = jackknife.linear_shifts(_residuals, jnp.asarray(theta), data, {"y": jnp.asarray(loo)},
                                           jnp.asarray(free))
    shifts, unit = np.asarray(shifts), np.asarray(unit)
    # linear model: the shift is the refit's change, exactly
    refit = np.linalg.lstsq(design[:, :2], (loo - theta[2] * x ** 2).T, rcond=None)[0].T
    np.testing.assert_allclose(shifts[:, :2], refit - theta[:2], rtol=1e-8, atol=1e-12)
    assert np.all(shifts[:, 2] == 0) and np.all(unit[2] == 0) and np.all(unit[:, 2] == 0)
    np.testing.assert_allclose(unit[:2, :2], np.linalg.inv(design[:, :2].T @ design[:, :2]) * sigma ** 2,
                               rtol=1e-8, atol=1e-15)
    # the jackknife sees the real noise: a variance 1/4 of the stated one (+/- 2 sqrt(2/K) ~ 14 %)
    cov = np.asarray(jackknife.covariance(shifts))
    var, var_unit = np.diag(cov), np.diag(unit)
    assert float(jackknife.pooled_scale(var, var_unit, free)) == pytest.approx(0.25, rel=0.15)
    assert float(jackknife.covariance(shifts, overlap=1.5)[0, 0]) == pytest.approx(1.5 * cov[0, 0])
    assert np.isnan(float(jackknife.pooled_scale(var, var_unit, np.zeros(3, bool))))
    # a fixed parameter (zero variance) is never pooled, even when asked for
    assert float(jackknife.pooled_scale(var, var_unit, np.ones(3, bool))) == pytest.approx(
        float(jackknife.pooled_scale(var, var_unit, free)))


def test_own_scales_keep_each_ratio_and_pool_the_rest():
    var_unit = np.array([1.0, 4.0, 2.0, 3.0, 0.0])
    var_jk = np.array([1.2, 10.0, 6.0, 30.0, 0.0])          # ratios 1.2, 2.5, 3, 10, (fixed)
    own = np.array([True, True, True, False, True])
    pooled, scales = (np.asarray(v) for v in jackknife.own_scales(var_jk, var_unit, own, 1.5))
    assert float(pooled) == pytest.approx((1.2 + 2.5 + 3.0) / 3)
    # the first ratio is below the floor; the fourth parameter is not its own, the fixed one pooled
    np.testing.assert_allclose(scales, [1.5, 2.5, 3.0, pooled, pooled])
    pooled, scales = jackknife.own_scales(var_jk, var_unit, np.zeros(5, bool), 1.0)
    assert np.isnan(float(pooled)) and np.all(np.isnan(np.asarray(scales)))


def test_the_fits_own_jacobian_gives_the_same_shifts():
    # lsq.least_squares keeps its Jacobian at the optimum (LsqResult.jac): passed in, linear_shifts skips
    # its own forward-mode pass (the biggest part of its compilation) and must not change a number
    from tactile_jax.lsq import least_squares

    rng = np.random.default_rng(6)
    x = np.linspace(-1, 1, 25)
    y = np.exp(0.3 + 0.8 * x) + 0.05 * rng.standard_normal((12, 25))
    data = _Line(jnp.asarray(x), jnp.asarray(y.mean(axis=0)), jnp.full(25, 0.05))
    loo = (y.sum(axis=0) - y) / 11

    free = jnp.asarray([True, True, False])
    fit = least_squares(_exp_residuals, jnp.asarray([0.0, 0.5, 1.0]), data, free)
    assert fit.jac.shape == (25, 3) and bool(fit.converged)
    own = jackknife.linear_shifts(_exp_residuals, fit.theta, data, {"y": jnp.asarray(loo)}, free, fit.jac)
    again = jackknife.linear_shifts(_exp_residuals, fit.theta, data, {"y": jnp.asarray(loo)}, free)
    for a, b in zip(own, again):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-14)
    assert np.all(np.asarray(own[0])[:, 2] == 0) and np.any(np.asarray(own[0])[:, :2] != 0)


def _exp_residuals(theta, d):
    return (d.y - theta[2] * jnp.exp(theta[0] + theta[1] * d.x)) / d.sigma


def test_bin_correlation_of_moving_average_noise():
    # errors e_i = u_i + 0.5 u_(i-1): rho_1 = 0.5 / 1.25 = 0.4, rho_2 = 0; K = 300 segments, 40 bins
    rng = np.random.default_rng(5)
    u = rng.standard_normal((300, 41))
    reps = u[:, 1:] + 0.5 * u[:, :-1]
    loo = (reps.sum(axis=0) - reps) / (reps.shape[0] - 1)
    mask = np.ones(40, bool)
    mask[[10, 11]] = False                                # gaps in the band are skipped, not bridged
    rho = jackknife.bin_correlation(loo, mask, max_lag=2)
    assert rho[0] == pytest.approx(0.4, abs=0.05) and abs(rho[1]) < 0.05
    assert np.all(np.isnan(jackknife.bin_correlation(loo, np.zeros(40, bool))))
