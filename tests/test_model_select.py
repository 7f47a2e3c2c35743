"""Nested scene models and their selection by BIC (``model_select``), and ``FitOptions.model``."""


import numpy as np
import pytest

from tactile_jax import model_select as ms
from tactile_jax.errors import TactileInputError
from tactile_jax.fit import FitOptions, FitResult, fit_cross_spectra, fit_recording


def test_information_criterion_corrects_for_correlated_bins_and_misfit():
    base = ms.information_criterion(100.0, 3, 64)
    assert base == pytest.approx(100.0 + 3 * np.log(64))
    # correlated bins: chi2 and the number of independent bins both shrink by the bin factor
    assert ms.information_criterion(100.0, 3, 64, bin_factor=2.0) == pytest.approx(50.0 + 3 * np.log(32))
    # a reduced chi-square above 1 (misfit) deflates chi2 differences, never below 1
    assert ms.information_criterion(100.0, 3, 64, scale=4.0) == pytest.approx(25.0 + 3 * np.log(64))
    assert ms.information_criterion(100.0, 3, 64, scale=0.5) == base
    assert ms.information_criterion(100.0, 3, 64, kind="aic") == pytest.approx(106.0)
    # one more parameter must buy more than ln(n / b) of chi2 / b
    assert ms.information_criterion(100.0 - 2 * np.log(32) * 1.01, 4, 64, bin_factor=2.0) < \
        ms.information_criterion(100.0, 3, 64, bin_factor=2.0)


def test_model_names_follow_the_free_mask():
    free = np.ones(19, bool)
    free[[3, 4, 6]] = False
    assert ms.model_name(free, False) == "window"
    free[2] = False
    assert ms.model_name(free, True) == "slip+v_known"
    free[[2, 3, 4, 6]] = True
    assert ms.model_name(free, False) == "window+gain+noise"


def test_forced_models_set_the_flags_and_unknown_ones_are_errors():
    for name in ("window+gain", "window+noise", "window+gain+noise", "slip", "window"):
        o = ms.options_for(FitOptions(model=name, fit_gain=True, noise_floor=True))
        assert (o.fit_gain, o.noise_floor) == ("gain" in name, "noise" in name)
    assert ms.options_for(FitOptions(model="auto", fit_gain=True)).fit_gain
    # the default (None) keeps the flags as given: --fit-gain still works without a model
    assert ms.options_for(FitOptions(fit_gain=True)).fit_gain
    assert ms.options_for(FitOptions(noise_floor=True)).noise_floor
    with pytest.raises(TactileInputError, match="unknown model 'cubic'"):
        ms.check_model("cubic")


def test_annotate_says_when_an_error_bar_exceeds_its_value():
    res = FitResult(vx=0.02, vx_err=0.001, gain_ratio=1.0, gain_ratio_err=2.0, message="")
    ms.annotate(res)
    assert "gain_ratio is not determined" in res.message and "vx" not in res.message
    res = FitResult(vy=1e-4, vy_err=3e-4, message="vy is consistent with 0 (95 % upper bound 0.06 cm/s)")
    ms.annotate(res)
    assert res.message.count("vy") == 1          # already said: not repeated


@pytest.fixture(scope="module")
def small_contact():
    """A 1.5 mm contact at 4.7 cm/s (4 s): the window matters and is measured."""
    from tactile_jax.scene import Scene, simulate

    return simulate(Scene(velocity=(0.047, 0.0), contact_radius=1.5e-3, duration=4.0, seed=2))


def test_auto_keeps_the_window_of_a_small_contact_and_reports_the_margin(small_contact):
    # velocity known from the arm (paper section 4.3): one start, no speed bounds to profile (keeps it quick);
    # without the cross-pair chain, whose model compiles for twice as long (session 15 ran this test with
    # it: the same choice, 78 s against 26 s)
    res = fit_recording(small_contact, FitOptions(model="auto", velocity=(0.047, 0.0), cross_pairs=0))
    assert res.status == "ok", res.message
    assert res.model == "window+v_known"
    assert res.model_margin is not None and res.model_margin > 0.0
    assert res.message.startswith("model window+v_known chosen by BIC")
    assert "slip+v_known +" in res.message               # the dropped-window model was scored, and lost
    slip_gap = float(res.message.split("slip+v_known +")[1].split(")")[0].split(",")[0])
    assert slip_gap > 100.0
    assert res.a == pytest.approx(1.5e-3, rel=0.1)
    row = res.to_record()
    assert row["model"] == "window+v_known" and row["model_margin"] == pytest.approx(res.model_margin)
    assert row["vx"] == 0.047 and row["vx_err"] is None          # fixed: its value, no error


def test_hertz_model_fits_the_slip_axis_pair_only():
    """``model="hertz"`` on a Hertz-window recording: the x pair's Hertz curve; vy is not claimed."""
    from tactile_jax.scene import Scene, simulate
    from tactile_jax.spectra import estimate_spectra

    rec = simulate(Scene(velocity=(0.047, 0.0), contact_radius=2.2e-3, window="hertz", duration=4.0, seed=0))
    spec = estimate_spectra(np.asarray(rec.signals, float), rec.fs, prewhiten=8)
    res = fit_cross_spectra(spec, rec.depths, FitOptions(model="hertz"))
    assert (res.model, res.window, res.status) == ("hertz", "hertz", "ok")
    assert res.vy is None and "vy not determined" in res.message
    assert res.vx == pytest.approx(0.047, rel=0.06) and res.a == pytest.approx(2.2e-3, rel=0.1)


def test_window_needed_is_a_likelihood_ratio_test(small_contact):
    """A loosely measured a is tested against a -> infinity; the slip refit decides, at 2.71 x the scale."""
    from tactile_jax import joint_model as jm
    from tactile_jax.lsq import LsqResult

    res = fit_recording(small_contact, FitOptions(velocity=(0.047, 0.0), cross_pairs=0))   # as the test above
    p = res.problem
    n_prior = jm.n_prior_residuals(len(p.theta))
    cov = np.asarray(p.cov) / p.scale * res.redchi             # back to lsq's scaling (redchi, no bin factor)
    fit = LsqResult(np.asarray(p.theta), cov, res.chi2, res.n_bins, res.n_bins - 1, res.redchi, 0, True, 1.0)
    # a measured to 1-2 %: not tested, no refit
    assert ms.window_needed(fit, p.free, p.args, n_prior=n_prior) == (True, "")
    # the same fit with a said to be loose: the slip refit is far worse (the 1.5 mm window is strong)
    loose = fit._replace(cov=_set(cov, 0.04))
    assert ms.window_needed(loose, p.free, p.args, n_prior=n_prior) == (True, "")
    # and with a chi2 so high that the slip refit is no worse: the window is not needed (the slip
    # refit of this 1.5 mm window ends near chi2 3e9 on the 38 bins the band floor gives it)
    worse = loose._replace(chi2=1e12)
    needed, note = ms.window_needed(worse, p.free, p.args, n_prior=n_prior)
    assert not needed and "do not need the contact window" in note


def _set(cov, value):
    cov = np.array(cov)
    cov[2, 2] = value
    return cov
