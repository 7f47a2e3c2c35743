"""The analysis program (``inference.analysis``): one record's every choice inside one fixed-shape program,
the same whether it runs on one record, on threads over the CPU's cores or vmapped over a chunk."""

import numpy as np
import pytest

from conftest import GAUSS
from tactile_jax.inference import analysis as an
from tactile_jax.inference import run
from tactile_jax.inference.fit import record_of
from tactile_jax.inference.options import FitOptions, analysis_settings, choices_of
from tactile_jax.simulation.scene import Scene, simulate


def _records(options, n=4):
    scenes = [((0.03, 0.012), 1.5e-3), ((0.02, 0.0), 2.0e-3), ((0.012, 0.025), 1.0e-3), ((0.045, 0.004), 1.2e-3)]
    out = []
    for k, (v, a) in enumerate(scenes[:n]):
        rec = simulate(Scene(velocity=v, contact_radius=a, duration=4.0, snr_db=45.0, seed=30 + k))
        out.append(record_of(np.asarray(rec.signals, float), rec.fs, rec.depths, options))
    return out


def _same(a, b):
    """Two analyses of one record agree: values within 1e-6 of their errors, errors to 1e-6, the same choices."""
    sd = np.abs(b.summary.sd).max()
    assert np.allclose(a.summary.theta, b.summary.theta, rtol=0, atol=1e-6 * sd)
    assert np.allclose(a.summary.sd, b.summary.sd, rtol=1e-6, atol=1e-12)
    for field in ("window", "texture", "direction", "window_needed"):
        assert int(getattr(a, field)) == int(getattr(b, field)), field
    assert int(a.summary.status) == int(b.summary.status)


def test_the_stages_report_what_ran():
    """Every stage's outcome is data: which ran, how many iterations each took, its chi-square; a stage off
    costs nothing. The Gaussian window's program has no Hertz stages."""
    options = FitOptions(**GAUSS)
    rec = _records(options, 1)[0]
    a = run.analyse_one(rec, analysis_settings(options), choices_of(options))
    st = a.stages
    ran = {name for name, on in zip(an.STAGES, st.active) if on}
    assert "G0" in ran and not ran & {"H1", "GW1", "HX", "GW2", "GF"}
    assert all(int(n) == 0 for n, on in zip(st.iterations, st.active) if not on)
    assert int(st.iterations[an.G0]) > 3 and np.isfinite(st.chi2[an.G0])
    assert int(a.window) == 0 and np.isnan(float(a.window_margin))
    # the kept fit is one of the stages' ends
    kept = [k for k in range(len(an.STAGES)) if st.active[k] and np.array_equal(st.theta[k], a.summary.theta)]
    assert kept


def test_a_refit_keeps_the_stage_it_ran_under_either_window():
    """A refit (profiles, model selection) runs G0 alone from the given start under the given window: the fit
    kept is G0's under the Gaussian window and under the Hertz disk alike (not the Hertz stage, which is off)."""
    import types

    n = len(an.STAGES)
    active = np.zeros(n, bool)
    active[an.G0] = True
    st = types.SimpleNamespace(chi2=np.where(active, 10.0, np.inf), redchi=np.where(active, 1.0, np.inf),
                               status=np.where(active, 0, 4), active=active, hertz=np.zeros(n, bool))
    for window in (1, 2):
        st.hertz[an.G0] = window == 2
        w = an._window_fit(st, an.Choices(window=window, texture=1, direction=1, test_window=False, refit=True), 2.0)
        assert int(w.index) == an.G0 and bool(w.hertz) == (window == 2)
    # the analysis itself, with the Hertz window given, keeps the Hertz stage
    st.active[an.H1], st.chi2[an.H1], st.status[an.H1], st.hertz[an.H1] = True, 9.0, 0, True
    assert int(an._window_fit(st, an.Choices(window=2), 2.0).index) == an.H1


def test_a_minor_speed_is_held_below_the_rise_the_caller_asks_for():
    """The slip-direction choice is data: holding the minor speed raises chi-square by 2.5 of its error scale,
    which Akaike's 2 calls a fitted speed and a tracker window's 5 tapers (``direction_keep``: F(1, 4) at 95 %,
    7.71) call noise."""
    import types

    from tactile_jax.inference.forward import INDEX
    from tactile_jax.track.tracker import direction_keep

    n, p = len(an.STAGES), len(INDEX)
    theta = np.zeros((n, p))
    theta[:, INDEX["log_vx"]], theta[:, INDEX["log_vy"]] = np.log(0.03), np.log(0.002)
    active = np.zeros(n, bool)
    active[[an.T2, an.DA]] = True
    chi2 = np.full(n, np.inf)
    chi2[an.T2], chi2[an.DA] = 100.0, 105.0
    st = types.SimpleNamespace(theta=theta, free=np.ones((n, p), bool), chi2=chi2, status=np.zeros(n, int),
                               active=active)
    scales = np.full(p, 2.0)
    assert direction_keep(5) == pytest.approx(7.7086, abs=1e-4) and direction_keep(10 ** 4) == pytest.approx(3.84,
                                                                                                             abs=0.01)
    kept, margin, _ = an._direction_fit(st, an.T2, an.Choices(), scales)
    assert int(kept) == an.T2 and float(margin) == pytest.approx(0.5)
    kept, margin, _ = an._direction_fit(st, an.T2, an.Choices(direction_keep=direction_keep(5)), scales)
    assert int(kept) == an.DA and float(margin) == pytest.approx(direction_keep(5) - 2.5)


def test_holding_a_real_minor_speed_gives_up_once_it_cannot_win():
    """A slip at (3, 0.6) cm/s: holding vy at 0 raises chi-square by far more than the direction test allows, so
    DA stops after ``GIVE_UP_AFTER`` final iterations and the slip stays oblique; where the user gives the
    direction, DA runs to its optimum."""
    options = FitOptions(**GAUSS)
    rec = simulate(Scene(velocity=(0.03, 0.006), contact_radius=1.5e-3, duration=16.0, snr_db=47.0, seed=40))
    rec = record_of(np.asarray(rec.signals, float), rec.fs, rec.depths, options)
    chosen = run.analyse_one(rec, analysis_settings(options), choices_of(options))
    given = run.analyse_one(rec, analysis_settings(options), choices_of(options)._replace(direction=2))
    assert int(chosen.direction) == 0 and float(chosen.direction_margin) > 10 * an.DIRECTION_GIVE_UP
    assert int(chosen.stages.iterations[an.DA]) == an.GIVE_UP_AFTER + 1
    assert int(given.direction) == 1 and int(given.stages.iterations[an.DA]) > an.GIVE_UP_AFTER + 1
    # the chosen one stopped short of its optimum (not converged), the given one reached it (a poor fit: vy is real)
    assert int(chosen.stages.status[an.DA]) == 2 and int(given.stages.status[an.DA]) in (0, 3)


@pytest.mark.slow
def test_a_vmapped_chunk_on_the_cpu_equals_the_single_record_program():
    """The batched path (``jax.vmap`` over a chunk of 4 different records) on the CPU gives each record's
    single-record values and errors, with both windows in the program."""
    options = FitOptions()
    recs = _records(options)
    settings, choices = analysis_settings(options), choices_of(options)
    many = run.analyse_many(recs, settings, choices, size=4, vmapped=True)
    for rec, a in zip(recs, many):
        _same(a, run.analyse_one(rec, settings, choices))


def test_a_lumpy_textures_random_effects_are_directions_of_the_jacobian():
    """The texture's random effects at each bin (each pair's log power, the angular factor) are directions in the
    parameters (``forward.lump_basis``): the refit of a lumpy texture takes the rows' derivatives by them from the
    Jacobian where its start ended, and they are the model's own derivatives (``forward.texture_tangents``)."""
    import jax
    import jax.numpy as jnp

    from tactile_jax.inference import forward, residuals
    from tactile_jax.inference.data import N_DATA_ROWS

    options = FitOptions(**GAUSS)
    rec = _records(options, 1)[0]
    a = run.analyse_one(rec, analysis_settings(options), choices_of(options))
    data = jax.tree.map(jnp.asarray, a.summary.data)
    theta = jnp.asarray(a.stages.theta[an.G0])
    from_jac = -a.stages.jac[an.G0][:N_DATA_ROWS] @ forward.lump_basis(theta.shape[0])
    own = jax.jit(lambda t, d: residuals.lump_rows(forward.texture_tangents(t, d), d))(theta, data)
    scale = np.abs(np.asarray(own)).max(0)
    assert np.all(scale > 0)
    np.testing.assert_allclose(from_jac, np.asarray(own), rtol=0, atol=1e-9 * scale.max())
    # a smooth texture's fit has none
    assert not np.asarray(a.lumps).any() and not a.stages.active[an.TL]


def test_the_hertz_table_is_converted_once_not_per_call():
    """Every call's settings hold the Hertz table (52 MB in float32): it is converted to the compute precision once,
    on the device, with the values a host round trip gives."""
    import jax

    s = analysis_settings(FitOptions())
    first, again = run._as_jnp(s).hertz, run._as_jnp(s).hertz
    assert first is again
    want = np.float64 if jax.config.jax_enable_x64 else np.float32
    assert first.dtype == want
    np.testing.assert_array_equal(np.asarray(first), np.asarray(s.hertz).astype(want))
    small = jax.numpy.arange(3.0, dtype=jax.numpy.float32)
    assert run._as_jnp(small).dtype == want
