"""Seeded statistical checks of the emcee posterior on a linear Gaussian toy model, and its files."""

import json

import jax.numpy as jnp
import numpy as np
import pytest

from tactile_jax.corner import corner_plot
from tactile_jax.lsq import least_squares
from tactile_jax.posterior import (load_posterior, make_log_prob, read_attrs, run_emcee, save_posterior,
                                   to_inference_data)
from tactile_jax.problem import FitProblem

SIGMA = 0.3
NAMES = ("m", "c", "q")
FREE = (True, True, False)           # q (a quadratic term) is fixed at Q_FIXED
Q_FIXED = 0.05


def residuals(theta, args):
    """(y - (m x + c + q x^2)) / sigma."""
    x, y = args
    m, c, q = theta
    return (y - (m * x + c + q * x**2)) / SIGMA


def to_physical(theta):
    theta = np.asarray(theta)
    return {"m": theta[..., 0], "c": theta[..., 1], "q": theta[..., 2]}


@pytest.fixture(scope="module")
def problem():
    rng = np.random.default_rng(42)
    x = np.linspace(-1.0, 2.0, 40)
    y = 1.3 * x - 0.4 + Q_FIXED * x**2 + SIGMA * rng.standard_normal(x.size)
    args = (jnp.asarray(x), jnp.asarray(y))
    fit = least_squares(residuals, jnp.array([1.0, 0.0, Q_FIXED]), args, free=FREE)
    assert bool(fit.converged)
    return FitProblem(residuals=residuals, args=args, theta=np.asarray(fit.theta), free=FREE, names=NAMES,
                      lower=np.array([0.0, -5.0, -1.0]), upper=np.array([5.0, 5.0, 1.0]),
                      cov=np.asarray(fit.cov), scale=float(fit.redchi), to_physical=to_physical)


@pytest.fixture(scope="module")
def result(problem):
    return run_emcee(problem, n_walkers=32, n_steps=3000, seed=3)


@pytest.fixture(scope="module")
def short(short_runs):
    """A short chain for what does not need a converged one (files, layouts, plots)."""
    return short_runs[0]


@pytest.fixture(scope="module")
def short_runs(problem):
    return run_emcee(problem, n_steps=100, seed=7), run_emcee(problem, n_steps=100, seed=7)


@pytest.mark.slow
def test_posterior_matches_laplace(problem, result):
    sd_laplace = np.sqrt(np.diag(problem.cov))
    summ = result.summary()
    for i, name in enumerate(("m", "c")):
        s = summ[name]
        assert abs(s["mean"] - problem.theta[i]) < 0.2 * sd_laplace[i], name
        assert s["sd"] == pytest.approx(sd_laplace[i], rel=0.15), name
        assert s["q2.5"] < s["q16"] < s["median"] < s["q84"] < s["q97.5"]


@pytest.mark.slow
def test_diagnostics(result):
    n_draws = 3000 - 3000 // 4
    assert result.theta.shape == (32, n_draws, 2)
    assert result.log_prob.shape == (32, n_draws)
    assert result.samples["m"].shape == (32, n_draws)
    assert result.names == ("m", "c", "q") and result.free_names == ("m", "c")
    assert 0.2 <= result.acceptance_fraction <= 0.8
    assert result.tau.shape == (2,) and np.all(np.isfinite(result.tau))
    assert result.ess == pytest.approx(32 * n_draws / result.tau.max())
    assert result.warnings == ()


def test_fixed_parameter_stays_fixed(short):
    result = short
    assert np.all(result.samples["q"] == Q_FIXED)


def test_short_chain_warns_and_seed_reproduces(short_runs):
    a, b = short_runs
    assert any("50 autocorrelation times" in w for w in a.warnings), a.warnings
    assert np.array_equal(a.theta, b.theta) and np.array_equal(a.log_prob, b.log_prob)
    assert a.n_burn == 25 and a.theta.shape[1] == 75


def test_log_prob_bounds_and_nonfinite(problem):
    log_prob = make_log_prob(problem)
    m, c = problem.theta[:2]
    lp = log_prob(np.array([[m, c], [-0.1, c], [m, 5.5], [0.0, c]]))
    assert lp.dtype == np.float64 and lp.shape == (4,)
    assert np.isfinite(lp[0]) and np.isfinite(lp[3])   # bounds are inclusive
    assert lp[1] == -np.inf and lp[2] == -np.inf
    chi2 = float(np.sum(np.square(residuals(jnp.asarray(problem.theta), problem.args))))
    assert lp[0] == pytest.approx(-0.5 * chi2 / problem.scale)
    x, y = problem.args
    bad = make_log_prob(problem._replace(args=(x, y.at[3].set(jnp.nan))))
    assert bad(np.array([[m, c]]))[0] == -np.inf


@pytest.mark.slow
def test_stretch_widens_one_parameter_and_keeps_the_correlation(problem, result):
    """fit's per-parameter error scales: a stretch of 2 on m doubles its posterior sd, leaves c's and the
    m-c correlation as they were, and its log-prob at fit + 2 delta is the plain one at fit + delta."""
    stretch = np.array([2.0, 1.0, 1.0])
    wide = problem._replace(cov=problem.cov * np.outer(stretch, stretch), stretch=stretch)
    delta = np.array([0.05, -0.02])
    plain_lp, wide_lp = make_log_prob(problem), make_log_prob(wide)
    assert wide_lp(problem.theta[:2] + stretch[:2] * delta) == pytest.approx(plain_lp(problem.theta[:2] + delta))
    post = run_emcee(wide, n_walkers=32, n_steps=3000, seed=3)
    sd = np.sqrt(np.diag(problem.cov))
    m, c = (post.samples[k].ravel() for k in ("m", "c"))
    assert np.std(m) == pytest.approx(2 * sd[0], rel=0.15)
    assert np.std(c) == pytest.approx(sd[1], rel=0.15)
    corr = np.corrcoef(m, c)[0, 1]
    assert corr == pytest.approx(np.corrcoef(result.samples["m"].ravel(), result.samples["c"].ravel())[0, 1],
                                 abs=0.05)
    assert abs(corr) > 0.3                 # the toy's m and c are correlated, so keeping it means something
    with pytest.raises(ValueError, match="stretch"):
        make_log_prob(problem._replace(stretch=np.array([0.0, 1.0, 1.0])))


def test_too_few_walkers(problem):
    with pytest.raises(ValueError, match="n_walkers"):
        run_emcee(problem, n_walkers=3, n_steps=10)


def test_save_load_round_trip(tmp_path, short):
    result = short
    path = save_posterior(tmp_path / "post.nc", result, attrs={"run": "toy", "truth": {"m": 1.3}})
    assert path.exists() and not list(tmp_path.glob("*.tmp"))
    groups = load_posterior(path)
    assert set(groups) == {"posterior", "unconstrained_posterior", "sample_stats"}
    for name in result.names:
        np.testing.assert_array_equal(groups["posterior"][name], result.samples[name])
    np.testing.assert_array_equal(groups["unconstrained_posterior"]["m"], result.theta[..., 0])
    np.testing.assert_array_equal(groups["sample_stats"]["lp"], result.log_prob)
    assert groups["sample_stats"]["acceptance_rate"].shape == (32,)
    attrs = read_attrs(path)
    assert attrs["created_by"] == "tactile_jax" and attrs["run"] == "toy" and attrs["truth"] == {"m": 1.3}
    np.testing.assert_allclose(attrs["tau"], result.tau)
    assert attrs["ess"] == pytest.approx(result.ess) and attrs["warnings"] == list(result.warnings)

    import h5py
    with h5py.File(path, "r") as h5:
        ds = h5["posterior/m"]
        assert [ds.dims[i][0].name for i in range(2)] == ["/posterior/chain", "/posterior/draw"]
        assert json.loads(h5.attrs["warnings"]) == list(result.warnings)

    az = pytest.importorskip("arviz")
    idata = az.from_netcdf(path)
    np.testing.assert_array_equal(np.asarray(idata["posterior"]["m"]), result.samples["m"])
    assert dict(idata["posterior"].sizes) == {"chain": 32, "draw": result.theta.shape[1]}


def test_to_inference_data(short):
    result = short
    az = pytest.importorskip("arviz")
    idata = to_inference_data(result, observed={"y": np.arange(3.0)}, attrs={"run": "toy"})
    np.testing.assert_array_equal(np.asarray(idata["sample_stats"]["lp"]), result.log_prob)
    assert json.loads(idata["posterior"].attrs["tau"]) == pytest.approx(list(result.tau))
    del az


def test_to_inference_data_without_arviz(short, monkeypatch):
    result = short
    import builtins

    real_import = builtins.__import__

    def no_arviz(name, *args, **kwargs):
        if name == "arviz":
            raise ImportError("no arviz")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_arviz)
    with pytest.raises(ImportError, match="pip install arviz"):
        to_inference_data(result)


def test_corner_plot(tmp_path, short):
    result = short
    path = corner_plot(result.samples, tmp_path / "corner.png", names=["m", "c", "q"],
                       truths={"m": 1.3, "c": -0.4}, labels={"m": "m (m/s)"}, title="toy posterior")
    assert path.exists() and path.stat().st_size > 5000


def test_diagnose_messages():
    from tactile_jax.posterior import _diagnose

    lp = np.zeros((8, 50))
    lp[2] = -100.0                                     # a walker stranded far below the others
    acc = np.full(8, 0.05)
    msgs = _diagnose(8, 1000, np.array([5.0, 30.0]), 0.05, acc, lp, 2)
    assert any("50 autocorrelation times (n_steps = 1000, max tau = 30.0)" in m for m in msgs)
    assert any("acceptance fraction 0.05 outside [0.15, 0.8]" in m for m in msgs)
    assert any("1 of 8 walkers stuck" in m for m in msgs)
    assert any("not estimable" in m for m in _diagnose(8, 1000, np.array([np.nan, 1.0]), 0.5, acc, lp * 0, 2))
