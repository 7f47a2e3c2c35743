"""The R curve: closed form vs quadrature, extremes, limits and gradients."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.special
from scipy.integrate import quad

from tactile_jax.model import r_curve
from tactile_jax.model.probe import line_response, selectivity
from tactile_jax.model.r_curve import log_g, log_g_quadrature, log_r_exact, log_r_hertz, log_r_rough
from tactile_jax.model.sensor import PAPER_SENSOR
from tactile_jax.model.window import hertz_line_response, hertz_projection

D1, D2 = PAPER_SENSOR.d1, PAPER_SENSOR.d2


def test_exact_matches_quadrature_to_1e9():
    alpha = np.concatenate([[0.0], np.logspace(-2, 6, 241)])
    a = np.logspace(np.log10(10e-6), np.log10(0.1), 61)
    al, aa = np.meshgrid(alpha, a)
    gap = jax.jit(lambda al, d, aa: log_g(al, d, aa) - log_g_quadrature(al, d, aa))
    for d in (D1, D2):
        err = np.abs(np.asarray(gap(al, d, aa)))
        # |log G - log G_quad| is the relative error of G
        assert err.max() < 1e-9, (d, err.max())
    err_r = np.abs(np.asarray(jax.jit(lambda al, aa: log_r_exact(al, D1, D2, aa) - r_curve.log_r_quadrature(
        al, D1, D2, aa))(al, aa)))
    assert err_r.max() < 1e-9


def test_quadrature_reference_against_mpmath():
    mp = pytest.importorskip("mpmath")
    mp.mp.dps = 30
    for alpha, a, d in [(0.0, 1e-3, D1), (3e3, 0.85e-3, D2), (2.5e5, 1.17e-5, D1), (1e6, 0.1, D2)]:
        f = lambda k: mp.exp(-((k - alpha) ** 2) * a**2 / 6 - abs(k) * d)
        w = 40.0 / a  # Gaussian half-width, rad/m: give mpmath the peak's neighbourhood
        pts = sorted({0.0, *(max(p, 0.0) for p in np.linspace(alpha - w, alpha + w, 41))})
        ref = mp.log(mp.quad(f, [-mp.inf, *pts, mp.inf], maxdegree=10)) - mp.log(mp.sqrt(6 * mp.pi) / a)
        assert abs(float(log_g_quadrature(alpha, d, a)) - float(ref)) < 1e-10


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_log_r_finite_at_extremes(dtype):
    alpha = np.concatenate([[0.0], np.logspace(-3, 8, 221)])
    a = np.logspace(-6, 0, 121)
    al, aa = (jnp.asarray(v, dtype) for v in np.meshgrid(alpha, a))
    d1, d2 = dtype(D1), dtype(D2)
    curves = jax.jit(lambda al, aa: (log_r_exact(al, d1, d2, aa), log_g(al, d1, aa), log_g(al, d2, aa),
                                     log_r_rough(al, d1, d2, aa)))
    for out in curves(al, aa):
        assert out.dtype == dtype
        assert bool(jnp.all(jnp.isfinite(out)))
    if dtype == jnp.float32:
        r64 = np.asarray(jax.jit(log_r_exact)(np.asarray(al, float), D1, D2, np.asarray(aa, float)))
        r32 = np.asarray(curves(al, aa)[0], float)
        assert np.max(np.abs(r32 - r64) / np.maximum(1.0, np.abs(r64))) < 1e-4


def test_erfcx_workaround_band():
    # jax's erfcx returns 0 near z = 26.6 (float64) and 9.3 (float32); ours must not
    z = np.linspace(0, 60, 60001)
    erfcx = jax.jit(r_curve._erfcx)
    ours = np.asarray(erfcx(jnp.asarray(z)))
    assert np.max(np.abs(ours / scipy.special.erfcx(z) - 1)) < 1e-13
    ours32 = np.asarray(erfcx(jnp.asarray(z, jnp.float32)), float)
    assert np.max(np.abs(ours32 / scipy.special.erfcx(z.astype(np.float32).astype(float)) - 1)) < 2e-6


def test_limits():
    alpha = np.logspace(0, 5, 30)
    # a -> infinity: Eq. 5, log R = -|alpha| (d2 - d1); the approach is O(1/a)
    for a in (1e2, 1e4):
        dev = np.abs(np.asarray(log_r_exact(alpha, D1, D2, a)) + alpha * (D2 - D1))
        assert dev.max() < 2e-3 / a
    # a -> 0: R -> d1 / d2 for all alpha
    dev0 = np.abs(np.asarray(log_r_exact(alpha, D1, D2, 1e-9)) - np.log(D1 / D2))
    assert dev0.max() < 1e-6
    # G is normalised: a -> inf gives exp(-|alpha| d) and even in alpha
    assert np.allclose(log_g(alpha, D1, 1e3), -alpha * D1, atol=1e-5)
    assert np.allclose(log_g(-alpha, D2, 1e-3), log_g(alpha, D2, 1e-3), rtol=0, atol=1e-14)


def test_rough_curve_is_the_large_alpha_asymptote():
    a = 2.2e-3
    alpha_big = 50 * 3 * D2 / a**2
    gap = abs(float(log_r_exact(alpha_big, D1, D2, a) - log_r_rough(alpha_big, D1, D2, a)))
    gap_small = abs(float(log_r_exact(0.1 * 3 * D2 / a**2, D1, D2, a) - log_r_rough(0.1 * 3 * D2 / a**2, D1, D2, a)))
    assert gap < 1e-3 < gap_small


#: log R and the gradients of log R and log G in (alpha, d1, d2, a), compiled once for every point
_LOG_R = jax.jit(lambda p: log_r_exact(p[0], p[1], p[2], p[3]))
_GRAD_R = jax.jit(jax.grad(lambda p: log_r_exact(p[0], p[1], p[2], p[3])))
_GRAD_G = jax.jit(jax.grad(lambda p: log_g(p[0], p[1], p[3])))


@pytest.mark.parametrize(
    "point",
    [(3e3, 1e-3), (200.0, 0.85e-3), (1e4, 2.2e-3), (5e4, 5e-3), (4e5, 2e-5), (2.0e3, 1.2e-3)],
)
def test_gradients_match_finite_differences(point):
    alpha, a = point
    p0 = jnp.array([alpha, D1, D2, a])
    g = np.asarray(_GRAD_R(p0))
    assert np.all(np.isfinite(g))
    for i in range(4):
        h = 1e-6 * float(p0[i])
        fd = (_LOG_R(p0.at[i].add(h)) - _LOG_R(p0.at[i].add(-h))) / (2 * h)
        assert abs(g[i] - float(fd)) <= 1e-6 * max(abs(float(fd)), 1e-3 / float(p0[i]))
    # and of log G itself
    assert bool(jnp.all(jnp.isfinite(_GRAD_G(p0))))


def test_gradients_finite_at_extremes():
    pts = jnp.array([[0.0, 1e-6], [1e8, 1e-6], [1e8, 1.0], [0.0, 1.0], [1e5, 1e-4]])
    g = jax.jit(jax.vmap(jax.grad(lambda p: log_r_exact(p[0], D1, D2, p[1]))))(pts)
    assert bool(jnp.all(jnp.isfinite(g)))


def _hertz_reference(kx, d, a):
    f = lambda x: d / (np.pi * (x * x + d * d)) * np.cos(kx * x) * np.pi * (a * a - x * x) / (2 * a)
    return 2 * quad(f, 0, a, limit=500, epsabs=0, epsrel=1e-13, points=[d])[0]


def test_hertz_line_response_against_scipy_quad():
    for kx in (0.0, 1e3, 1e4):
        for a in (0.3e-3, 1e-3, 3e-3):
            h = float(hertz_line_response(kx, 0.0, D1, a))
            assert abs(h / _hertz_reference(kx, D1, a) - 1) < 1e-10
    # projection with ky != 0 against pi b J1(ky b) / (a ky)
    a, x, ky = 2e-3, 0.5e-3, 7e3
    b = np.sqrt(a * a - x * x)
    ref = np.pi * b * scipy.special.j1(ky * b) / (a * ky)
    assert abs(float(hertz_projection(x, ky, a)) / ref - 1) < 1e-10


def test_hertz_flattens_where_gaussian_keeps_falling():
    a = 2.2e-3
    alpha = np.array([2e3, 2e4])
    lh = np.asarray(log_r_hertz(alpha, D1, D2, a))
    lg = np.asarray(log_r_exact(alpha, D1, D2, a))
    assert np.all(np.isfinite(lh))
    assert lh[1] - lh[0] > lg[1] - lg[0] + 1.0   # Hertz falls far less over the decade


def test_selectivity():
    k = 2 * np.pi / 1.5e-3
    theta = np.deg2rad(np.array([0.0, 10.0, 30.0, 60.0]))
    s = np.asarray(selectivity(theta, k, D1, 3e-3))
    assert s[0] == pytest.approx(1.0)
    assert np.all(np.diff(s) < 0) and s[-1] < 1e-3
    # Gaussian: the ky factor is exp(-a^2 ky^2 / 6), the kx factor G(k cos)
    ref = np.exp(-((3e-3 * k * np.sin(theta)) ** 2) / 6) * np.exp(
        np.asarray(log_g(k * np.cos(theta), D1, 3e-3) - log_g(k, D1, 3e-3)))
    assert np.allclose(s, ref, rtol=1e-12)
    sh = np.asarray(selectivity(theta, k, D1, 3e-3, window="hertz"))
    assert sh[0] == pytest.approx(1.0) and sh[1] < 0.8
    with pytest.raises(ValueError, match="unknown window"):
        line_response(1.0, 0.0, D1, 1e-3, window="square")
