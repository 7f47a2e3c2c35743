"""The y pair conditioned on the x pair (``cross_pair``): the measured regression and its weights."""

import numpy as np
import pytest

from tactile_jax.model import cross_pair
from tactile_jax.spectral.estimate import estimate_spectra


def _channels(rng, n):
    """x1, x2 and y1, y2 that share a common source through known real gains, plus their own noise."""
    s, e = rng.standard_normal(n), rng.standard_normal((4, n))
    return np.stack([s + 0.5 * e[0], 0.6 * s + 0.4 * e[1], 0.8 * s + 0.5 * e[2], 0.3 * s + 0.2 * e[3] + 0.4 * e[2]])


@pytest.mark.slow
def test_chain_is_the_least_squares_regression_and_its_weights_whiten_it():
    rng = np.random.default_rng(3)
    spec = estimate_spectra(_channels(rng, 2 ** 15), 1000.0)
    est = cross_pair.chain_estimate(spec.psd, spec.csd, spec.xy, spec.dof)
    m = np.asarray(cross_pair.chain_matrix(spec.psd, spec.csd, spec.xy))
    b = 100                                                        # one bin: numpy's regression
    np.testing.assert_allclose(m[b], m[b].conj().T)
    beta = np.linalg.solve(m[b, :3, :3], m[b, :3, 3])
    np.testing.assert_allclose(np.asarray(est.beta2)[b], beta, rtol=1e-10)
    c = np.real(m[b, 3, 3] - m[b, :3, 3].conj() @ beta)
    assert float(est.log_c[1, b]) == pytest.approx(np.log(c))
    w = np.asarray(est.w2)[b]
    np.testing.assert_allclose(w.conj().T @ w, 2 * (spec.dof - 3) / c * m[b, :3, :3], rtol=1e-10)
    assert bool(np.all(np.asarray(est.ok)[:, 1:]))
    # the truth: the population regression of y2 on (x1, x2, y1) (white spectra, so every bin has it),
    # and the whitened deviations over all bins are about unit normal, real and imaginary parts alike
    cov = np.array([[1.25, 0.6, 0.8, 0.3], [0.6, 0.52, 0.48, 0.18], [0.8, 0.48, 0.89, 0.44],
                    [0.3, 0.18, 0.44, 0.29]])
    true = np.linalg.solve(cov[:3, :3], cov[:3, 3])
    z = np.einsum("mij,mj->mi", np.asarray(est.w2)[1:-1], np.asarray(est.beta2)[1:-1] - true)
    parts = np.concatenate([z.real.ravel(), z.imag.ravel()])
    assert abs(parts.mean()) < 0.1 and 0.8 < parts.std() < 1.25, (parts.mean(), parts.std())
    # the residual PSD: its log's mean is the offset plus a channel PSD's own psi(K) - log K, its sd 1 / weight
    from scipy.special import digamma
    weight, offset = cross_pair.chain_offsets(spec.dof)
    c_true = (cov[3, 3] - cov[:3, 3] @ true) * 2 / 1000.0              # one-sided density, units^2/Hz
    dev = np.asarray(est.log_c[1, 1:-1]) - np.log(c_true)
    assert dev.mean() == pytest.approx(offset[1] + digamma(spec.dof) - np.log(spec.dof), abs=0.03)
    assert 0.8 < dev.std() * weight[1] < 1.25
