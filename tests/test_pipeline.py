"""End to end on simulated scenes: space-domain simulator -> spectra -> closed-form and exact-R fits.

The simulator never calls the R-curve formulas, so agreement here tests the
physics of both sides.
"""

import dataclasses

import numpy as np
import pytest

from tactile_jax.model.closed_form import slope_speed
from tactile_jax.cli.demo import DEFAULT_PREWHITEN, paper_fig5_scene
from tactile_jax.inference.pair_fit import fit_pair
from tactile_jax.model.r_curve import log_r_exact
from tactile_jax.simulation.scene import simulate
from tactile_jax.spectral.estimate import amplitude_ratio, estimate_spectra, usable_band


def _x_pair(scene):
    rec = simulate(scene)
    spec = estimate_spectra(rec.signals, rec.fs, prewhiten=DEFAULT_PREWHITEN)
    ratio = amplitude_ratio(spec)
    band = usable_band(ratio)
    d1, d2 = rec.depths
    return (ratio.omega, ratio.log_ratio[0], ratio.log_ratio_err[0], band[0], d1, d2), spec.bin_factor


@pytest.mark.parametrize("a", [1.5e-3, 3e-3])
def test_measured_ratio_follows_exact_r_curve(a):
    (omega, lr, err, band, d1, d2), _ = _x_pair(dataclasses.replace(paper_fig5_scene(seed=3), contact_radius=a))
    m = np.asarray(band)
    assert m.sum() >= 15
    pull = (np.asarray(lr) - np.asarray(log_r_exact(np.asarray(omega) / 0.023, d1, d2, a))) / np.asarray(err)
    assert abs(np.mean(pull[m])) < 1.0 and np.mean(pull[m] ** 2) < 4.0


@pytest.mark.slow
def test_exact_r_fit_recovers_speed_and_radius():
    args, bf = _x_pair(paper_fig5_scene(seed=1))
    fit = fit_pair(*args, bin_factor=bf)
    assert fit.converged
    assert fit.speed == pytest.approx(0.023, rel=0.02) and abs(fit.speed - 0.023) < 3 * fit.speed_err
    assert fit.a == pytest.approx(3e-3, rel=0.1) and abs(fit.a - 3e-3) < 3 * fit.a_err


@pytest.mark.slow
def test_eq6_slope_holds_for_a_large_contact_and_is_flagged_for_a_small_one():
    args, bf = _x_pair(dataclasses.replace(paper_fig5_scene(seed=2), contact_radius=10e-3))
    big = slope_speed(*args, bin_factor=bf)
    assert bool(big.ok) and float(big.speed) == pytest.approx(0.023, rel=0.02)
    args, bf = _x_pair(dataclasses.replace(paper_fig5_scene(seed=2), contact_radius=1.5e-3))
    small = slope_speed(*args, bin_factor=bf)
    # the window bends the line: the slope overestimates |v| and says so through chi2
    assert float(small.speed) > 0.023 * 1.03 and float(small.redchi) > 3.0


@pytest.mark.slow
def test_jaxopt_solver_agrees_with_optimistix():
    args, bf = _x_pair(paper_fig5_scene(seed=1))
    a = fit_pair(*args, bin_factor=bf)
    b = fit_pair(*args, bin_factor=bf, solver="jaxopt")
    assert b.speed == pytest.approx(a.speed, rel=1e-4) and b.a == pytest.approx(a.a, rel=1e-3)
