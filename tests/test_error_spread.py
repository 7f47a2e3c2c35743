"""The misfit's spread across frequency (``core._spread``): the delete-one-cluster jackknife over adjacent bins."""

import types

import jax
import jax.numpy as jnp
import numpy as np

from tactile_jax.inference import core, residuals
from tactile_jax.inference.data import N_DATA_ROWS
from tactile_jax.inference.residuals import N_LUMP_SERIES, row_bins, row_series

jax.config.update("jax_enable_x64", True)

L = 48
#: the data rows' series and all series (the texture random effects' rows last)
S_DATA = 18
S_ALL = S_DATA + N_LUMP_SERIES


def _data():
    meas = types.SimpleNamespace(beta1=np.zeros((L, 2)), beta2=np.zeros((L, 3)))
    return types.SimpleNamespace(omega=np.zeros(L), meas=meas)


def _sandwich(r, x, cluster):
    """Cluster-robust variances over the Laplace ones, centred scores, C / (C - 1): written out in numpy."""
    bread = np.linalg.inv(x.T @ x)
    ids = np.unique(cluster)
    scores = np.stack([x[cluster == c].T @ r[cluster == c] for c in ids])
    scores -= scores.mean(0)
    meat = len(ids) / (len(ids) - 1) * scores.T @ scores
    return np.diag(bread @ meat @ bread) / np.diag(bread)


def _reference(r, x, cluster):
    """The delete-one-cluster jackknife's variances over the Laplace ones, by refitting the linear model
    without each cluster: written out in numpy."""
    bread = np.linalg.inv(x.T @ x)
    ids = np.unique(cluster)
    fits = np.stack([np.linalg.lstsq(x[cluster != c], r[cluster != c], rcond=None)[0] for c in ids])
    fits -= fits.mean(0)
    return (len(ids) - 1) / len(ids) * np.sum(fits ** 2, 0) / np.diag(bread)


def _design(rng, rows):
    return np.column_stack([np.ones(rows), rng.standard_normal((rows, 4))])


def test_rows_follow_the_blocks_layout():
    bins = row_bins(_data())
    # 3 x 2 L level blocks, 4 L + 6 L chain rows, 2 L residual PSDs, then the random effects' rows
    assert bins.shape == (S_ALL * L,)
    assert np.bincount(bins).tolist() == [S_ALL] * L
    assert residuals.n_data_rows(_data()) == N_DATA_ROWS == S_DATA * L      # the count the program's shapes use


def test_spread_is_the_cluster_jackknife_and_flags_only_shared_misfit():
    rng = np.random.default_rng(5)
    bins = row_bins(_data())
    data_rows = np.arange(bins.size) < S_DATA * L           # the random effects' rows: zero in a smooth model
    x = _design(rng, bins.size) * data_rows[:, None]
    free = np.ones(5, bool)
    cluster = bins // core.SPREAD_BINS
    noise = rng.standard_normal(bins.size) * data_rows
    # a misfit shared by every row of a bin (a lump of the texture spectrum), along the first columns
    lump = (3.0 * rng.standard_normal(L))[bins] * (1.0 + x[:, 1] + x[:, 2])
    spread = jax.jit(lambda r, x, free: core._spread(r, x, free, core._unit_inverse(x, free), _data()))
    for y, flagged in ((noise, False), (noise + lump, True)):
        r = y - x @ np.linalg.lstsq(x, y, rcond=None)[0]          # the residuals at the fit
        ratios, pooled, plain, plain_pooled = spread(jnp.asarray(r), jnp.asarray(x), jnp.asarray(free))
        for got, got_pooled, ref in ((ratios, pooled, _reference(r, x, cluster)),
                                     (plain, plain_pooled, _sandwich(r, x, cluster))):
            np.testing.assert_allclose(np.asarray(got)[:3], ref[:3], rtol=1e-8)
            assert float(got_pooled) == np.asarray(got)[3] == np.asarray(got)[4]
            assert np.isclose(float(got_pooled), ref[:3].mean(), rtol=1e-8)
        assert np.all(np.asarray(ratios)[:3] > np.asarray(plain)[:3])          # the leverage correction widens
        assert bool(np.any(np.asarray(plain)[:3] > core.SPREAD_GATE * np.mean(r ** 2))) is flagged


def test_series_cover_every_row_once_each_along_the_bins():
    data = _data()
    idx = row_series(data)
    assert idx.shape == (S_ALL, L)
    assert np.array_equal(np.sort(idx.ravel()), np.arange(S_ALL * L))
    assert np.all(row_bins(data)[idx] == np.arange(L))


def test_roughness_tells_a_trend_from_scatter():
    """Scatter from bin to bin, however large, leaves the F ratio of a smooth part near 1; a trend across the
    band raises it far above ``core.LUMPY_F``, in the median of the series or, where one block alone has the
    trend, in their largest; rows out of use (zeros) are left out, and series too short for the test too."""
    rng = np.random.default_rng(3)
    data = _data()
    roughness = jax.jit(lambda r: core._roughness(r, data))
    bins = row_bins(data)
    scatter = 4.0 * rng.standard_normal(S_ALL * L)
    median, largest, n = (float(x) for x in roughness(jnp.asarray(scatter)))
    assert 0.5 < median < 1.6 and largest < core.LUMPY_F_MAX and n == S_DATA     # the data's series alone
    trend = scatter + 8.0 * np.sin(2.0 * np.linspace(-1, 1, L)[bins])
    assert float(roughness(jnp.asarray(trend))[0]) > 3 * core.LUMPY_F
    masked = np.where(bins % 3 == 0, 0.0, trend)
    assert float(roughness(jnp.asarray(masked))[0]) > 3 * core.LUMPY_F
    one_block = scatter.copy()
    one_block[L:2 * L] += 8.0 * np.sin(2.0 * np.linspace(-1, 1, L))      # the x pair's ratio alone
    median, largest, _ = (float(x) for x in roughness(jnp.asarray(one_block)))
    assert median < core.LUMPY_F and largest > 3 * core.LUMPY_F_MAX
    few = np.where(bins < core.ROUGHNESS_MIN_ROWS - 1, scatter, 0.0)
    median, largest, n = (float(x) for x in roughness(jnp.asarray(few)))
    assert np.isnan(median) and np.isnan(largest) and n == 0


def test_a_poor_fit_is_lumpy_where_every_series_long_enough_to_test_has_no_trend():
    """A short record's band may leave only ``core.LUMPY_SERIES`` series long enough for the trend test (a 2 s
    window of a slip along an axis): scatter in them reads as lumps, a trend in one of them does not, fewer
    series give no verdict, and a fit that is not poor is never lumpy."""
    rng = np.random.default_rng(4)
    data = _data()
    lumpy = jax.jit(lambda poor, r: core._lumpy(poor, r, data, 1.0)[1])
    idx = row_series(data)
    short = np.zeros(S_ALL * L)
    short[idx[:, :core.ROUGHNESS_MIN_ROWS - 1]] = 1.0                     # every series too short for the test ...
    for n in (core.LUMPY_SERIES, core.LUMPY_SERIES - 1):
        keep = short.copy()
        keep[idx[:n]] = 1.0                                               # ... but the first n
        scatter = 4.0 * rng.standard_normal(S_ALL * L) * keep
        assert bool(lumpy(True, jnp.asarray(scatter))) is (n == core.LUMPY_SERIES)
        assert not bool(lumpy(False, jnp.asarray(scatter)))
    keep = short.copy()
    keep[idx[:core.LUMPY_SERIES]] = 1.0
    y = 4.0 * rng.standard_normal(S_ALL * L)
    y[idx[0]] += 8.0 * np.sin(2.0 * np.linspace(-1, 1, L))
    assert not bool(lumpy(True, jnp.asarray(y * keep)))
    assert core.LUMPY_SERIES <= 3           # what a 2 s window of a slip along an axis may have (benchmarks/track.py)


def _lumpy_data(rng, sd):
    """Data rows whose every bin carries random effects along random directions, the rows' derivatives by them,
    and the data of those shapes (``residuals._profiled``'s inputs)."""
    n_rows = S_DATA * L
    bins = row_bins(_data())[:n_rows]
    jl = rng.standard_normal((n_rows, residuals.N_LUMP)) * rng.uniform(0.5, 3.0, residuals.N_LUMP)
    jl[rng.random(n_rows) < 0.3] = 0.0                                             # rows out of use
    data = types.SimpleNamespace(omega=np.zeros(L), meas=_data().meas, lump_sd=jnp.asarray(sd),
                                 lump_rows=jnp.asarray(jl))
    return data, jl, bins


def test_random_effects_give_the_marginal_quadratic_form_and_their_degrees_of_freedom():
    """Per bin, |r - J delta|^2 + |prior rows|^2 is r^T (I + J C J^T)^-1 r, the marginal likelihood's quadratic form,
    and the degrees of freedom are tr(J (J^T J + C^-1)^-1 J^T); with the sds at 0 the rows are unchanged."""
    rng = np.random.default_rng(11)
    sd = np.array([0.4, 0.3, 0.6])
    data, jl, bins = _lumpy_data(rng, sd)
    r = rng.standard_normal(jl.shape[0]) * 2.0
    r[~jl.any(1)] = 0.0
    rows, extra, edf = jax.jit(lambda r: residuals._profiled(r, data))(jnp.asarray(r))
    c = np.asarray(residuals._prior_factor(jnp.asarray(sd)))
    c = c @ c.T
    assert np.isclose(c[0, 1], sd[0] ** 2) and np.isclose(c[0, 0], sd[0] ** 2 + sd[1] ** 2)
    assert np.allclose(c[2:, 2:], sd[2] ** 2 * np.eye(4))
    q_ref, edf_ref = 0.0, 0.0
    for b in range(L):
        m = bins == b
        j, rb = jl[m], r[m]
        q_ref += rb @ np.linalg.solve(np.eye(m.sum()) + j @ c @ j.T, rb)
        edf_ref += np.trace(j @ np.linalg.solve(j.T @ j + np.linalg.inv(c), j.T))
    np.testing.assert_allclose(float(np.sum(np.asarray(rows) ** 2) + np.sum(np.asarray(extra) ** 2)), q_ref,
                               rtol=1e-9)
    np.testing.assert_allclose(float(edf), edf_ref, rtol=1e-9)
    data.lump_sd = jnp.zeros(3)
    rows0, extra0, edf0 = jax.jit(lambda r: residuals._profiled(r, data))(jnp.asarray(r))
    assert np.array_equal(np.asarray(rows0), r) and not np.asarray(extra0).any() and float(edf0) == 0.0


def test_profiled_least_squares_is_generalised_least_squares():
    """``residuals.profile`` of a linear model's residuals and Jacobian (data rows, the effects' zero rows, priors):
    its least-squares solution is the one of the marginal likelihood, sum over bins of
    r_b^T (I + J_l C J_l^T)^-1 r_b plus the priors; the priors pass unchanged."""
    rng = np.random.default_rng(5)
    sd = np.array([0.5, 0.2, 0.3])
    data, jl, bins = _lumpy_data(rng, sd)
    n, p = jl.shape[0], 4
    used = jl.any(1)
    x = np.where(used[:, None], rng.standard_normal((n, p)), 0.0)
    r0 = np.where(used, rng.standard_normal(n), 0.0)
    prior_x, prior_r = 0.3 * np.eye(p), rng.standard_normal(p)
    full_x = np.concatenate([x, np.zeros((residuals.N_LUMP_SERIES * L, p)), prior_x])
    full_r = np.concatenate([r0, np.zeros(residuals.N_LUMP_SERIES * L), prior_r])
    px, pr = (np.asarray(jax.jit(lambda a: residuals.profile(a, data))(jnp.asarray(a))) for a in (full_x, full_r))
    np.testing.assert_array_equal(pr[-p:], prior_r)
    theta = np.linalg.lstsq(px, -pr, rcond=None)[0]
    c = np.asarray(residuals._prior_factor(jnp.asarray(sd)))
    c = c @ c.T
    normal, rhs = prior_x.T @ prior_x, -prior_x.T @ prior_r
    for b in range(L):
        m = bins == b
        w = np.linalg.inv(np.eye(m.sum()) + jl[m] @ c @ jl[m].T)
        normal += x[m].T @ w @ x[m]
        rhs -= x[m].T @ w @ r0[m]
    np.testing.assert_allclose(theta, np.linalg.solve(normal, rhs), rtol=1e-9, atol=1e-12)


def test_lump_scale_measures_the_pairs_powers_spread():
    """Rows made of each bin's pair powers (common sd 0.5, each pair's own 0.3) plus unit noise: the moments give
    the two sds back."""
    rng = np.random.default_rng(2)
    sd = np.array([0.5, 0.3])
    est = []
    data = _lumpy_data(rng, np.zeros(3))[0]
    scale = jax.jit(lambda r, j: residuals.lump_scale(r, j, data))        # the data's shapes alone enter
    for _ in range(20):
        _, jl, bins = _lumpy_data(rng, np.zeros(3))
        jl[:, :2] *= 4.0
        delta = sd[0] * rng.standard_normal(L)[:, None] + sd[1] * rng.standard_normal((L, 2))
        r = np.sum(jl[:, :2] * delta[bins], 1) + rng.standard_normal(jl.shape[0])
        r[~jl.any(1)] = 0.0
        est.append(np.asarray(scale(jnp.asarray(r), jnp.asarray(jl))))
    est = np.asarray(est)
    np.testing.assert_allclose(np.median(est[:, :2], 0), sd, rtol=0.15)
    np.testing.assert_allclose(est[:, 2], np.hypot(est[:, 0], est[:, 1]))
