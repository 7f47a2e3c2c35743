"""Cramer-Rao bounds (crb): analytic cases, Monte-Carlo efficiency of the exact-R fit, blind directions."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tactile_jax.closed_form import slope_speed
from tactile_jax.crb import banded_correlation, bound_covariance, fisher_information, pair_crb
from tactile_jax.pair_fit import _residuals as _pair_residuals
from tactile_jax.pair_fit import fit_pair
from tactile_jax.r_curve import log_r_exact
from tactile_jax.sensor import PAPER_SENSOR

D1, D2 = PAPER_SENSOR.d1, PAPER_SENSOR.d2
OMEGA = 2 * np.pi * np.arange(1, 129) * (1000.0 / 512)       # 128 bins of a 512-point Welch at 1 kHz


def _line_residuals(theta, args):
    omega, y, err, d1, d2 = args
    c, log_v = theta[0], theta[1]
    return (y - (c - omega * (d2 - d1) / jnp.exp(log_v))) / err


def test_line_bound_matches_weighted_least_squares_error():
    """Eq. 6 line: the bound on |v| is the weighted-LS error propagated through v = -eps / slope."""
    v = 0.023
    err = 0.02 + 0.1 * OMEGA / OMEGA.max()
    y = -OMEGA * (D2 - D1) / v                       # exact: redchi 0, slope_speed's scale is 1
    line = slope_speed(jnp.asarray(OMEGA), jnp.asarray(y), jnp.asarray(err), jnp.ones(OMEGA.size, bool), D1, D2)
    args = (jnp.asarray(OMEGA), jnp.asarray(y), jnp.asarray(err), D1, D2)
    fisher = fisher_information(_line_residuals, jnp.array([0.0, np.log(v)]), args, jnp.array([True, True]))
    x = np.stack([np.ones_like(OMEGA), OMEGA * (D2 - D1) / v], 1) / err[:, None]     # d model / d(c, log v)
    np.testing.assert_allclose(np.asarray(fisher), x.T @ x, rtol=1e-10)
    cov = bound_covariance(fisher, jnp.array([True, True]))
    np.testing.assert_allclose(v * np.sqrt(float(cov[1, 1])), float(line.speed_err), rtol=1e-8)


def test_bin_factor_and_fixed_parameters():
    err = np.full(OMEGA.size, 0.05)
    mask = OMEGA < 2 * np.pi * 150
    b1 = pair_crb(OMEGA, err, mask, D1, D2, 0.023, 2e-3)
    b2 = pair_crb(OMEGA, err, mask, D1, D2, 0.023, 2e-3, bin_factor=1.94)
    np.testing.assert_allclose(np.asarray(b2.speed_sd), np.asarray(b1.speed_sd) * np.sqrt(1.94), rtol=1e-10)
    # a gain that must be fitted too (confounded with the radius offset) can only widen the bound
    bg = pair_crb(OMEGA, err, mask, D1, D2, 0.023, 2e-3, fit_gain=True)
    assert float(bg.a_sd) > 1.5 * float(b1.a_sd)
    assert float(bg.speed_sd[0]) >= float(b1.speed_sd[0])
    assert float(b1.log_cov[2, 2]) == 0.0                     # a known gain: no variance


def _pair_args(err, mask):
    """``pair_crb``'s residual arguments for a single-bin kernel."""
    return (jnp.asarray(OMEGA), jnp.zeros(OMEGA.size), jnp.where(jnp.asarray(mask), jnp.asarray(err), 1.0),
            jnp.asarray(mask), D1, D2, jnp.zeros(1), jnp.zeros(1))


def test_measured_bin_correlation():
    err = np.full(OMEGA.size, 0.05)
    mask = (OMEGA > 2 * np.pi * 10) & (OMEGA < 2 * np.pi * 150)
    b1 = pair_crb(OMEGA, err, mask, D1, D2, 0.023, 2e-3)
    b0 = pair_crb(OMEGA, err, mask, D1, D2, 0.023, 2e-3, bin_corr=(0.0, 0.0))
    np.testing.assert_allclose(np.asarray(b0.fisher), np.asarray(b1.fisher), rtol=1e-10)
    # neighbours sharing noise carry less information than independent bins; sharing it with
    # the opposite sign, more (for a smooth curve). A smooth model's sum over many bins sees
    # the white-noise bin_factor 1 + 2 rho: the banded bound lies near it.
    plus = pair_crb(OMEGA, err, mask, D1, D2, 0.023, 2e-3, bin_corr=(0.3,))
    minus = pair_crb(OMEGA, err, mask, D1, D2, 0.023, 2e-3, bin_corr=(-0.2,))
    v1 = float(b1.speed_sd[0])
    assert float(plus.speed_sd[0]) == pytest.approx(v1 * np.sqrt(1.6), rel=0.1)
    assert float(minus.speed_sd[0]) == pytest.approx(v1 * np.sqrt(0.6), rel=0.1)
    # a gap in the band: the bound uses the used bins' own correlation block, as if the gap were absent
    gap = mask.copy()
    gap[np.flatnonzero(mask)[10:14]] = False
    g_corr = pair_crb(OMEGA, err, gap, D1, D2, 0.023, 2e-3, bin_corr=(0.3,))
    used = np.flatnonzero(gap)
    c = banded_correlation((0.3,), used)
    assert c[9, 10] == 0.0 and c[8, 9] == pytest.approx(0.3)         # bins 4 apart across the gap: no correlation
    jac = np.asarray(jax.jacfwd(_pair_residuals)(jnp.log(jnp.array([0.023, 2e-3, 1.0])), _pair_args(err, gap)))
    jac = jac[used][:, :2]
    np.testing.assert_allclose(np.asarray(g_corr.fisher)[:2, :2], jac.T @ np.linalg.solve(c, jac), rtol=1e-8)
    # an impossible measured correlation (not positive definite) still gives a finite bound
    c = banded_correlation((0.9, 0.9), np.arange(20))
    assert np.linalg.eigvalsh(c)[0] > 0 and np.allclose(np.diag(c), 1.0)
    assert np.isfinite(float(pair_crb(OMEGA, err, mask, D1, D2, 0.023, 2e-3, bin_corr=(0.9, 0.9)).speed_sd[0]))


def test_no_information_is_infinite_not_finite():
    err = np.full(OMEGA.size, 0.05)
    b = pair_crb(OMEGA, err, np.zeros(OMEGA.size, bool), D1, D2, 0.023, 2e-3)
    assert np.isinf(float(b.speed_sd[0])) and np.isinf(float(b.a_sd))


def test_radius_bound_grows_with_the_contact():
    """A larger contact bends the ratio less: its radius is harder to measure (relative error grows)."""
    err = np.full(OMEGA.size, 0.05)
    mask = OMEGA < 2 * np.pi * 150
    rel = [float(pair_crb(OMEGA, err, mask, D1, D2, 0.023, a).a_sd) / a for a in (1e-3, 3e-3, 10e-3)]
    assert rel[0] < rel[1] < rel[2]


def test_exact_fit_reaches_the_bound_monte_carlo():
    """Seeded Monte Carlo: the exact-R least-squares fit (fit_pair) has the spread of the bound
    (efficiency ~ 1), and its own error bar is the bound."""
    v, a, sigma = 0.023, 2e-3, 0.05
    mask = OMEGA < 2 * np.pi * 150
    err = np.full(OMEGA.size, sigma)
    truth = np.asarray(log_r_exact(OMEGA / v, D1, D2, a))
    bound = pair_crb(OMEGA, err, mask, D1, D2, v, a)
    rng = np.random.default_rng(5)
    ys = truth + sigma * rng.standard_normal((160, OMEGA.size))
    fits = [fit_pair(OMEGA, y, err, mask, D1, D2, speed0=0.02, a0=2.5e-3) for y in ys]
    assert all(f.converged for f in fits)
    vs, as_ = np.array([f.speed for f in fits]), np.array([f.a for f in fits])
    eff_v = float(bound.speed_sd[0]) ** 2 / np.mean((vs - v) ** 2)
    eff_a = float(bound.a_sd) ** 2 / np.mean((as_ - a) ** 2)
    # 160 draws: the MSE has a relative sd of about 11 %
    assert 0.7 < eff_v < 1.4, eff_v
    assert 0.7 < eff_a < 1.4, eff_a
    assert np.median([f.speed_err for f in fits]) == pytest.approx(float(bound.speed_sd[0]), rel=0.15)
    assert np.median([f.a_err for f in fits]) == pytest.approx(float(bound.a_sd), rel=0.15)
