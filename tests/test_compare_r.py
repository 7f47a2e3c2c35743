"""Rough (Eq. 26) vs exact (Eq. 23) R curve and Gaussian vs Hertz: maps, tolerance region, fit bias."""

import jax
import numpy as np
import pytest
from click.testing import CliRunner

from tactile_jax.inference import compare_r as cr
from tactile_jax.inference.pair_fit import fit_pair
from tactile_jax.studies import compare_r as study

D1, D2 = 0.265e-3, 0.925e-3
_plane = jax.jit(cr.rough_error_plane)


def test_error_is_a_function_of_the_dimensionless_plane():
    alpha = np.array([300.0, 3e3, 3e4])
    for a in (0.5e-3, 2.2e-3, 8e-3):
        direct = np.asarray(cr.rough_error_sensor(alpha, a, (D1, D2)))
        plane = np.asarray(cr.rough_error_plane(alpha * a, D2 / a))
        np.testing.assert_allclose(direct, plane, rtol=1e-9, atol=1e-12)


def test_rough_curve_limits():
    # far in the asymptotic region the rough curve is the exact one; at low alpha a with a small contact it is not
    assert float(cr.rough_error_plane(1e3, 0.1)) < 1e-3
    assert float(cr.rough_error_plane(0.3, 1.0)) > 0.3
    # a -> infinity (d2 / a -> 0): both tend to exp(-alpha eps) for any alpha, the error as O(d2 / a)
    err = [float(cr.rough_error_plane(0.5, y)) for y in (1e-2, 1e-3, 1e-4)]
    assert err[0] > err[1] > err[2] and err[2] < 1e-4


def test_tolerance_boundary_is_where_the_error_crosses_tol():
    d2a = np.array([0.1, 0.3, 1.0, 2.0])
    tol = 0.05
    x = cr.rough_valid_alpha(d2a, tol)
    assert np.all(np.isfinite(x)) and np.all(np.diff(x) > 0)     # smaller contacts need larger alpha a
    for xi, yi in zip(x, d2a):
        assert float(_plane(xi * 1.01, yi)) <= tol
        assert float(_plane(xi * 0.99, yi)) > tol
        # and it stays within tol beyond the boundary
        assert float(np.max(_plane(xi * np.geomspace(1.01, 100, 50), yi))) <= tol


def test_gaussian_vs_hertz_agree_for_large_contacts_and_differ_for_small():
    assert float(cr.window_error_plane(0.5, 0.01)) < 0.01
    # the disk's edge flattens the Hertz ratio at large alpha a where the Gaussian keeps falling
    assert float(cr.window_error_plane(10.0, 1.0)) > 1.0


@pytest.fixture(scope="module")
def bias_rows():
    return cr.fit_bias([2.2e-3], [0.047], seeds=(0,), curves=("exact", "rough"))


@pytest.mark.slow
def test_fit_bias_exact_is_unbiased_and_rough_is_not(bias_rows):
    exact, rough = bias_rows
    assert (exact.curve, rough.curve) == ("exact", "rough")
    assert exact.n_ok == 1 and abs(exact.a_bias) < 0.02 and abs(exact.speed_bias) < 0.005
    assert abs(exact.a_pull) < 3 and exact.redchi < 2
    # the rough curve misses the bend at low alpha: a biased speed, and a poor fit
    assert rough.speed_bias > 0.05
    assert rough.redchi > 5 * exact.redchi
    assert exact.seconds > 0 and rough.seconds > 0
    text = cr.format_bias_table(bias_rows)
    assert "rough" in text and "2.20" in text and "4.70" in text


def test_synthetic_ratio_band_and_errors():
    d = cr.synthetic_ratio(0.047, 2.2e-3, seed=3)
    assert 10 < d.mask.sum() < d.omega.size
    assert np.all(d.err[d.mask] <= 0.5)
    # the noise has the stated size: normalised residuals about the exact curve have unit spread
    from tactile_jax.model.r_curve import log_r_exact

    z = (d.log_ratio - np.asarray(log_r_exact(d.omega / 0.047, D1, D2, 2.2e-3)))[d.mask] / d.err[d.mask]
    assert 0.6 < np.std(z) < 1.5


def test_fit_bias_data_makers(monkeypatch):
    """The study's "simulator" source reaches ``simulator_ratio`` with the truth as its window; the analysis's
    ``fit_bias`` knows only "synthetic" or a data maker (it imports no simulator)."""
    seen = []

    class Made(Exception):
        pass

    def fake(speed, a, *, window, seed, **kw):
        seen.append((speed, a, window, seed, kw))
        raise Made

    monkeypatch.setattr(study, "simulator_ratio", fake)
    with pytest.raises(Made):
        study.fit_bias([2.2e-3], [0.047], seeds=(5,), source="simulator", truth="hertz", duration=2.0)
    assert seen == [(0.047, 2.2e-3, "hertz", 5, {"duration": 2.0})]
    with pytest.raises(ValueError, match="simulator"):
        cr.fit_bias([2.2e-3], [0.047], source="simulator")


@pytest.mark.slow
def test_hertz_pair_residuals_see_the_hertz_truth():
    """The Hertz curve variant of the pair fit: unit-size residuals at the truth, large ones 10 % off."""
    from tactile_jax.inference.pair_fit import exact_residuals, hertz_residuals

    d = cr.synthetic_ratio(0.047, 2.2e-3, truth="hertz", seed=0)
    args = (d.omega, d.log_ratio, d.err, d.mask, D1, D2, np.zeros(1), np.zeros(1))
    truth = np.log([0.047, 2.2e-3, 1.0])
    off = np.log([0.047, 2.42e-3, 1.0])
    n = d.mask.sum()
    chi2 = lambda fn, th: float(np.sum(np.square(fn(th, args)))) / n
    assert 0.4 < chi2(hertz_residuals, truth) < 2.0
    assert chi2(hertz_residuals, off) > 10 * chi2(hertz_residuals, truth)
    assert chi2(exact_residuals, truth) > 10 * chi2(hertz_residuals, truth)     # the Gaussian curve misfits Hertz data
    with pytest.raises(ValueError, match="unknown R curve"):
        fit_pair(d.omega, d.log_ratio, d.err, d.mask, D1, D2, curve="cubic")


@pytest.mark.slow
def test_compare_r_cli_quick(tmp_path, monkeypatch, bias_rows):
    from tactile_jax.cli import main

    calls = []

    def small(a_values, speeds, **kw):          # the table is tested above: reuse its rows
        calls.append(kw.get("source", "synthetic"))
        return bias_rows

    monkeypatch.setattr(study, "fit_bias", small)
    res = CliRunner().invoke(main, ["compare-r", "--out", str(tmp_path), "--seeds", "1", "--no-simulate",
                                    "--no-hertz"])
    assert res.exit_code == 0, res.output
    assert "alpha >= rad/m" in res.output and "rough" in res.output
    for name in ("rough_vs_exact_plane.png", "rough_vs_exact_sensor.png", "gauss_vs_hertz_plane.png", "fit_bias.csv"):
        assert (tmp_path / name).stat().st_size > 1000 or name.endswith(".csv")
    assert calls == ["synthetic"]
    res = CliRunner().invoke(main, ["compare-r", "--out", str(tmp_path), "--tol", "-1"])
    assert res.exit_code == 2 and "--tol" in res.output
