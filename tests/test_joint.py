"""The joint pipeline's pieces: fixed-shape spectra, the line integrals and their Jacobian, the solver."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tactile_jax.model.cross_pair import _solve_small
from tactile_jax.spectral import band as band_mod
from tactile_jax.model.hertz import hertz_table
from tactile_jax.model import lines
from tactile_jax.inference.forward import _to_half_bins
from tactile_jax.inference.run import resolution_want
from tactile_jax.spectral.segments import KERNEL_OFFSETS, N_BINS, N_GROUPS, segments
from tactile_jax.inference.solve import levenberg_marquardt
from tactile_jax.model.r_curve import log_r_exact
from tactile_jax.simulation.scene import Scene, simulate
from tactile_jax.spectral.estimate import estimate_spectra

D1, D2 = 0.265e-3, 0.925e-3
DEPTHS = jnp.array([D1, D2])
KNOTS = jnp.log(jnp.geomspace(50.0, 25.0 / (2 * D1), 12))
LOG_PHI = -3.0 * jnp.log1p(jnp.exp(KNOTS) * 1e-3)


@pytest.fixture(scope="module")
def recording():
    return simulate(Scene(velocity=(0.016, 0.011), contact_radius=1.5e-3, duration=8.0, seed=3))


@pytest.mark.parametrize("kw", [{}, {"nperseg": 256}, {"method": "multitaper"}])
def test_grouped_segments_sum_to_the_spectra_estimate(recording, kw):
    x = np.asarray(recording.signals, float)
    seg = segments(x, recording.fs, **kw)
    old = estimate_spectra(x, recording.fs, prewhiten=8, **kw)
    n = seg.count.sum()
    assert n == old.n_segments and seg.auto.shape == (N_GROUPS, 4, N_BINS)
    m = min(old.psd.shape[-1], N_BINS)
    for got, want in ((seg.auto.sum(0) / n, old.psd), (seg.csd.sum(0) / n, old.csd), (seg.xy.sum(0) / n, old.xy)):
        want = np.asarray(want)[..., :m]
        assert np.max(np.abs(got[..., :m] - want)) < 1e-9 * np.max(np.abs(want))
    assert float(seg.dof) == pytest.approx(old.dof) and float(seg.bin_factor) == pytest.approx(old.bin_factor)
    assert float(seg.kernel.sum()) == pytest.approx(1.0) and seg.kernel.size == KERNEL_OFFSETS.size
    # more segments than groups: consecutive segments share a group, none is lost
    assert np.all(seg.count[seg.count > 0] >= 1) and seg.count.sum() == old.n_segments


def test_segments_refuse_what_a_record_cannot_meet():
    from tactile_jax.errors import TactileInputError

    with pytest.raises(TactileInputError, match="too short"):
        segments(np.zeros((4, 20)), 1000.0)
    with pytest.raises(TactileInputError, match="nperseg"):
        segments(np.random.default_rng(0).standard_normal((4, 4000)), 1000.0, nperseg=8000)
    with pytest.raises(TactileInputError, match="method"):
        segments(np.zeros((4, 4000)), 1000.0, method="burg")


ISO = jnp.zeros(4)


def _matrix_program(n_nodes, window="gaussian"):
    """log_matrix at ``n_nodes`` per panel under ``window``, compiled once for every (p, omega)."""
    name = "N_NODES" if window == "gaussian" else "N_NODES_HERTZ"
    old = getattr(lines, name)
    setattr(lines, name, n_nodes)
    try:
        if window == "gaussian":
            f = jax.jit(lambda p, omega: lines.log_matrix(p, LOG_PHI, ISO, omega, DEPTHS, KNOTS)[0])
            return f.lower(jnp.ones(3), jnp.ones(62)).compile()      # traced here, at n_nodes
        coef = hertz_table().coef
        f = jax.jit(lambda p, omega, c: lines.log_matrix(p, LOG_PHI, ISO, omega, DEPTHS, KNOTS, 1, c)[0])
        compiled = f.lower(jnp.ones(3), jnp.ones(119), coef).compile()
        return lambda p, omega: compiled(p, omega, coef)
    finally:
        setattr(lines, name, old)


def _quadrature_error(fine, used, p, omega):
    """|used / fine - 1| of each entry relative to its power with a white floor 50 dB below each pair's peak."""
    ref = np.asarray(fine(jnp.array(p), omega))
    got = np.asarray(used(jnp.array(p), omega))
    diag = ref[[0, 2, 3, 5]]
    floor = np.repeat(diag[[0, 2]].max(axis=1, keepdims=True), 2, axis=0) - np.log(1e5)
    total = np.logaddexp(diag, floor)
    scale = np.array([0.5 * (total[i] + total[j]) for i, j in lines.ENTRIES])
    return np.abs(np.exp(got - ref) - 1.0) * np.exp(ref - scale)


def test_slip_along_x_through_a_large_contact_gives_the_exact_r_curve():
    """vy = 0: the x pair's ratio S12 / S11 is the exact R of the mode alpha = omega / vx, the paper's Eq. 23
    (exp(-alpha (d2 - d1)) for a large window); the y pair hears every ky of that mode's line at once, and its
    ratio stays far above the x pair's at high omega."""
    v, a = 0.02, 8e-3
    omega = jnp.linspace(20.0, 400.0, 12)
    m = np.asarray(jax.jit(lambda p: lines.log_matrix(p, LOG_PHI, ISO, omega, DEPTHS, KNOTS)[0])(jnp.array([v, 1e-9, a])))
    ratio_x = m[1] - m[0]
    assert np.allclose(ratio_x, np.asarray(log_r_exact(omega / v, D1, D2, a)), atol=2e-3)
    ratio_y = m[4] - m[3]
    assert np.all(ratio_y < 0) and np.all(ratio_y[-4:] > ratio_x[-4:] + 1.0)


@pytest.mark.slow
def test_the_quadrature_is_converged_where_the_spectra_are_above_the_noise():
    """The fit's 12 nodes per panel against 48, on oblique slips and small and large contacts, relative to
    each entry's power with a white floor 50 dB below each pair's peak (what a fit sees)."""
    fine, used = _matrix_program(48), _matrix_program(lines.N_NODES)
    for p in ([0.016, 0.011, 1.5e-3], [0.03, 0.002, 0.9e-3], [0.02, 0.02, 6e-3]):
        omega = jnp.arange(62) * 0.15 * p[0] / (D2 - D1)
        err = _quadrature_error(fine, used, p, omega)
        assert err.max() < 2e-2 and np.median(err) < 1e-4, p


@pytest.mark.slow
def test_the_hertz_quadrature_is_converged_where_the_spectra_are_above_the_noise():
    """The Hertz window's nodes per panel against 96 on its half-bin grid (oblique, along x, small and large
    contacts), by the Gaussian window's measure; the rule with 12 nodes would not pass."""
    fine, used = _matrix_program(96, "hertz"), _matrix_program(lines.N_NODES_HERTZ, "hertz")
    for p in ([0.016, 0.011, 1.5e-3], [0.03, 0.002, 0.9e-3], [0.02, 0.02, 3e-3], [0.04, 0.0, 2.2e-3]):
        omega = jnp.arange(119) * 0.075 * p[0] / (D2 - D1) + 10.0
        err = _quadrature_error(fine, used, p, omega)
        assert err.max() < 2e-3 and np.median(err) < 2e-5, p


# the Hertz window's program compiles 7 s: the slow tier
@pytest.mark.parametrize("window", ["gaussian", pytest.param("hertz", marks=pytest.mark.slow)])
def test_the_custom_jacobian_matches_finite_differences(window):
    omega = jnp.linspace(5.0, 300.0, 9)
    q = jnp.concatenate([jnp.array([0.016, 0.011, 1.5e-3, 0.4, -0.7, 0.3, -0.2]), LOG_PHI])
    # the Hertz table's coefficients as an argument (folded into the program as a constant, it compiles slower)
    coef = hertz_table().coef if window == "hertz" else None
    win = 1 if window == "hertz" else None

    # one compiled program serves the primal (for the differences) and the custom JVP (the Hertz window's takes
    # every tangent from one table lookup)
    @jax.jit
    def jvp(q, dq, coef):
        return jax.jvp(lambda q: lines.log_matrix(q[:3], q[7:], q[3:7], omega, DEPTHS, KNOTS, win, coef)[0],
                       (q,), (dq,))

    # central differences in log of the physical parameters, the angular factor and the knots
    step = np.concatenate([1e-5 * np.asarray(q[:3]), np.full(4 + 12, 1e-5)])
    for i in (0, 1, 2, 3, 4, 5, 6, 9, 13):
        dq = jnp.zeros_like(q).at[i].set(step[i])
        fd = (np.asarray(jvp(q + dq, dq, coef)[0]) - np.asarray(jvp(q - dq, dq, coef)[0])) / (2 * step[i])
        tangent = np.asarray(jvp(q, dq, coef)[1]) / step[i]
        used = np.abs(fd) > 1e-8
        assert np.allclose(tangent[used], fd[used], rtol=2e-4, atol=1e-6), i


def test_the_angular_factor_is_a_log_fourier_series_with_exact_derivatives():
    theta = jnp.linspace(0.0, np.pi, 13)
    coef = jnp.array([0.7, -0.4, 0.25, 0.1])
    cos2, sin2 = jnp.cos(2 * theta), jnp.sin(2 * theta)
    log_a, d_c, d_s, d_coef = lines.log_angular(cos2, sin2, coef)
    want = (0.7 * np.cos(2 * theta) - 0.4 * np.sin(2 * theta) + 0.25 * np.cos(4 * theta) + 0.1 * np.sin(4 * theta))
    np.testing.assert_allclose(log_a, want, rtol=1e-12, atol=1e-14)
    jac = jax.jacfwd(lambda c, s, k: lines.log_angular(c, s, k)[0], argnums=(0, 1, 2))(cos2, sin2, coef)
    np.testing.assert_allclose(d_c, jnp.diagonal(jac[0]), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(d_s, jnp.diagonal(jac[1]), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(d_coef, jac[2].T, rtol=1e-12, atol=1e-14)
    assert np.all(np.asarray(lines.log_angular(cos2, sin2, jnp.zeros(4))[0]) == 0.0)      # isotropic


def test_half_bins_are_cubic_interpolation():
    x = np.arange(-7.0, 20.0)
    f = 0.3 * x ** 3 - x ** 2 + 2.0
    half = np.asarray(_to_half_bins(jnp.asarray(f)))
    grid = np.arange(-6.0, 18.5, 0.5)
    assert half.shape == grid.shape
    assert np.allclose(half, 0.3 * grid ** 3 - grid ** 2 + 2.0, atol=1e-9)


def test_small_hermitian_solves_match_lapack():
    rng = np.random.default_rng(1)
    for n in (2, 3):
        z = rng.standard_normal((5, n, n)) + 1j * rng.standard_normal((5, n, n))
        a = z @ np.conj(np.swapaxes(z, -1, -2)) + n * np.eye(n)
        b = rng.standard_normal((5, n)) + 1j * rng.standard_normal((5, n))
        assert np.allclose(np.asarray(_solve_small(jnp.asarray(a), jnp.asarray(b))), np.linalg.solve(a, b[..., None])[..., 0])


def _toy(theta, x):
    """A two-basin problem: y = sin(theta0 x) + theta1; the aux output is the model."""
    model = jnp.sin(theta[0] * x) + theta[1]
    return (model - (jnp.sin(3.0 * x) + 0.5)) / 0.01, model


def test_the_solver_keeps_the_best_start_and_holds_the_first_stage_mask():
    x = jnp.linspace(0.0, 3.0, 60)
    starts = jnp.array([[1.0, 0.0], [2.8, 0.0], [5.5, 0.0]])        # only the second is in the right basin
    free = jnp.array([True, True])
    theta, r, jac, model = levenberg_marquardt(_toy, starts, x, free, jnp.array([False, True]), n_start=8, n_first=2,
                                               n_final=10)
    assert np.allclose(np.asarray(theta), [3.0, 0.5], atol=1e-6)
    assert np.asarray(jac).shape == (60, 2) and np.allclose(np.asarray(model), np.sin(3.0 * x) + 0.5, atol=1e-6)
    # from a given start alone: the final iterations only
    theta, *_ = levenberg_marquardt(_toy, jnp.array([[2.9, 0.4]] * 3), x, free, free, n_start=8, n_first=2,
                                    n_final=10, skip_starts=True)
    assert np.allclose(np.asarray(theta), [3.0, 0.5], atol=1e-6)
    # the first stage moves only the ``first`` parameters: with no final iterations theta0 stays at its start
    theta, *_ = levenberg_marquardt(_toy, jnp.array([[3.0, 0.0]]), x, free, jnp.array([False, True]), n_start=4,
                                    n_first=4, n_final=0)
    assert float(theta[0]) == 3.0 and float(theta[1]) == pytest.approx(0.5, abs=1e-6)
    # each start's end (what the Hertz window's exploration picks from): the basins apart, each end a descent
    theta, *_, ends = levenberg_marquardt(_toy, starts, x, free, jnp.array([False, True]), n_start=8, n_first=2,
                                          n_final=0, ends=True)
    ends = np.asarray(ends)
    assert ends.shape == (3, 2) and np.allclose(ends[1], [3.0, 0.5], atol=1e-3)
    assert abs(ends[0, 0] - 3.0) > 0.3 and abs(ends[2, 0] - 3.0) > 0.3
    cost = [float(np.sum(np.square(_toy(jnp.asarray(e), x)[0]))) for e in ends]
    assert np.allclose(np.asarray(theta), ends[int(np.argmin(cost))])
    assert all(c <= float(np.sum(np.square(_toy(s0, x)[0]))) for c, s0 in zip(cost, starts))


def test_a_start_far_behind_an_earlier_one_is_left_early():
    """``scout_give_up``: a start whose cost stands far above the best an earlier start ended at is left where it
    stands; the solve ends at the same optimum in fewer evaluations, and a start never left runs as before."""
    x = jnp.linspace(0.0, 3.0, 60)
    free, first = jnp.array([True, True]), jnp.array([False, True])
    for order in ([1, 0, 2], [0, 1, 2]):        # the right basin's start second, then first
        starts = jnp.array([[2.8, 0.0], [1.0, 0.0], [5.5, 0.0]])[np.array(order)]
        solve = lambda **kw: levenberg_marquardt(_toy, starts, x, free, first, n_start=8, n_first=2,   # noqa: E731
                                                 n_final=10, ends=True, count=True, **kw)
        theta, *_, ends, n = solve()
        theta_s, *_, ends_s, costs_s, n_s = solve(scout_give_up=10.0, scout_after=3, end_costs=True)
        assert np.array_equal(np.asarray(theta), np.asarray(theta_s)) and int(n_s) < int(n)
        right = order.index(0)
        assert np.array_equal(np.asarray(ends[: right + 1]), np.asarray(ends_s[: right + 1]))
        cost = lambda t: float(np.sum(np.square(_toy(t, x)[0])))          # noqa: E731
        assert np.allclose(np.asarray(costs_s), [0.5 * cost(e) for e in ends_s], rtol=1e-12)
        for j in range(right + 1, 3):           # left: behind by the factor where it stood
            assert cost(ends_s[j]) > 10.0 * cost(ends_s[right]) and not np.array_equal(ends[j], ends_s[j])


def test_a_jacobian_no_step_uses_is_not_asked_for():
    """``jac_use`` is told which evaluations' Jacobians no step uses (each start only evaluated, the last of each
    start's exploration): with those Jacobians zeroed the solve is the same, and every other one is asked for."""
    x = jnp.linspace(0.0, 3.0, 60)
    starts = jnp.array([[1.0, 0.0], [2.8, 0.0], [5.5, 0.0]])
    free, first = jnp.array([True, True]), jnp.array([False, True])
    told = []

    def fun(theta, args):
        x, used = args
        jax.debug.callback(lambda u: told.append(bool(u)), used)
        return _toy(jnp.where(used, theta, jax.lax.stop_gradient(theta)), x)

    for n_start, n_final in ((1, 12), (4, 12)):
        plain = levenberg_marquardt(_toy, starts, x, free, first, n_start=n_start, n_first=2, n_final=n_final)
        told.clear()
        cheap = levenberg_marquardt(fun, starts, (x, True), free, first, n_start=n_start, n_first=2, n_final=n_final,
                                    jac_use=lambda args, used: (args[0], used))
        jax.effects_barrier()
        assert np.array_equal(np.asarray(plain[0]), np.asarray(cheap[0]))
        assert np.array_equal(np.asarray(plain[2]), np.asarray(cheap[2]))
        explore = 3 * n_start
        assert told == [(k + 1) % n_start != 0 or k + 1 > explore for k in range(explore + n_final + 1)]


def test_the_hertz_values_alone_are_the_tangents_values():
    """Under the Hertz window alone, in float64, the values are computed from the table's Hn as they are (one
    exponential a node, no envelope): the same as the values beside the tangents (the envelope's form) and as
    with the window traced (both windows' factors, the Hertz ones chosen), to rounding, with the table in float64
    as the analysis program has it; with the table kept in float32 (a sampler's corner), to its precision."""
    omega = jnp.linspace(5.0, 300.0, 9)
    p, coef = jnp.array([0.016, 0.011, 1.5e-3]), hertz_table().coef.astype(jnp.float64)
    dp = jnp.array([1e-3, -2e-3, 1e-6])

    @jax.jit
    def three(p, coef, window):
        value = lines.log_matrix(p, LOG_PHI, ISO, omega, DEPTHS, KNOTS, 1, coef, False)
        beside = jax.jvp(lambda q: lines.log_matrix(q, LOG_PHI, ISO, omega, DEPTHS, KNOTS, 1, coef, True), (p,),
                         (dp,))[0]
        traced = lines.log_matrix(p, LOG_PHI, ISO, omega, DEPTHS, KNOTS, window, coef, False)
        return value, beside, traced

    (value, sign), (beside, sign_b), (traced, sign_t) = three(p, coef, jnp.asarray(1))
    assert np.all(np.asarray(value) > -1e4) and np.array_equal(np.asarray(sign), np.asarray(sign_b))
    np.testing.assert_allclose(np.asarray(value), np.asarray(beside), rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(value), np.asarray(traced), rtol=0, atol=1e-12)
    assert np.array_equal(np.asarray(sign), np.asarray(sign_t))
    (value32, sign32), _, _ = three(p, hertz_table().coef, jnp.asarray(1))
    np.testing.assert_allclose(np.asarray(value32), np.asarray(value), rtol=0, atol=1e-6)
    assert np.array_equal(np.asarray(sign32), np.asarray(sign))


def test_the_hertz_line_integrals_skip_the_tangents_in_p_where_asked():
    omega = jnp.linspace(5.0, 300.0, 9)
    p, coef = jnp.array([0.016, 0.011, 1.5e-3]), hertz_table().coef
    dp, dphi = jnp.array([1e-3, -2e-3, 1e-6]), jnp.linspace(-1.0, 1.0, LOG_PHI.shape[0])

    @jax.jit
    def jvp(dp, dphi, coef, wanted):
        return jax.jvp(lambda p, phi: lines.log_matrix(p, phi, ISO, omega, DEPTHS, KNOTS, 1, coef, wanted)[0],
                       (p, LOG_PHI), (dp, dphi))

    (value, both), (value_no, phi_only) = jvp(dp, dphi, coef, True), jvp(dp, dphi, coef, False)
    assert np.array_equal(np.asarray(value), np.asarray(value_no))
    assert np.allclose(np.asarray(jvp(0 * dp, dphi, coef, True)[1]), np.asarray(phi_only), rtol=1e-12, atol=1e-12)
    assert np.all(np.asarray(jvp(dp, 0 * dphi, coef, False)[1]) == 0.0) and np.any(np.asarray(both) != phi_only)


def _counted_solve(traced: str, **fixed):
    """``solve(start, value)``: the toy's final iterations from ``start`` (30 at most) as one program, with
    ``levenberg_marquardt``'s keyword ``traced`` set to ``value`` and ``fixed`` as given; returns theta and
    how many evaluations of the residuals it took."""
    x = jnp.linspace(0.0, 3.0, 60)
    free = jnp.array([True, True])
    calls = []

    def counted(theta, x):
        jax.debug.callback(lambda: calls.append(1))
        return _toy(theta, x)

    @jax.jit
    def run(start, value):
        return levenberg_marquardt(counted, start[None], x, free, free, n_start=1, n_first=0, n_final=30,
                                   skip_starts=True, **fixed, **{traced: value})[0]

    def solve(start, value):
        calls.clear()
        theta = np.asarray(run(jnp.asarray(start, float), value))
        jax.effects_barrier()
        return theta, len(calls)

    return solve


def test_the_final_iterations_stop_once_the_decrement_is_below_the_tolerance():
    solve = _counted_solve("stop_tol")          # one program: a tolerance of 0 never stops
    full, n_full = solve([2.9, 0.4], 0.0)
    early, n_early = solve([2.9, 0.4], 1e-10)
    assert n_full == 31 and n_early < 15
    assert np.allclose(early, full, atol=1e-5) and np.allclose(full, [3.0, 0.5], atol=1e-6)
    # from the optimum itself: one evaluation, and it stays there
    at, n_at = solve(full, 1e-10)
    assert n_at == 1 and np.array_equal(at, full)


def test_a_solve_gives_up_once_it_cannot_beat_the_bound():
    """``give_up_chi2``: after ``soft_after`` final iterations a solve whose chi-square, less the decrement still
    to go, stays above the bound ends (a wrong basin's local minimum); one that can go below it runs on."""
    solve = _counted_solve("give_up_chi2", stop_tol=0.0, soft_after=3, soft_tol=0.0)
    wrong, n_wrong = solve([1.0, 0.0], 100.0)         # a local minimum of chi2 ~ 1e5
    assert n_wrong == 4 and abs(wrong[0] - 3.0) > 0.5
    right, n_right = solve([2.9, 0.4], 100.0)          # reaches chi2 ~ 0: runs its 30 iterations
    assert n_right == 31 and np.allclose(right, [3.0, 0.5], atol=1e-6)
    _, n_never = solve([1.0, 0.0], np.inf)
    assert n_never == 31


def test_resolution_rules():
    fs, depths, n = 1000.0, np.array([D1, D2]), 16000
    # a slow slip's ratio falls fast per bin: longer segments, capped at 6 half-overlapping ones
    assert resolution_want([0.01, np.nan], [20, 0], fs, depths, n, 1024) == 4096
    assert resolution_want([0.05, 0.01], [40, 10], fs, depths, n, 1024) == 1024
    # a band of 3 bins with no slope is stretched to 8
    assert resolution_want([np.nan, np.nan], [3, 1], fs, depths, n, 1024) == 4096
    assert resolution_want([np.nan, np.nan], [0, 0], fs, depths, n, 1024) == 1024


def test_stray_bins_are_dropped_and_harmonics_kept():
    band = np.zeros((2, 120), bool)
    band[0, 5:12] = True
    band[0, 20:23] = True                # harmonics, within 3x: kept
    band[0, 100] = True                  # a lone coherent bin far above (beyond 3 x 22 + 4): dropped
    out = np.asarray(band_mod._main_band(jnp.asarray(band)))
    assert out[0, 5:12].all() and out[0, 20:23].all() and not out[0, 100]
