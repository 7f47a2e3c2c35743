"""Nested scene models and their selection by BIC (``model_select``), and ``FitOptions.model``."""


import numpy as np
import pytest

from conftest import GAUSS
from tactile_jax.inference import select as ms
from tactile_jax.errors import TactileInputError
from tactile_jax.inference.options import FitOptions
from tactile_jax.inference.result import FitResult
from tactile_jax.inference.fit import fit_recording


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
    res = FitResult(message="")
    res.set("vx", value=0.02, err=0.001)
    res.set("gain_ratio", value=1.0, err=2.0)
    ms.annotate(res)
    assert "gain_ratio is not determined" in res.message and "vx" not in res.message
    res = FitResult(message="vy is consistent with 0 (95 % upper bound 0.06 cm/s)")
    res.set("vy", value=1e-4, err=3e-4)
    ms.annotate(res)
    assert res.message.count("vy") == 1          # already said: not repeated


@pytest.fixture(scope="module")
def small_contact():
    """A 1.5 mm contact at 4.7 cm/s (4 s): the window matters and is measured."""
    from tactile_jax.simulation.scene import Scene, simulate

    return simulate(Scene(velocity=(0.047, 0.0), contact_radius=1.5e-3, duration=4.0, seed=2))


def test_auto_keeps_the_window_of_a_small_contact_and_reports_the_margin(small_contact):
    # velocity known from the arm (paper section 4.3): no speed bounds to profile (keeps it quick)
    res = fit_recording(small_contact, FitOptions(model="auto", velocity=(0.047, 0.0), **GAUSS))
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


@pytest.mark.slow
def test_the_window_that_made_the_data_is_chosen():
    """A Hertz contact and a Gaussian one, slip along x: the default fits the Hertz disk and the Gaussian
    window from it and keeps the one that made the data, by a decisive margin, with a near the truth."""
    from tactile_jax.simulation.scene import Scene, simulate

    for window in ("hertz", "gaussian"):
        rec = simulate(Scene(velocity=(0.03, 0.0), contact_radius=1.8e-3, window=window, duration=8.0, seed=3))
        res = fit_recording(rec, FitOptions(texture="isotropic"))
        assert res.status == "ok" and res.window == window, (window, res.window, res.window_margin, res.message)
        assert res.window_margin > ms.WINDOW_DECISIVE and res.to_record()["window"] == window
        assert res.vx == pytest.approx(0.03, rel=0.03) and res.a == pytest.approx(1.8e-3, rel=0.05)


@pytest.mark.slow
def test_a_hertz_slip_along_x_reads_no_minor_speed():
    """A Hertz contact (a 1.53 mm) slipping along x at 1.97 cm/s, 16 s at 50 dB: the y pair's densities dip
    between bins at the disk spectrum's nulls, so the model must follow them there. Then the fit describes
    the spectra (reduced chi-square near 1) and vy is consistent with its truth 0, not a small number with a
    tight interval that excludes 0: the slip model holds it at 0 and bounds it."""
    from tactile_jax.simulation.scene import Scene, simulate

    rec = simulate(Scene(velocity=(0.01967, 0.0), contact_radius=1.531e-3, window="hertz", snr_db=49.5,
                         duration=16.0, seed=158399401))
    res = fit_recording(rec, FitOptions(window="hertz", texture="isotropic"))
    assert res.status == "ok" and res.redchi < 1.3, (res.status, res.redchi, res.message)
    assert res.problem.precision == "float64"          # float32 does not carry the Hertz disk's conditioned PSDs
    assert res.vx == pytest.approx(0.01967, rel=0.01) and res.a == pytest.approx(1.531e-3, rel=0.02)
    est = res["vy"]
    assert est.lo2 == 0.0 or est.upper is not None or est.value < 2.0 * (est.err or 0.0), (est, res.message)
    # a vy the data do not need is held at 0 by the slip model, with its profile's upper bound
    assert res.direction == "along x" and est.value == 0.0 and 0.0 < est.upper < 0.002, (res.direction, est, res.message)


@pytest.mark.slow
def test_a_large_hertz_disk_at_a_slow_slip_is_found_from_the_hertz_programs_own_starts():
    """A Hertz disk of 2.65 mm slipping along x at 1.16 cm/s, 16 s at 50 dB: the Gaussian curve cannot follow
    the x pair's ratio (its radius runs away), so every start of the Gaussian scouting lies in a wrong basin
    (reduced chi-square 68 from there). The Hertz program's own starts, each pair fitted with the Hertz curve,
    find the slip, and the message says that they did."""
    from tactile_jax.simulation.scene import Scene, simulate

    rec = simulate(Scene(velocity=(0.011616, 0.0), contact_radius=2.6504e-3, window="hertz", snr_db=49.7,
                         duration=16.0, seed=1020355719))
    for window in ("hertz", None):
        res = fit_recording(rec, FitOptions(window=window))
        assert res.status == "ok" and res.window == "hertz" and res.redchi < 1.5, (res.status, res.message)
        assert "own starts found a better fit" in res.message
        assert res.vx == pytest.approx(0.011616, rel=0.02) and res.a == pytest.approx(2.6504e-3, rel=0.02)


def _stages(**ran):
    """``analysis.Stages`` with the named stages run (name -> dict of chi2, redchi, theta, free, status, n_data):
    what the program's choices read."""
    import types

    from tactile_jax.inference import analysis as an
    from tactile_jax.inference.forward import N_PHYS

    k, p = len(an.STAGES), N_PHYS + 12
    st = types.SimpleNamespace(theta=np.zeros((k, p)), free=np.ones((k, p), bool), chi2=np.full(k, np.inf),
                               redchi=np.full(k, np.inf), n_data=np.full(k, 400.0), status=np.full(k, 4),
                               active=np.zeros(k, bool), hertz=np.zeros(k, bool))
    for name, fields in ran.items():
        i = an.STAGES.index(name)
        st.active[i], st.status[i] = True, 0
        for key, value in fields.items():
            getattr(st, key)[i] = value
    return st


@pytest.mark.parametrize("chi_h, red_h, chi_g, red_g, bin_factor, window, decisive", [
    (400.0, 1.0, 500.0, 1.25, 1.0, "hertz", True),          # Hertz fits better by 100 (scale 1)
    (500.0, 1.25, 400.0, 1.0, 1.94, "gaussian", True),      # Gaussian by 100 / 1.94
    (400.0, 1.0, 405.0, 1.01, 1.94, "hertz", False),        # 2.6 < 6: undecided, the Hertz fit kept
    (1000.0, 2.5, 990.0, 1.8, 1.94, "gaussian", False),     # undecided, only the Gaussian describes the spectra
])
def test_window_choice_by_chi_square_margin(chi_h, red_h, chi_g, red_g, bin_factor, window, decisive):
    """The margin is the chi-square difference over the bin factor times the better fit's reduced
    chi-square (at least 1); below ``WINDOW_DECISIVE`` the other window's fit is averaged in with the kept
    one's Akaike weight."""
    from tactile_jax.inference import analysis as an

    st = _stages(H1=dict(chi2=chi_h, redchi=red_h), GW1=dict(chi2=chi_g, redchi=red_g))
    got = an._compare_windows(st, an.H1, an.GW1, bin_factor)
    kept = an.H1 if window == "hertz" else an.GW1
    assert int(got.kept) == kept
    expected = (chi_g - chi_h) / (max(bin_factor, 1) * max(min(red_h, red_g), 1))
    assert float(got.margin) == pytest.approx(expected)
    assert (abs(float(got.margin)) >= ms.WINDOW_DECISIVE) == decisive
    assert (int(got.other) == -1) == decisive
    w_hertz = 1.0 / (1.0 + np.exp(-0.5 * expected))
    assert float(got.weight) == pytest.approx(1.0 if decisive else (w_hertz if window == "hertz" else 1 - w_hertz))
    no_band = _stages(H1=dict(chi2=1.0, redchi=1.0, status=1), GW1=dict(chi2=1.0, redchi=1.0))
    got = an._compare_windows(no_band, an.H1, an.GW1, 1.0)                  # nothing to compare
    assert int(got.kept) == an.H1 and np.isnan(float(got.margin)) and float(got.weight) == 1.0


def test_the_gaussian_refit_starts_from_the_hertz_radius_of_the_same_second_moment():
    """The window choice's numbers turn into words at the edge (``describe.notes_of``)."""
    import types

    from tactile_jax.inference.describe import notes_of

    a = types.SimpleNamespace(explored=False, window_margin=2.6, window_weight=0.78, window=1,
                              window_other=np.log([0.031, 0.001, 1.5e-3]), texture_note=0, texture_margin=np.nan,
                              direction=0, window_needed=True)
    notes, warnings = notes_of(a)
    assert "cannot tell the contact windows apart (margin +2.6)" in notes[0]
    assert "the Gaussian window alone gives |vx| = 3.1" in notes[0] and not warnings
    a.window_margin, a.window_weight, a.window = -51.0, 1.0, 0
    assert notes_of(a)[0] == ["Gaussian contact window (chi-square margin 51.0 over the Hertz disk)"]


@pytest.mark.parametrize("vy, rise, scale, held", [
    (0.001, 1.5, 1.0, True),         # within 1.4 sigma of 0: a fitted vy would be noise
    (0.001, 5.0, 1.0, False),        # holding it costs 5 > 2: the data need it
    (0.001, 5.0, 3.0, True),         # ... unless its error scale (jackknife) is 3: 5 / 3 < 2
    (0.012, 0.0, 1.0, False),        # 0.4 of the major speed: not tested
])
def test_a_minor_speed_the_data_do_not_need_is_held_at_0(vy, rise, scale, held):
    """Akaike's criterion in units of the minor speed's error scale: held where the refit with it at
    ``AXIS_FLOOR`` of the major speed raises chi-square by at most 2 of that scale."""
    from tactile_jax.inference import analysis as an

    theta = np.r_[np.log([0.03, vy, 2e-3]), np.zeros(20)]
    st = _stages(T2=dict(chi2=400.0, redchi=1.0, theta=theta))
    choices = an.Choices()
    minor, tested = an._minor(st, an.T2, choices)
    assert int(minor) == 1 and bool(tested) == (vy < ms.DIRECTION_TESTED * 0.03)
    if tested:
        st.active[an.DA], st.status[an.DA], st.chi2[an.DA] = True, 0, 400.0 + rise
    kept, margin, forced = an._direction_fit(st, an.T2, choices, np.full(st.theta.shape[1], scale))
    assert (int(kept) == an.DA) == held and not bool(forced)
    if tested:
        assert float(margin) == pytest.approx(abs(2.0 - rise / scale))
    else:
        assert np.isnan(float(margin))


def test_a_given_slip_direction_is_held_whatever_the_data_say():
    """``FitOptions.direction``: "oblique" tests nothing; "along y" holds vx at 0 even as the major speed;
    an unknown direction is a one-line input error."""
    from tactile_jax.errors import TactileInputError
    from tactile_jax.inference import analysis as an
    from tactile_jax.inference.options import FitOptions, choices_of, settings_of

    theta = np.r_[np.log([0.03, 0.001, 2e-3]), np.zeros(20)]
    st = _stages(T2=dict(chi2=400.0, redchi=1.0, theta=theta))
    assert not bool(an._minor(st, an.T2, choices_of(FitOptions(direction="oblique")))[1])
    along_y = choices_of(FitOptions(direction="along y"))
    minor, tested = an._minor(st, an.T2, along_y)
    assert int(minor) == 0 and bool(tested)
    st.active[an.DA], st.status[an.DA], st.chi2[an.DA] = True, 0, 9e9
    kept, margin, forced = an._direction_fit(st, an.T2, along_y, np.ones(st.theta.shape[1]))
    assert int(kept) == an.DA and bool(forced) and np.isnan(float(margin))
    with pytest.raises(TactileInputError, match="direction must be one of oblique, along x, along y"):
        settings_of(FitOptions(direction="sideways"))


def test_windows_the_data_cannot_tell_apart_are_averaged():
    """Model averaging: the mean by the weights, an error holding both fits' errors and their spread, the
    other window's radius scaled to the same second moment, a minor speed's interval widened to hold the
    other window's value."""
    from tactile_jax.inference.core import HERTZ_PER_GAUSS

    res, other = FitResult(), FitResult()
    res.set("vx", value=0.0138, err=0.0004)
    res.set("vy", value=0.0010, err=0.0005, lo=0.0004, hi=0.0015, lo2=0.0001, hi2=0.0020)
    res.set("a", value=1.55e-3, err=0.02e-3)
    res.curvature_radius = 0.03
    other.set("vx", value=0.0155, err=0.00045)
    other.set("vy", value=0.0002, err=0.0005)
    other.set("a", value=1.20e-3, err=0.03e-3)
    ms.average_windows(res, other, 0.3, "hertz")
    assert res.vx == pytest.approx(0.3 * 0.0138 + 0.7 * 0.0155)
    spread = 0.3 * (0.0004 ** 2 + (0.0138 - res.vx) ** 2) + 0.7 * (0.00045 ** 2 + (0.0155 - res.vx) ** 2)
    assert res.vx_err == pytest.approx(np.sqrt(spread))
    assert res.vx_err > 0.0155 - 0.0138 - 0.001              # the windows' difference is in the error
    a_other = 1.20e-3 * HERTZ_PER_GAUSS                     # the Gaussian radius as a Hertz radius
    assert res.a == pytest.approx(0.3 * 1.55e-3 + 0.7 * a_other)
    assert res["contact_depth"].value == pytest.approx(res.a ** 2 / 0.03)
    assert res["vy"].lo == 0.0 and res["vy"].hi == 0.0015      # shifted by -0.0008: lo clipped at 0, hi kept
    held = FitResult()
    held.set("vy", value=0.0, fixed=True, upper=0.001)
    ms.average_windows(held, other, 0.3, "hertz")
    assert held.vy == 0.0 and held["vy"].upper == 0.001            # a speed held at 0 stays held


def test_texture_models_the_data_barely_tell_apart_are_averaged():
    """A directional lobe that AIC does not keep by a margin of TEXTURE_AVERAGED still enters: the isotropic
    fit is kept and the second-harmonic one averaged in with the isotropic Akaike weight; a decisive lobe is
    kept alone and refitted to its fourth harmonic (T4); a lobe that does not describe the spectra is not."""
    from tactile_jax.inference import analysis as an
    from tactile_jax.inference.forward import ANISO, INDEX, N_PHYS

    n = N_PHYS + 12
    iso_free = np.ones(n, bool)
    iso_free[[INDEX[name] for name in ANISO]] = False
    dir_free = iso_free.copy()
    dir_free[[INDEX[name] for name in ANISO[:2]]] = True

    def stages(drop, redchi=None):
        return _stages(GW1=dict(chi2=400.0, redchi=1.0, free=iso_free),
                       T2=dict(chi2=400.0 - drop, redchi=redchi or (400.0 - drop) / 390, free=dir_free))

    close = an._texture_fit(stages(3.0), an.GW1, 1.0)       # AIC: -3 for the lobe against +4 for its 2 harmonics
    margin = 4.0 - 3.0 / max(397.0 / (400.0 - dir_free.sum()), 1.0)
    assert int(close.index) == an.GW1 and int(close.other) == an.T2 and int(close.note) == 4
    assert float(close.margin) == pytest.approx(margin, rel=1e-6)
    assert float(close.weight) == pytest.approx(1.0 / (1.0 + np.exp(-0.5 * margin)))
    decisive = an._texture_fit(stages(60.0), an.GW1, 1.0)
    assert int(decisive.index) == an.T2 and int(decisive.other) == -1 and float(decisive.weight) == 1.0
    assert float(decisive.margin) > ms.TEXTURE_AVERAGED and int(decisive.note) == 3 and bool(decisive.directional)
    st = stages(60.0)
    st.active[an.T4], st.status[an.T4], st.chi2[an.T4], st.free[an.T4] = True, 0, 339.0, True
    assert int(an._texture_fit(st, an.GW1, 1.0).index) == an.T4
    lumpy = _stages(GW1=dict(chi2=2000.0, redchi=5.0, free=iso_free), T2=dict(chi2=1500.0, redchi=3.8, free=dir_free))
    poor = an._texture_fit(lumpy, an.GW1, 1.0)
    assert int(poor.index) == an.GW1 and int(poor.note) == 2 and np.isnan(float(poor.margin))
    res, other = FitResult(), FitResult()
    res.set("vx", value=0.0200, err=0.0002)
    other.set("vx", value=0.0206, err=0.0003)
    ms.average_models(res, other, 0.75)
    assert res.vx == pytest.approx(0.75 * 0.0200 + 0.25 * 0.0206)
    assert res.vx_err == pytest.approx(np.sqrt(0.75 * (0.0002 ** 2 + 0.00015 ** 2) + 0.25 * (0.0003 ** 2 + 0.00045 ** 2)))


def test_window_needed_is_a_likelihood_ratio_test():
    """A loosely measured a is tested against a -> infinity: needed where the rise reaches 2.71 x a's scale."""
    from tactile_jax.inference import analysis as an

    assert bool(an._window_needed(False, np.inf, 100.0, 1.0)[0])             # not tested
    assert bool(an._window_needed(True, 1e9, 100.0, 1.0)[0])
    needed, rise, threshold = an._window_needed(True, 102.0, 100.0, 1.5)
    assert not bool(needed) and float(rise) == 2.0 and float(threshold) == pytest.approx(2.71 * 1.5)
    assert bool(an._window_needed(True, np.nan, 100.0, 1.0)[0])


def test_the_lobe_is_described_by_its_direction_and_contrast():
    along, ratio = ms.lobe_of([0.5 * np.cos(2 * 0.6), 0.5 * np.sin(2 * 0.6), 0.0, 0.0])
    assert along == pytest.approx(np.degrees(0.6), abs=0.25) and ratio == pytest.approx(np.exp(1.0), rel=1e-4)
    # a brushed surface's lobe (aspect 3) to its fourth harmonic, ridges across 150 deg
    rho, t0 = 0.5, np.radians(150.0)
    coef = [3 * rho * np.cos(2 * t0), 3 * rho * np.sin(2 * t0), 1.5 * rho ** 2 * np.cos(4 * t0), 1.5 * rho ** 2 * np.sin(4 * t0)]
    along, ratio = ms.lobe_of(coef)
    assert along == pytest.approx(150.0, abs=0.25) and ratio == pytest.approx(np.exp(3.0), rel=1e-6)    # the 4th harmonic cancels at 0 and 90 deg
    assert ms.lobe_of([0.0] * 4)[1] == 1.0
