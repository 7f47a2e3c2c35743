"""Seeded statistical checks of the emcee posterior on a linear Gaussian toy model, its files, its figure,
``fit --mcmc`` as the user meets it, and the optional extras (arviz, matplotlib)."""

import json
import os
import stat
import sys
from types import SimpleNamespace

import jax.numpy as jnp
import numpy as np
import pytest

from tactile_jax._cores import usable_cores
from tactile_jax._optional import MissingExtra
from tactile_jax.uncertainty import posterior
from tactile_jax.inference.lsq import least_squares
from tactile_jax.uncertainty.posterior import (
    load_posterior,
    make_log_prob,
    read_attrs,
    run_emcee,
    save_posterior,
    to_inference_data,
)
from tactile_jax.inference.problem import FitProblem

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
    assert result.names == ("m", "c") and result.free_names == ("m", "c") and set(result.fixed) == {"q"}
    assert 0.2 <= result.acceptance_fraction <= 0.8
    assert result.tau.shape == (2,) and np.all(np.isfinite(result.tau))
    assert result.ess == pytest.approx(32 * n_draws / result.tau.max())
    assert result.warnings == ()


def test_fixed_parameter_is_not_sampled(short):
    assert short.names == ("m", "c") and "q" not in short.samples
    assert short.fixed == {"q": pytest.approx(Q_FIXED)}
    assert set(short.summary()) == {"m", "c"}


def test_summary_carries_emcee_tau_and_ess(short):
    summ = short.summary()
    assert summ["m"]["tau"] == pytest.approx(short.tau[0]) and summ["c"]["tau"] == pytest.approx(short.tau[1])
    n_walkers, n_draws = short.log_prob.shape
    assert summ["m"]["ess"] == pytest.approx(min(n_walkers * 75 / short.tau[0], n_walkers * n_draws))


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


def test_a_float32_run_is_checked_against_float64(problem, short):
    assert short.precision == "float32" and 0.0 <= short.lp_error <= posterior.PRECISION_TOL
    kept = short.theta.reshape(-1, 2)[::50]
    high = make_log_prob(problem)(kept)
    assert np.allclose(short.log_prob.ravel()[::50], high, atol=1e-3)   # the toy's float32 lp: to 1e-3 of float64
    with pytest.raises(ValueError, match="precision"):
        run_emcee(problem, n_steps=10, precision="float16")


def test_a_float32_run_that_strays_is_sampled_again_in_float64(problem, monkeypatch):
    monkeypatch.setattr(posterior, "PRECISION_TOL", -1.0)
    strayed = run_emcee(problem, n_steps=40, seed=5)
    plain = run_emcee(problem, n_steps=40, seed=5, precision="float64")
    assert strayed.precision == "float64" and np.isfinite(strayed.lp_error) and np.isnan(plain.lp_error)
    assert np.array_equal(strayed.theta, plain.theta)


def test_a_problem_float32_does_not_carry_is_sampled_in_float64_at_once(problem, monkeypatch):
    tried = []
    original = posterior._in_precision
    monkeypatch.setattr(posterior, "_in_precision", lambda p, precision: tried.append(precision) or original(p, precision))
    floor = run_emcee(problem._replace(precision="float64"), n_steps=40, seed=5)
    plain = run_emcee(problem, n_steps=40, seed=5, precision="float64")
    assert floor.precision == "float64" and np.isnan(floor.lp_error) and not tried
    assert np.array_equal(floor.theta, plain.theta)
    with pytest.raises(ValueError, match="problem.precision"):
        run_emcee(problem._replace(precision="half"), n_steps=10)


def test_the_log_prob_runs_any_number_of_walkers_through_one_block_shape(problem):
    lp_block, lp_one = make_log_prob(problem, block=4), make_log_prob(problem, block=1)
    walkers = problem.theta[:2] + 0.01 * np.random.default_rng(0).standard_normal((7, 2))
    lp_block(walkers[:4])
    compiled = posterior._log_prob_batch._cache_size()
    for n in (1, 3, 5, 7):
        assert np.allclose(lp_block(walkers[:n]), lp_one(walkers[:n]), rtol=1e-12)
    assert posterior._log_prob_batch._cache_size() == compiled + 1        # block 1's shape, and no other
    with pytest.raises(ValueError, match="block"):
        make_log_prob(problem, block=0)


def test_threads_evaluate_the_blocks_of_a_call_side_by_side(problem):
    walkers = problem.theta[:2] + 0.01 * np.random.default_rng(1).standard_normal((16, 2))
    one, two = make_log_prob(problem, block=4), make_log_prob(problem, block=4, workers=2)
    assert np.array_equal(one(walkers), two(walkers)) and np.array_equal(one(walkers[:3]), two(walkers[:3]))
    with pytest.raises(ValueError, match="workers"):
        make_log_prob(problem, workers=0)
    assert len(usable_cores()) >= 1


def test_too_few_walkers(problem):
    with pytest.raises(ValueError, match="n_walkers"):
        run_emcee(problem, n_walkers=3, n_steps=10)


def test_save_load_round_trip(tmp_path, short):
    result = short
    path = save_posterior(tmp_path / "post.nc", result, attrs={"run": "toy", "truth": {"m": 1.3}, "flag": True})
    assert path.exists() and not list(tmp_path.glob(".*tmp"))
    groups = load_posterior(path)
    assert set(groups) == {"posterior", "unconstrained_posterior", "sample_stats"}
    assert set(groups["posterior"]) == {"m", "c"}                     # q is fixed: an attribute, not draws
    for name in result.names:
        np.testing.assert_array_equal(groups["posterior"][name], result.samples[name])
    np.testing.assert_array_equal(groups["unconstrained_posterior"]["m"], result.theta[..., 0])
    np.testing.assert_array_equal(groups["sample_stats"]["lp"], result.log_prob)
    assert groups["sample_stats"]["acceptance_rate"].shape == (32,)
    attrs = read_attrs(path)
    assert attrs["created_by"] == "tactile_jax" and attrs["run"] == "toy" and attrs["truth"] == {"m": 1.3}
    assert attrs["flag"] is True and attrs["fixed"] == {"q": pytest.approx(Q_FIXED)}
    np.testing.assert_allclose(attrs["tau"], result.tau)
    assert attrs["ess"] == pytest.approx(result.ess) and attrs["warnings"] == list(result.warnings)
    assert attrs["acceptance_fraction"] == pytest.approx(result.acceptance_fraction)
    assert attrs["n_walkers"] == 32 and attrs["n_steps"] == 100 and attrs["n_burn"] == 25
    assert not any(k.startswith("_") for k in attrs)

    az = pytest.importorskip("arviz")
    idata = az.from_netcdf(path)
    np.testing.assert_array_equal(np.asarray(idata["posterior"]["m"]), result.samples["m"])
    assert dict(idata["posterior"].sizes) == {"chain": 32, "draw": result.theta.shape[1]}
    assert idata["posterior"]["m"].attrs["tau"] == pytest.approx(result.summary()["m"]["tau"])
    assert "not independent chains" in idata["posterior"]["chain"].attrs["long_name"]
    summary = az.summary(idata)
    assert list(summary.index) == ["m", "c"] and np.all(np.isfinite(summary["r_hat"]))


def test_posterior_file_has_the_permissions_of_a_plain_file(tmp_path, short):
    old = os.umask(0o027)
    try:
        path = save_posterior(tmp_path / "post.h5", short)
        plain = tmp_path / "plain.txt"
        plain.write_text("x")
    finally:
        os.umask(old)
    assert stat.S_IMODE(path.stat().st_mode) == stat.S_IMODE(plain.stat().st_mode) == 0o640


def test_to_inference_data(short):
    result = short
    pytest.importorskip("arviz")
    idata = to_inference_data(result, observed={"y": np.arange(3.0)}, attrs={"run": "toy"})
    np.testing.assert_array_equal(np.asarray(idata["sample_stats"]["lp"]), result.log_prob)
    assert json.loads(idata["posterior"].attrs["tau"]) == pytest.approx(list(result.tau))
    assert json.loads(idata["posterior"].attrs["fixed"]) == {"q": pytest.approx(Q_FIXED)}


@pytest.fixture
def no_module(monkeypatch):
    """``no_module("arviz")``: importing that module (and its submodules) raises ImportError for this test."""

    def block(name):
        for mod in [m for m in sys.modules if m == name or m.startswith(name + ".")]:
            monkeypatch.delitem(sys.modules, mod)
        monkeypatch.setitem(sys.modules, name, None)

    return block


def test_to_inference_data_and_save_without_arviz(short, no_module, tmp_path):
    no_module("arviz")
    with pytest.raises(MissingExtra, match=r'pip install "tactile_jax\[mcmc\]"'):
        to_inference_data(short)
    with pytest.raises(MissingExtra, match=r"tactile_jax\[mcmc\]"):
        save_posterior(tmp_path / "post.h5", short)
    assert not list(tmp_path.iterdir())


def test_corner_plot_with_arviz(tmp_path, short):
    from tactile_jax.viz.figures import plot_posterior_corner

    post = short._replace(names=("vx", "a"), samples={"vx": short.samples["m"] / 100, "a": short.samples["c"] / 1e3})
    fit = SimpleNamespace(posterior=post, file="toy.h5", index=0)
    paths = plot_posterior_corner(fit, tmp_path, truth={"vx": 0.013, "a": -0.0004})
    assert paths == [tmp_path / "corner_toy_0.png"] and paths[0].stat().st_size > 10_000
    one = post._replace(names=("vx",), samples={"vx": post.samples["vx"]})
    assert plot_posterior_corner(SimpleNamespace(posterior=one, file="toy.h5", index=0), tmp_path) == []


def test_figures_without_matplotlib(no_module, monkeypatch, tmp_path):
    """plotting imports without matplotlib; drawing names the plot extra, and so do compare_r's figures."""
    no_module("matplotlib")
    monkeypatch.delitem(sys.modules, "tactile_jax.viz.figures", raising=False)
    import importlib

    plotting = importlib.import_module("tactile_jax.viz.figures")
    with pytest.raises(MissingExtra, match=r'plotting needs matplotlib: pip install "tactile_jax\[plot\]"'):
        plotting.pyplot()
    from tactile_jax.studies.compare_r import write_figures

    with pytest.raises(MissingExtra, match=r"tactile_jax\[plot\]"):
        write_figures(tmp_path)


@pytest.mark.slow
def test_demo_without_matplotlib_writes_a_note(no_module, monkeypatch, tmp_path):
    """The demo without matplotlib: no figure, a note naming the plot extra (spectra compile: seconds)."""
    from tactile_jax.cli import demo

    monkeypatch.setattr(demo, "fit_recording", lambda rec, options: SimpleNamespace(vx=0.023, a=3e-3))
    no_module("matplotlib")
    res = demo.run_demo(tmp_path, duration=2.0)
    assert res.figure is None and not list(tmp_path.iterdir())
    assert res.note == 'figure not written: plotting needs matplotlib: pip install "tactile_jax[plot]"'


# ---------------------------------------------------------------- fit --mcmc as the user meets it

@pytest.mark.parametrize("flag, extra, module", [("--mcmc", "mcmc", "arviz"), ("--plot", "plot", "matplotlib")])
def test_fit_names_a_missing_extra_before_fitting(no_module, tmp_path, flag, extra, module):
    from click.testing import CliRunner

    from tactile_jax.cli import main

    no_module(module)
    args = [flag] if flag == "--mcmc" else [flag, str(tmp_path / "figs")]
    res = CliRunner().invoke(main, ["fit", str(tmp_path / "missing.h5"), "--out", str(tmp_path / "r.json"), *args])
    assert res.exit_code == 2
    assert res.output.strip() == f'error: {flag} needs {module}: pip install "tactile_jax[{extra}]"'
    assert not list(tmp_path.iterdir())                   # no fit ran, no results file


def _fit_of(problem):
    """What ``cli._attach_mcmc`` reads of a ``FitResult``."""
    return SimpleNamespace(problem=problem, status="ok", file="toy.h5", index=0, truth={}, posterior=None,
                           to_record=lambda: {})


@pytest.mark.parametrize("quiet", [False, True])
def test_attach_mcmc_shows_progress_and_the_posterior_file(problem, tmp_path, capsys, quiet):
    from tactile_jax.cli import fit as cli

    fit, row = _fit_of(problem), {}
    cli._POSTERIOR_FILES.clear()
    cli._attach_mcmc(fit, row, tmp_path / "r.json", dict(n_walkers=8, n_steps=40, seed=1, progress=not quiet))
    err = capsys.readouterr().err
    path = tmp_path / "r_toy_0_posterior.h5"
    assert row["posterior_file"] == str(path) and path.exists() and fit.posterior is not None
    if quiet:
        assert err == ""
    else:
        assert "40/40" in err                             # emcee's tqdm bar, on a stderr that is no TTY
        post = fit.posterior
        assert post.precision == "float32"
        assert err.splitlines()[-1] == (f"posterior: {path} (ESS {post.ess:.0f}, tau {post.max_tau:.1f} steps; "
                                        f"float32 log-probability, sd {post.lp_error:.3f} from float64)")


def test_diagnose_messages():
    from tactile_jax.uncertainty.posterior import _diagnose

    lp = np.zeros((8, 50))
    lp[2] = -100.0                                     # a walker stranded far below the others
    acc = np.full(8, 0.05)
    msgs = _diagnose(8, 1000, np.array([5.0, 30.0]), 0.05, acc, lp, 2)
    assert any("50 autocorrelation times (n_steps = 1000, max tau = 30.0)" in m for m in msgs)
    assert any("acceptance fraction 0.05 outside [0.15, 0.8]" in m for m in msgs)
    assert any("1 of 8 walkers stuck" in m for m in msgs)
    assert any("not estimable" in m for m in _diagnose(8, 1000, np.array([np.nan, 1.0]), 0.5, acc, lp * 0, 2))


@pytest.mark.slow
def test_a_hertz_fit_is_sampled_on_the_corner_of_the_table_its_walkers_read():
    """The sampler reads the Hertz table's corner its walkers need (``FitProblem.sampling_args``): the same
    log-probabilities as the whole table at draws of the Laplace approximation, and none where a walker's line
    integrals leave the corner (its radius eight times the fit's)."""
    from tactile_jax.inference.fit import fit_recording
    from tactile_jax.inference.options import FitOptions
    from tactile_jax.simulation.scene import Scene, simulate
    from tactile_jax.simulation.texture import RandomTexture

    rec = simulate(Scene(texture=RandomTexture(), fs=1000.0, duration=8.0, snr_db=50.0, seed=3, velocity=(0.02, 0.02),
                         contact_radius=1.0e-3, window="hertz"))
    res = fit_recording(rec, FitOptions())
    pr = res.problem
    assert res.window == "hertz" and res.status == "ok" and pr.precision == "float64"
    assert pr.sampling_args()[1].shape[1] < pr.args[1].shape[1] / 4
    idx = np.flatnonzero(pr.free)
    draws = posterior._laplace_draws(pr, idx, 16, 0)
    whole, corner = make_log_prob(pr._replace(sampling_args=None)), make_log_prob(pr, workers=2)
    np.testing.assert_allclose(corner(draws), whole(draws), rtol=1e-12)
    far = np.asarray(pr.theta, float)[idx][None].copy()
    i = list(idx).index(pr.names.index("log_a"))
    far[0, i] += np.log(8.0) * pr.stretch[pr.names.index("log_a")]
    assert np.isfinite(whole(far)[0]) and corner(far)[0] == -np.inf
    post = run_emcee(pr, n_walkers=32, n_steps=20)
    assert post.precision == "float64" and np.all(np.isfinite(post.log_prob))
