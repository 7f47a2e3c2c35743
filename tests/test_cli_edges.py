"""What a new user meets at the command line: help, a fit without --out, honest report statistics,
exit statuses when nothing was fitted, and one-line errors naming the file and the problem."""

import math
import re

import h5py
import pytest
from click.testing import CliRunner

from tactile_jax.cli import main
from tactile_jax.io.files import write_recording
from tactile_jax.simulation.scene import Scene, simulate


@pytest.fixture(scope="module")
def runner():
    return CliRunner()


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("scene") / "scene.h5"
    write_recording(path, simulate(Scene(velocity=(0.03, 0.02), contact_radius=2e-3, duration=8.0, seed=4)))
    return path


def test_help_gives_every_command_a_whole_first_line(runner):
    text = runner.invoke(main, ["--help"]).output
    lines = text[text.index("Commands:"):].splitlines()[1:]
    names = {"batch", "compare-r", "demo", "fit", "simulate", "spectra", "track"}
    found = {line.split()[0]: line.split(None, 1)[1] for line in lines if line.strip()}
    assert set(found) == names
    for name, first in found.items():
        assert first.endswith(".") and not first.endswith("...") and "(Eq." not in first, (name, first)


def test_fit_without_out_prints_the_report_and_writes_nothing(runner, scene_file, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = runner.invoke(main, ["fit", str(scene_file), "--window", "gaussian"])
    assert result.exit_code == 0, result.output
    assert "[[Fit Statistics]]" in result.output and "wrote" not in result.output
    assert list(tmp_path.iterdir()) == []
    # the statistics count residuals, and chi-square / (residuals - variables) is the reduced chi-square
    stat = dict(re.findall(r"^\s{4}(\S[\w -]*?)\s*= (\S+)", result.output, re.M))
    n_res, n_par, dof = int(stat["residuals"]), int(stat["variables"]), int(stat["degrees of freedom"])
    assert dof == n_res - n_par and n_res > int(re.search(r"from (\d+) usable", result.output).group(1))
    assert float(stat["chi-square"]) / dof == pytest.approx(float(stat["reduced chi-square"]), rel=1e-4)


def test_nothing_fitted_exits_2(runner, tmp_path):
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"not hdf5")
    empty = tmp_path / "empty.h5"
    h5py.File(empty, "w").close()
    result = runner.invoke(main, ["fit", str(bad), str(empty), "--quiet"])
    assert result.exit_code == 2
    assert result.output.strip().splitlines()[-1] == "error: none of the 2 records was fitted"
    alone = runner.invoke(main, ["fit", str(empty)])
    assert alone.exit_code == 2
    assert alone.output.strip() == (f"error: {empty}: the file holds neither a recording ('signals') nor spectra "
                                    "('omega', 'psd')")


def test_writing_into_a_missing_folder_names_the_folder(runner, tmp_path):
    target = tmp_path / "nowhere" / "v.h5"
    result = runner.invoke(main, ["simulate", "--out", str(target), "--duration", "1"])
    assert result.exit_code == 2
    assert result.output.strip() == f"error: {target}: cannot write v.h5: the folder {target.parent} does not exist"


def test_truth_is_placed_against_the_bound_not_the_laplace_sigma():
    from tactile_jax.inference.result import FitResult
    from tactile_jax.viz.report import fit_report

    res = FitResult(converged=True, redchi=1.0, chi2=100.0, n_bins=40, n_residuals=120, n_params=12)
    res.set("vx", value=0.03, err=3e-4)
    res.set("vy", value=3.5e-4, err=1e-4, upper=6e-4)
    res.set("a", value=2e-3, err=1e-5)
    line = next(ln for ln in fit_report(res, truth={"vx": 0.03, "vy": 0.0, "a": 2e-3}).splitlines()
                if ln.strip().startswith("vy"))
    assert "sigma" not in line.split("consistent with 0")[1] and "truth 0, inside the bound" in line
    assert not math.isnan(res.vy_upper)


def test_a_held_speed_reads_as_held_with_its_bound():
    from tactile_jax.inference.result import FitResult
    from tactile_jax.viz.report import fit_report

    res = FitResult(converged=True, redchi=1.0, chi2=100.0, n_bins=40, n_residuals=120, n_params=12,
                    direction="along x")
    res.set("vx", value=0.03, err=3e-4)
    res.set("vy", value=0.0, fixed=True, upper=6e-4)
    res.set("a", value=2e-3, err=1e-5)
    text = fit_report(res, truth={"vx": 0.03, "vy": 1e-4, "a": 2e-3})
    line = next(ln for ln in text.splitlines() if ln.strip().startswith("vy"))
    assert "0 (held: slip along x; 95 % upper bound 0.06 cm/s)" in line and "inside the bound" in line, line
    assert "slip along x" in next(ln for ln in text.splitlines() if ln.strip().startswith("model:"))
    assert res.to_record()["direction"] == "along x" and res.to_record()["vy_upper"] == 6e-4
