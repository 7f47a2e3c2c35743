"""The joint model: its texture spectrum between the knots, and the derivatives of its line integrals."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from tactile_jax import joint_model as jm
from tactile_jax.joint_model import log_phi_at
from tactile_jax.texture import RandomTexture


@pytest.mark.parametrize("n, bc", [(12, "not-a-knot"), (3, "natural")])
def test_log_phi_is_scipys_cubic_spline_through_the_knots_and_constant_outside(n, bc):
    x = np.sort(np.random.default_rng(n).uniform(4.0, 11.0, n))
    y = np.sin(x) + 0.1 * x ** 2
    t = np.linspace(3.0, 12.0, 701)
    got = np.asarray(log_phi_at(jnp.asarray(t), jnp.asarray(x), jnp.asarray(y)))
    want = CubicSpline(x, y, bc_type=bc)(np.clip(t, x[0], x[-1]))
    np.testing.assert_allclose(got, want, atol=1e-10)
    grad = jax.grad(lambda v: log_phi_at(jnp.asarray(t), jnp.asarray(x), v).sum())(jnp.asarray(y))
    assert np.all(np.isfinite(np.asarray(grad)))


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_texture_spectrum_at_k_zero_has_a_finite_gradient(dtype):
    """omega = 0 is a grid point, where a node can have kx = ky = 0. The floor under k^2 was 1e-300, which is 0
    in float32: log(0) and a 0/0 gradient made every float32 error bar of the chain fit NaN (session 20)."""
    knots = jnp.linspace(6.0, 10.0, 12, dtype=dtype)
    phi = jnp.linspace(-20.0, -30.0, 12, dtype=dtype)

    def f(kxy, phi):
        return jm._log_phi(kxy[0], kxy[1], knots, phi)

    k0 = jnp.zeros(2, dtype)
    assert np.isfinite(float(f(k0, phi))) and float(f(k0, phi)) == pytest.approx(-20.0)
    for g in jax.grad(f, argnums=(0, 1))(k0, phi):
        assert g.dtype == dtype and np.all(np.isfinite(np.asarray(g))), g


def test_the_spline_follows_the_simulators_texture_spectrum_better_than_straight_lines():
    # the default knot layout spans ~3.4 decades with 12 knots (fit.py); the random texture's
    # spectrum bends over one decade around k = 1 / correlation_length
    knots = np.log(np.geomspace(20.0, 47000.0, 12))
    t = np.log(np.geomspace(100.0, 20000.0, 400))          # where the bands of the coverage scenes lie
    log_phi = lambda lk: np.log(RandomTexture().power_spectrum(np.exp(lk)))
    spline = np.asarray(log_phi_at(jnp.asarray(t), jnp.asarray(knots), jnp.asarray(log_phi(knots))))
    linear = np.interp(t, knots, log_phi(knots))
    err_spline = np.abs(spline - log_phi(t)).max()
    err_linear = np.abs(linear - log_phi(t)).max()
    assert err_spline < 0.3 * err_linear, (err_spline, err_linear)


@pytest.mark.parametrize("nodes", ["_pair_nodes", "_matrix_nodes"])
def test_the_nodes_jvp_along_vx_vy_a_only_is_autodiffs_jvp(nodes):
    # ``_few_inputs_jvp`` pushes 3 tangents through the nodes and maps them onto all parameters: the
    # Jacobian over a 19-vector (3 physical entries, 16 that the nodes do not see) must be forward
    # mode's through the undecorated function, in both parametrisations (|vx| >= |vy| and not)
    f = getattr(jm, nodes)
    omega = jnp.linspace(2.0, 300.0, 9)

    @jax.jit
    def jacobians(theta):
        def through(g):
            def h(th):
                out = g(jnp.exp(th[:3]), omega, 0.265e-3, 0.925e-3)
                return jax.tree.map(lambda o: o * (1.0 + 0.0 * th[3:].sum()), out)
            return jax.jacfwd(h)(theta)
        return through(f), through(f.fun)

    for v in [(0.03, 0.012), (0.004, 0.05), (0.02, 1e-5)]:
        got, want = jacobians(jnp.concatenate([jnp.log(jnp.array([*v, 1.3e-3])), jnp.linspace(-1.0, 1.0, 16)]))
        for g, w in zip(jax.tree.leaves(got), jax.tree.leaves(want)):
            g, w = np.asarray(g), np.asarray(w)
            assert np.all(np.isfinite(g)), v
            np.testing.assert_allclose(g, w, rtol=1e-9, atol=1e-12 * np.abs(w).max(), err_msg=str(v))
            assert not np.any(g[..., 3:]), v
