"""The pair model's spectral-window average, weighted by the shallow spectrum the estimator saw."""

import jax.numpy as jnp
import numpy as np
import pytest

from tactile_jax.inference.pair_fit import exact_residuals, fit_pair, kernel_log_weights
from tactile_jax.model.r_curve import log_r_exact
from tactile_jax.model.sensor import PAPER_SENSOR
from tactile_jax.spectral.estimate import spectral_kernel

D1, D2 = PAPER_SENSOR.d1, PAPER_SENSOR.d2
NPERSEG = 2048
D_OMEGA = 2 * np.pi * 1000.0 / NPERSEG
OMEGA = D_OMEGA * np.arange(129)                            # the lowest 129 bins of a 2048-point Welch at 1 kHz
KERNEL = spectral_kernel(np.hanning(NPERSEG)[None, :], NPERSEG, 3.0)          # Hann: offsets in half bins
SPEED, A = 0.015, 4e-3                                      # the slow, large-contact cell of speed_vs_error


def _spectrum(omega):
    """A steep shallow spectrum, log-linear in |omega| (so interpolation between bins is exact): e^-1 per 3 bins."""
    return np.exp(-np.abs(omega) / (3 * D_OMEGA))


def _expected_log_ratio():
    """log of sum w S R / sum w S over the window around each bin: the H1 ratio the estimator returns."""
    offsets, weights = (np.asarray(k) for k in KERNEL)
    at = np.abs(OMEGA[:, None] + offsets[None, :] * D_OMEGA)
    r = np.exp(np.asarray(log_r_exact(jnp.asarray(at / SPEED), D1, D2, A)))
    ws = weights[None, :] * _spectrum(at)
    return np.log(np.sum(ws * r, axis=1) / np.sum(ws, axis=1))


@pytest.fixture(scope="module")
def exact_ratio():
    y = _expected_log_ratio()
    mask = (np.arange(OMEGA.size) >= 3) & (np.arange(OMEGA.size) < 40)       # clear of DC's fold, in band
    return y, np.full(OMEGA.size, 0.01), mask


@pytest.mark.slow
def test_weighted_window_recovers_the_truth_where_the_flat_one_is_biased(exact_ratio):
    y, err, mask = exact_ratio
    weighted = fit_pair(OMEGA, y, err, mask, D1, D2, kernel=KERNEL, spectrum=_spectrum(OMEGA), speed0=0.02, a0=3e-3)
    flat = fit_pair(OMEGA, y, err, mask, D1, D2, kernel=KERNEL, speed0=0.02, a0=3e-3)
    assert weighted.converged and flat.converged
    assert weighted.speed == pytest.approx(SPEED, rel=1e-6) and weighted.a == pytest.approx(A, rel=1e-5)
    # the flat window misreads the same noise-free ratio: a by several per cent
    assert abs(flat.a / A - 1) > 0.02


def test_kernel_log_weights_flat_and_weighted():
    offsets, log_w = kernel_log_weights(OMEGA, KERNEL)
    assert log_w.ndim == 1 and np.all(np.isfinite(log_w)) and np.exp(log_w).sum() == pytest.approx(1.0)
    _, log_ws = kernel_log_weights(OMEGA, KERNEL, _spectrum(OMEGA))
    assert log_ws.shape == (OMEGA.size, offsets.size)
    # a flat spectrum gives the flat window; a spectrum with no positive bin falls back to it
    np.testing.assert_allclose(kernel_log_weights(OMEGA, KERNEL, np.full(OMEGA.size, 7.0))[1] - log_w, 0.0,
                               atol=1e-12)
    np.testing.assert_array_equal(kernel_log_weights(OMEGA, KERNEL, np.zeros(OMEGA.size))[1], log_w)


def test_the_joint_pipelines_pair_starts_are_pair_fits_model(exact_ratio):
    """The joint pipeline starts from each pair fitted alone with ``pair_fit``'s residuals, given the flat
    spectral window on the fixed kernel grid (zero weights as -2e4 in log): the same residuals as with the
    window's own support."""
    from tactile_jax.spectral.segments import KERNEL_OFFSETS

    y, err, mask = exact_ratio
    theta = jnp.log(jnp.asarray([0.017, 3.5e-3, 1.1]))
    off, lw = kernel_log_weights(OMEGA, KERNEL)
    ref = np.asarray(exact_residuals(theta, (jnp.asarray(OMEGA), jnp.asarray(y), jnp.asarray(err), jnp.asarray(mask),
                                        D1, D2, jnp.asarray(off), jnp.asarray(lw))))
    w = np.full(KERNEL_OFFSETS.size, -2e4)
    for o, v in zip(off, lw):
        w[int(round((o - KERNEL_OFFSETS[0]) * 2))] = v
    got = np.asarray(exact_residuals(theta, (jnp.asarray(OMEGA), jnp.asarray(y), jnp.asarray(err), jnp.asarray(mask),
                                        D1, D2, jnp.asarray(KERNEL_OFFSETS), jnp.asarray(w))))
    np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-9)
