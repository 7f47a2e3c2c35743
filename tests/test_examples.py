"""Every example runs, with tiny sizes, and shows what its docstring says."""

import runpy
from pathlib import Path

import numpy as np
import pytest

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def _main(name):
    return runpy.run_path(str(EXAMPLES / name))["main"]


def test_every_example_has_a_test():
    tested = {"simulate_and_measure.py", "fit_spectra_with_errors.py", "rough_vs_exact.py", "posterior_corner.py",
              "batch_folder.py", "track_stream.py"}
    assert {p.name for p in EXAMPLES.glob("*.py")} <= tested


@pytest.mark.slow
def test_simulate_and_measure(tmp_path):
    fit = _main("simulate_and_measure.py")(duration=6.0, out=str(tmp_path / "scene.h5"))
    assert fit.converged and fit.speed == pytest.approx(0.03, rel=0.05)


@pytest.mark.slow
def test_fit_spectra_with_errors(tmp_path):
    joint, pairs, truth = _main("fit_spectra_with_errors.py")(duration=6.0, out=str(tmp_path / "spectra.npz"))
    assert (tmp_path / "spectra.npz").exists()
    assert joint.model != "pair" and pairs.model == "pair"
    assert joint.vx == pytest.approx(abs(truth["vx"]), rel=0.1)
    assert joint.vx_err is not None and 0 < joint.vx_err < 0.1 * joint.vx
    # spectra without their segments: no jackknife, the Laplace errors times the bin correlation
    assert joint.error_method.startswith("laplace x max(redchi, 1)")
    assert joint.a is not None and joint.a == pytest.approx(truth["a"], rel=0.3)
    assert pairs.vx == pytest.approx(abs(truth["vx"]), rel=0.15)


@pytest.mark.slow
def test_rough_vs_exact(tmp_path):
    out = tmp_path / "rough.png"
    r = _main("rough_vs_exact.py")(duration=8.0, radius=2e-3, out=str(out))
    v, a = r["truth"]
    assert out.stat().st_size > 10_000
    assert r["exact"][0] == pytest.approx(v, rel=0.05)
    assert r["exact"][1] == pytest.approx(a, rel=0.3)
    # the straight line of Eq. 6/26 through a bent log ratio: the rough speed is the worse one
    assert abs(r["rough"][0] - v) > abs(r["exact"][0] - v)


@pytest.mark.slow
def test_posterior_corner(tmp_path):
    res, paths = _main("posterior_corner.py")(duration=6.0, steps=30, walkers=8, out_dir=str(tmp_path))
    post = res.posterior.summary()
    assert len(paths) == 1 and paths[0].exists()
    assert res.posterior.samples["vx"].shape[0] >= 2 * sum(res.problem.free)
    vx = abs(res.truth["vx"])
    assert np.isfinite(post["vx"]["sd"]) and post["vx"]["sd"] > 0
    assert abs(post["vx"]["mean"] - vx) < max(5 * post["vx"]["sd"], 0.1 * vx)


@pytest.mark.slow
def test_batch_folder(tmp_path):
    _, rows = _main("batch_folder.py")(files=2, duration=6.0, folder=str(tmp_path / "data"),
                                             out=str(tmp_path / "results.csv"))
    assert len(rows) == 2 + 1 + 1                        # two files, a second record in the last, the broken one
    broken = [r for r in rows if Path(str(r["file"])).name == "broken.npz"]
    assert len(broken) == 1 and broken[0]["status"] not in ("ok", "not_converged", "poor_fit")
    good = [r for r in rows if r not in broken]
    assert all(r["status"] == "ok" for r in good)
    for r in good:
        assert r["vx"] == pytest.approx(0.03 if Path(str(r["file"])).name == "run_00.h5" else 0.045, rel=0.1)


@pytest.mark.slow
def test_track_stream():
    from tactile_jax.simulation.path import truth_at

    rows, truth = _main("track_stream.py")(block=0.07, still=2.5, along_x=3.0, oblique=3.0)
    assert rows[0]["status"] == "no_slip" and rows[0]["vx"] is None
    inside = [(r, truth_at(truth, r["t"] - 1.0, r["t"] + 1.0)) for r in rows]
    ok = [(r, p) for r, p in inside if p is not None and p["moving"] and r["status"] == "ok"]
    assert len(ok) >= 10
    assert np.median([abs(r["vx"] - abs(p["vx"])) / np.hypot(p["vx"], p["vy"]) for r, p in ok]) < 0.05
