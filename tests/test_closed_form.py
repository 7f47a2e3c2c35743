"""The paper's closed-form estimators on exact synthetic inputs."""

import numpy as np

from tactile_jax.model.closed_form import dominant_wavenumber, radius_from_offset, slope_speed
from tactile_jax.model.r_curve import log_r_rough
from tactile_jax.model.sensor import PAPER_SENSOR

D1, D2 = PAPER_SENSOR.d1, PAPER_SENSOR.d2


def test_dominant_wavenumber_inverts_depth_decay():
    k0 = 2 * np.pi / 1.5e-3
    assert np.isclose(dominant_wavenumber(1.0, np.exp(-k0 * (D2 - D1)), D1, D2), k0)


def test_slope_speed_recovers_line_and_calibrated_errors():
    rng = np.random.default_rng(1)
    v, a = 0.023, 2e-3
    omega = np.linspace(5.0, 600.0, 200)
    truth = np.asarray(log_r_rough(omega / v, D1, D2, a))
    sigma = np.full_like(omega, 0.05)
    pulls = []
    for _ in range(200):
        y = truth + sigma * rng.standard_normal(omega.shape)
        fit = slope_speed(omega, y, sigma, np.ones_like(omega, bool), D1, D2)
        assert bool(fit.ok)
        pulls.append((float(fit.speed) - v) / float(fit.speed_err))
    pulls = np.array(pulls)
    assert abs(pulls.mean()) < 0.25 and 0.8 < pulls.std() < 1.2
    assert np.isclose(radius_from_offset(float(fit.intercept), D1, D2), a, rtol=0.05)


def test_slope_speed_reports_failure_as_data():
    omega = np.linspace(1.0, 10.0, 5)
    rising = slope_speed(omega, omega * 1.0, np.ones(5), np.ones(5, bool), D1, D2)
    assert not bool(rising.ok) and np.isnan(rising.speed)
    few = slope_speed(omega, -omega, np.ones(5), np.array([1, 1, 0, 0, 0], bool), D1, D2)
    assert not bool(few.ok) and int(few.n_bins) == 2
    assert np.isnan(radius_from_offset(-0.1, D1, D2))
