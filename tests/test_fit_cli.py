"""``tactile-jax fit``: reports, result files, figures, MCMC and failures as rows.

One short simulated scene (8 s, the paper's Fig. 5 slip along x) is fitted by every
test, so the compiled joint pipeline is built once per process.
"""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from tactile_jax.cli import main
from tactile_jax.inference.result import RESULT_FIELDS
from tactile_jax.io.files import write_recording
from tactile_jax.io.results import read_results, write_results
from tactile_jax.simulation.scene import Scene, simulate

VX = 0.023
NO_CHAIN: list = []


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("scene") / "scene.h5"
    write_recording(path, simulate(Scene(velocity=(VX, 0.0), duration=8.0, seed=0)))
    return path


@pytest.fixture(scope="module")
def mcmc_run(scene_file, tmp_path_factory):
    """One fit with --plot and a short --mcmc chain, shared by the checks below."""
    out_dir = tmp_path_factory.mktemp("fit")
    out = out_dir / "results.json"
    res = CliRunner().invoke(main, ["fit", str(scene_file), "--out", str(out), "--plot", str(out_dir / "figs"),
                                    "--mcmc", "--steps", "60", "--walkers", "36", *NO_CHAIN])
    return res, out, out_dir


def test_results_round_trip_json_and_csv(tmp_path):
    rows = [{**dict.fromkeys(RESULT_FIELDS), "file": "a.h5", "index": 0, "vx": 0.023, "vx_err": 1e-4,
             "converged": True, "status": "ok", "message": "x; y", "extra": 1.5},
            {"file": "b.h5", "index": 1, "vx": float("nan"), "converged": False, "status": "unreadable",
             "message": "b.h5: file not found", "later": "text"}]
    for suffix in (".json", ".csv"):
        path = write_results(tmp_path / f"r{suffix}", rows)
        back = read_results(path)
        assert len(back) == 2
        assert list(back[0])[:len(RESULT_FIELDS)] == list(RESULT_FIELDS)
        assert set(RESULT_FIELDS) <= set(back[1])
        assert back[0]["vx"] == pytest.approx(0.023) and back[0]["converged"] is True
        assert back[1]["vx"] is None and back[1]["a"] is None and back[1]["converged"] is False
        assert back[0]["message"] == "x; y" and back[1]["later"] == "text" and back[0]["later"] is None
        assert back[0]["extra"] == 1.5 and back[0]["index"] == 0
    assert json.loads((tmp_path / "r.json").read_text())[1]["vx"] is None        # NaN -> null
    assert (tmp_path / "r.csv").read_text().splitlines()[0].startswith(",".join(RESULT_FIELDS))
    with pytest.raises(ValueError, match="unsupported results file type"):
        write_results(tmp_path / "r.txt", rows)


@pytest.mark.slow
def test_fit_reports_and_recovers_vx(mcmc_run):
    res, out, _ = mcmc_run
    assert res.exit_code == 0, res.output
    for section in ("[[Fit Statistics]]", "[[Variables]]", "[[Correlations]]", "[[MCMC]]"):
        assert section in res.stdout
    assert "vx (cm/s):" in res.stdout and "truth 2.3" in res.stdout
    (row,) = read_results(out)
    assert set(RESULT_FIELDS) <= set(row)
    assert row["file"].endswith("scene.h5") and row["index"] == 0 and row["status"] == "ok"
    assert row["vx"] == pytest.approx(VX, rel=0.10)
    assert row["vx_err"] > 0 and row["converged"] is True


@pytest.mark.slow
def test_fit_plot_writes_png(mcmc_run):
    _, _, out_dir = mcmc_run
    assert (out_dir / "figs" / "fit_scene_0.png").stat().st_size > 10_000
    assert (out_dir / "figs" / "corner_scene_0.png").stat().st_size > 10_000


@pytest.mark.slow
def test_fit_mcmc_adds_fields_and_posterior_file(mcmc_run):
    from tactile_jax.uncertainty.posterior import load_posterior

    _, out, out_dir = mcmc_run
    (row,) = read_results(out)
    for key in ("mcmc_acceptance", "mcmc_ess", "mcmc_tau_max", "mcmc_warnings", "vx_post_mean", "vx_post_sd",
                "a_post_mean", "posterior_file"):
        assert key in row, key
    assert "autocorrelation times" in row["mcmc_warnings"]                     # 60 steps is a short chain
    assert row["vx_post_mean"] == pytest.approx(VX, rel=0.10)
    post = out_dir / "results_scene_0_posterior.h5"
    assert post.exists() and row["posterior_file"] == str(post)
    assert load_posterior(post)["posterior"]["vx"].shape[0] == 36


def test_missing_file_alone_exits_2_with_a_row(tmp_path):
    out = tmp_path / "r.json"
    res = CliRunner().invoke(main, ["fit", str(tmp_path / "missing.h5"), "--out", str(out)])
    assert res.exit_code == 2
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and "missing.h5: file not found" in lines[0], res.output
    assert "Traceback" not in res.output
    (row,) = read_results(out)
    assert row["status"] == "unreadable" and row["file"].endswith("missing.h5") and "not found" in row["message"]


def test_good_and_garbage_files_go_on(scene_file, tmp_path):
    garbage = tmp_path / "garbage.h5"
    garbage.write_bytes(b"not hdf5 at all")
    out = tmp_path / "r.csv"
    res = CliRunner().invoke(main, ["fit", str(scene_file), str(garbage), "--out", str(out), "--quiet", "--window", "gaussian",
                                    *NO_CHAIN])
    assert res.exit_code == 0, res.output
    assert res.stdout == ""                                                     # --quiet: no reports
    assert "1 fitted, 1 failed" in res.stderr
    rows = read_results(out)
    assert [r["status"] == "ok" for r in rows] == [True, False]
    assert rows[0]["vx"] == pytest.approx(VX, rel=0.10) and rows[0]["converged"] is True
    assert rows[1]["status"] == "unreadable" and rows[1]["file"] == str(garbage) and rows[1]["vx"] is None
    assert all(set(RESULT_FIELDS) <= set(r) for r in rows)


@pytest.mark.slow
def test_spectra_file_fits_like_its_recording(scene_file, tmp_path):
    """The spectra file carries the estimator, the x-y spectra and the segment groups: the recording's fit."""
    spec = tmp_path / "spec.npz"
    runner = CliRunner()
    res = runner.invoke(main, ["spectra", str(scene_file), "--out", str(spec), "--nperseg", "1024"])
    assert res.exit_code == 0, res.output
    out = tmp_path / "r.json"
    res = runner.invoke(main, ["fit", str(spec), "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "[[Variables]]" in res.stdout
    (row,) = read_results(out)
    assert row["file"] == str(spec) and row["index"] == 0 and row["status"] == "ok"
    from tactile_jax.inference.options import FitOptions
    from tactile_jax.inference.fit import fit_recording
    from tactile_jax.io.files import read_recording

    direct = fit_recording(read_recording(scene_file), FitOptions(nperseg=1024))
    assert row["error_method"] == direct.error_method
    for name in ("vx", "vx_err", "a", "a_err"):
        assert row[name] == pytest.approx(getattr(direct, name), rel=1e-9), name
    # --ratio-only: the deep probe's conditioned PSD left out, as FitOptions(conditioned=False)
    res = runner.invoke(main, ["fit", str(spec), "--out", str(out), "--ratio-only", "--quiet"])
    assert res.exit_code == 0, res.output
    (plain,) = read_results(out)
    ratio_only = fit_recording(read_recording(scene_file), FitOptions(nperseg=1024, conditioned=False))
    assert plain["vx"] == pytest.approx(ratio_only.vx, rel=1e-6) and plain["vx"] != pytest.approx(row["vx"], rel=1e-6)


def test_report_says_fixed_and_undetermined():
    from tactile_jax.inference.result import FitResult
    from tactile_jax.viz.report import fit_report

    r = FitResult(file="f.h5", index=3, n_bins=20, redchi=1.1, chi2=20.0, converged=True,
                  message="vy is consistent with 0 (95 % upper bound 0.04 cm/s); the contact window is too weak",
                  correlations=np.array([[1.0, 0.8], [0.8, 1.0]]), names=("log_vy", "log_a"))
    r.set("vx", value=0.02, fixed=True)
    r.set("vy", value=1e-5, err=2e-4, upper=4e-4)
    r.set("a", lower=4.2e-3)
    r.set("gain_ratio", value=1.0, fixed=True)
    text = fit_report(r, truth={"vx": -0.02, "a": 5e-3})
    assert "f.h5  (record 3)" in text
    assert "vx (cm/s):" in text and "2 (fixed)" in text
    assert "a (mm):" in text and "> 4.2 mm (95 % lower bound" in text and "inside the bound" in text
    assert "consistent with 0, 95 % upper bound 0.04 cm/s" in text
    assert "C(log_vy, log_a) = +0.8000" in text
    assert "[[Warnings]]\n    vy is consistent with 0 (95 % upper bound 0.04 cm/s)\n    the contact window" in text
    assert "x-y cross-spectra" not in text
    import dataclasses
    chained = fit_report(dataclasses.replace(r, cross_pairs=2))
    assert "y pair given x (2 blocks, x-y cross-spectra)" in chained.splitlines()[2]
