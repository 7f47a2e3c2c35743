"""The Hertz window's line response (``model.hertz``): accuracy against the quadrature reference,
tangents against finite differences, limits, float32. About 9 s on a 2-core CPU with the table cached (the first
run builds it: +3-5 s). Every evaluation goes through jitted functions of one node shape (4
channels x 24 nodes) so that compilation stays short."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tactile_jax.model import hertz
from tactile_jax.model.window import hertz_line_response

D1, D2 = 0.265e-3, 0.925e-3          # sensor depths, m
KBAND = np.log(1e4) / (D2 - D1)       # band edge: exp(-ks (d2 - d1)) = 1e-4, rad/m


def reference_with_amplitude(ks, kp, delta, eps=1e-4):
    """Reference Hn and its local amplitude sqrt(Hn^2 + |grad_kappa Hn|^2) (dimensionless inputs):
    for an edge oscillation A cos(kappa + phi) the amplitude is A."""
    ref = hertz.hertz_reference(ks, kp, delta)
    gs = (hertz.hertz_reference(ks + eps, kp, delta) - hertz.hertz_reference(ks - eps, kp, delta)) / (2 * eps)
    gp = (hertz.hertz_reference(ks, kp + eps, delta) - hertz.hertz_reference(ks, kp - eps, delta)) / (2 * eps)
    return ref, np.sqrt(ref ** 2 + gs ** 2 + gp ** 2)


DEPTHS = np.asarray([D1, D2])
CH_DEPTH = np.asarray([D1, D2, D1, D2])[:, None]      # depth of each channel (x1, x2, y1, y2)
SHAPE = (4, 24)


@pytest.fixture(scope="module")
def fns():
    table = hertz.hertz_table()

    def everything(ks, kp, dep, a, tks, tkp, tdep, ta, coef):
        """Hn, (log_env, mant) and the tangent of Hn along (tks, tkp, tdep, ta)."""
        tab = table._replace(coef=coef)
        hn, dhn = jax.jvp(lambda *x: hertz.hertz_hn(*x, tab), (ks, kp, dep, a), (tks, tkp, tdep, ta))
        le, mant = hertz.hertz_factors(ks, kp, dep, a, tab)
        return hn, le, mant, dhn

    # the coefficients are an argument, as in the package's programs: as a constant they would be
    # folded into the executable, which then compiles and caches slower
    every = jax.jit(everything)
    cut = jax.jit(lambda ks, kp, dep, a, coef: hertz.hertz_hn(ks, kp, dep, a, table._replace(coef=coef),
                                                              far_field=False))
    return (lambda *x: every(*x, table.coef)), (lambda *x: cut(*x, table.coef)), table


def _call(f, ks, kp, dep, a, t=None):
    dt = ks.dtype
    z = [np.zeros(SHAPE, dt), np.zeros(SHAPE, dt), np.zeros(2, dt), np.asarray(0.0, dt)]
    if t is not None:
        z[t[0]] = t[1]
    return f(ks, kp, np.asarray(dep, dt), np.asarray(a, dt), *z)


def _nodes(rng, kmax, lo=0.0):
    """Random kappa in [lo, kmax] (|kappa| = radius), as (4, 24) arrays of kappa_s, kappa_p."""
    kap = rng.uniform(lo, kmax, SHAPE)
    ph = rng.uniform(0, np.pi / 2, SHAPE)
    return kap * np.cos(ph), kap * np.sin(ph)


def test_reference_matches_package():
    """The numpy reference reproduces ``window.hertz_line_response`` (normalised by pi a / 2)."""
    rng = np.random.default_rng(0)
    a = 2e-3
    ks, kp = rng.uniform(0, 4e4, 8), rng.uniform(0, 1.2e4, 8)
    for d in (D1, D2):
        pkg = np.asarray(hertz_line_response(ks, kp, d, a, n=32, panels=48, n_y=96)) / (np.pi * a / 2)
        ref = hertz.hertz_reference(ks * a, kp * a, d / a)
        np.testing.assert_allclose(pkg, ref, rtol=0, atol=1e-13)


def test_ratio_in_band(fns):
    """Band of the fit (sensor depths, a in 0.3-10 mm, exp(-ks (d2 - d1)) >= 1e-4, |kp a| <= 130):
    the ratio Hn(d2)/Hn(d1) to 1.5e-3 wherever neither Hn is within 0.1 of its local amplitude of 0
    (i.e. within 0.1/a rad/m of a zero crossing); each Hn to 3e-4 of its local amplitude (the cubic
    table; the line integrals' quadrature is good to 1e-3)."""
    f = fns[0]
    rng = np.random.default_rng(11)
    worst_ratio, worst_amp = 0.0, 0.0
    for a in np.exp(rng.uniform(np.log(0.3e-3), np.log(10e-3), 3)):
        ks = rng.uniform(0, KBAND, (1, 24)).repeat(4, 0)
        kp = rng.uniform(0, 130.0 / a, (1, 24)).repeat(4, 0)
        hn = np.asarray(_call(f, ks, kp, DEPTHS, a)[0])      # all four channels at the same (ks, kp)
        refs = [reference_with_amplitude(ks[0] * a, kp[0] * a, d / a) for d in (D1, D2)]
        for c in range(4):
            ref, amp = refs[c % 2]
            worst_amp = max(worst_amp, np.max(np.abs(hn[c] - ref) / amp))
        ok = (np.abs(refs[0][0]) > 0.1 * refs[0][1]) & (np.abs(refs[1][0]) > 0.1 * refs[1][1])
        ratio = hn[1] / hn[0] / (refs[1][0] / refs[0][0])
        worst_ratio = max(worst_ratio, np.max(np.abs(ratio[ok] - 1)))
    assert worst_ratio < 1.5e-3 and worst_amp < 3e-4, (worst_ratio, worst_amp)


def test_far_field(fns):
    """Beyond the table (kappa > 160): the leading large-kappa form, a few % of the local amplitude."""
    f = fns[0]
    rng = np.random.default_rng(5)
    for a in (8e-3, 30e-3):
        ksk, kpk = _nodes(rng, 900.0, 170.0)
        hn = np.asarray(_call(f, ksk / a, kpk / a, DEPTHS, a)[0])
        for c in (0, 1):
            ref, amp = reference_with_amplitude(ksk[c], kpk[c], DEPTHS[c] / a)
            assert np.max(np.abs(hn[c] - ref) / amp) < 5e-2


@pytest.mark.parametrize("a0", [0.6e-3, 3e-3, 9e-3])
def test_jvp_matches_finite_differences(fns, a0):
    """jax.jvp against central differences in ks, kp, the depths and a (a = 9 mm: far field on)."""
    f = fns[0]
    rng = np.random.default_rng(int(a0 * 1e6))
    ks = rng.uniform(-2.2e4, 2.2e4, SHAPE)
    kp = rng.uniform(-2.2e4, 2.2e4, SHAPE)
    args = [ks, kp, DEPTHS, np.asarray(a0)]
    for i, (scale, eps) in enumerate(((1.0, 1e-3), (1.0, 1e-3), (1e-4, 1e-4), (a0, 1e-7))):
        t = np.ones_like(args[i]) * scale
        jv = np.asarray(_call(f, *args, t=(i, t))[3])
        plus, minus = list(args), list(args)
        plus[i], minus[i] = args[i] + eps * t, args[i] - eps * t
        fd = (np.asarray(_call(f, *plus)[0]) - np.asarray(_call(f, *minus)[0])) / (2 * eps)
        err = np.max(np.abs(jv - fd)) / np.max(np.abs(jv))
        assert err < 1e-6, (i, err)


def test_limits(fns):
    f = fns[0]
    # a -> infinity at kp = 0: exp(-|ks| d), up to the O(d / a) of the Poisson kernel's tails
    # beyond the contact (Hn(0, 0) = 1 - 4 d / (pi a) + ...)
    ks = np.tile(np.linspace(-4000.0, 4000.0, 24), (4, 1))
    for a in (1.0, 10.0, 100.0):
        hn = np.asarray(_call(f, ks, np.zeros(SHAPE), DEPTHS, a)[0])
        expect = np.exp(-np.abs(ks) * CH_DEPTH)
        assert np.max(np.abs(hn / expect - 1)) < 1.5 * D2 / a
    # ks = kp = 0: Hn(0, 0, delta) = (1 + delta^2) (2/pi) atan(1/delta) - 2 delta / pi
    for a in (0.3e-3, 2e-3, 20e-3):
        dl = CH_DEPTH[:, 0] / a
        hn = np.asarray(_call(f, np.zeros(SHAPE), np.zeros(SHAPE), DEPTHS, a)[0])[:, 0]
        exact = (1 + dl ** 2) * (2 / np.pi) * np.arctan(1 / dl) - 2 * dl / np.pi
        np.testing.assert_allclose(hn, exact, rtol=1e-7)
    # even in ks and kp, finite on the axes (kp = 0, ks = 0)
    rng = np.random.default_rng(3)
    k1, k2 = rng.uniform(0, 3e4, SHAPE), rng.uniform(0, 3e4, SHAPE)
    k1[:, :5] = 0.0
    k2[:, 5:10] = 0.0
    h = np.asarray(_call(f, k1, k2, DEPTHS, 4e-3)[0])
    assert np.all(np.isfinite(h))
    np.testing.assert_array_equal(h, np.asarray(_call(f, -k1, -k2, DEPTHS, 4e-3)[0]))


@pytest.mark.slow
def test_float32_inputs(fns):
    """float32 in: float32 out, finite (values and tangents, also on the axes and in the far
    field), within 1e-3 of the envelope of the float64 result."""
    f = fns[0]
    rng = np.random.default_rng(4)
    ks = rng.uniform(-6e4, 6e4, SHAPE)
    kp = rng.uniform(-6e4, 6e4, SHAPE)
    ks[:, :3] = 0.0
    kp[:, 3:6] = 0.0
    for a in (0.3e-3, 8e-3):
        out32 = _call(f, ks.astype(np.float32), kp.astype(np.float32), DEPTHS, a, t=(3, np.float32(1e-4)))
        assert all(x.dtype == jnp.float32 and bool(jnp.all(jnp.isfinite(x))) for x in out32)
        hn64, le64 = (np.asarray(x) for x in _call(f, ks, kp, DEPTHS, a)[:2])
        assert np.max(np.abs(np.asarray(out32[0]) - hn64) / np.exp(le64)) < 1e-3


def test_factors_and_cutoff(fns):
    f, cut, table = fns
    rng = np.random.default_rng(6)
    ks = rng.uniform(-5e4, 5e4, SHAPE)
    kp = rng.uniform(-5e4, 5e4, SHAPE)
    a = 6e-3
    hn, le, mant, _ = (np.asarray(x) for x in _call(f, ks, kp, DEPTHS, a))
    np.testing.assert_allclose(mant * np.exp(le), hn, rtol=1e-12, atol=1e-300)
    assert np.max(np.abs(mant)) < 2.0
    # far_field=False: a smooth cut-off to 0 beyond the table (||kappa||_8 > kmax)
    hc = np.asarray(cut(ks, kp, DEPTHS, a))
    m8 = (np.abs(ks * a) ** 8 + np.abs(kp * a) ** 8) ** 0.125
    kmax = table.meta.kmax
    assert np.all(hc[m8 > kmax] == 0.0)
    np.testing.assert_array_equal(hc[m8 < kmax - 12], hn[m8 < kmax - 12])
    assert KBAND * 10e-3 < kmax - 12          # the whole 10 mm band is inside the exact zone


def test_a_vmapped_chunk_runs_the_far_field_only_where_a_record_needs_it(fns):
    """Under vmap the far-field branch runs for the chunk where one record's nodes reach it, and leaves the
    other records' values as they are alone: each record's Hn vmapped equals its Hn on its own."""
    from tactile_jax._numerics import any_in_batch

    rng = np.random.default_rng(11)
    near = _nodes(rng, 20.0, 4.0)                   # kappa well inside the table
    far = _nodes(rng, 900.0, 170.0)                 # beyond it
    a = np.array([1.5e-3, 1.5e-3])
    ks, kp = np.stack([near[0], far[0]]) / a[:, None, None], np.stack([near[1], far[1]]) / a[:, None, None]
    table = fns[2]
    many = jax.jit(jax.vmap(lambda s, p, r, coef: hertz.hertz_hn(s, p, jnp.asarray(DEPTHS), r,
                                                                  table._replace(coef=coef)),
                            in_axes=(0, 0, 0, None)))(ks, kp, a, table.coef)
    for i in range(2):          # alone: the module's program of one record
        alone = _call(fns[0], ks[i], kp[i], DEPTHS, a[i])[0]
        np.testing.assert_allclose(np.asarray(many[i]), np.asarray(alone), rtol=1e-12, atol=1e-14)
    # the predicate: the record's any alone, the chunk's any (unbatched) under vmap
    x = jnp.array([[-1.0, -2.0], [-1.0, 3.0]])
    assert not bool(any_in_batch(x[0] > 0)) and bool(any_in_batch(x[1] > 0))
    branch = jax.vmap(lambda v: jax.lax.cond(any_in_batch(v > 0), lambda: v + 1.0, lambda: v))
    assert "select_n" not in str(jax.make_jaxpr(branch)(x))
    np.testing.assert_array_equal(branch(x), x + 1.0)


def test_all_depths_at_once_and_a_corner_of_the_table(fns):
    """``hertz_hn_depths`` (one gather a node for every depth, values only) gives ``hertz_hn``'s values, far field
    and radii of large delta included, from a float64 table to rounding and from the float32 table (its slices in
    float32) to the table's own precision; a corner of the table (``corner``) gives the same values inside it and
    NaN beyond it, never a value read off its edge."""
    f, _, table = fns
    rng = np.random.default_rng(11)
    both = jax.jit(lambda ks, kp, a, coef: hertz.hertz_hn_depths(ks, kp, jnp.asarray(DEPTHS), a,
                                                                  table._replace(coef=coef)))
    for a, kmax in ((1.0e-3, 60.0), (6e-3, 170.0), (0.15e-3, 30.0)):       # inside, far field, delta above the table
        ks, kp = (x / a for x in _nodes(rng, kmax))
        ks, kp = ks[:2], kp[:2]                 # two positions' groups: (kx, ky) and (ky, kx) in the joint model
        # channels (group 0, depth 0), (0, 1), (1, 0), (1, 1)
        hn = np.asarray(_call(f, ks[[0, 0, 1, 1]], kp[[0, 0, 1, 1]], DEPTHS, a)[0])
        want = np.stack([hn[[0, 2]], hn[[1, 3]]])
        got = np.asarray(both(ks, kp, a, table.coef.astype(jnp.float64)))  # (depth, group, nodes)
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-14 * np.max(np.abs(want)))
        got = np.asarray(both(ks, kp, a, table.coef))
        np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-8 * np.max(np.abs(want)))
    a = 1.0e-3
    ks, kp = (x / a for x in _nodes(rng, 60.0))
    ks, kp = ks[:2], kp[:2]
    whole = np.asarray(both(ks, kp, a, table.coef))
    inside = hertz.corner(table.coef, 61.0)
    assert inside.shape[1] < table.coef.shape[1] / 6
    np.testing.assert_array_equal(np.asarray(both(ks, kp, a, inside)), whole)
    small = np.asarray(both(ks, kp, a, hertz.corner(table.coef, 40.0)))
    beyond = np.maximum(np.abs(ks), np.abs(kp)) * a > 40.0 + table.meta.h + 1e-9
    assert beyond.any() and np.isnan(small[:, beyond]).all()
    np.testing.assert_array_equal(small[:, np.maximum(np.abs(ks), np.abs(kp)) * a <= 40.0],
                                  whole[:, np.maximum(np.abs(ks), np.abs(kp)) * a <= 40.0])
    assert hertz.corner(table.coef, table.meta.kmax) is table.coef
