"""Batch reprocessing: rows for every record, bad input as rows, resume, atomic output, Dask.

One tiny dataset (6 records of 4 x 2048 samples at 1 kHz, one chunk) and one local run are
shared by the module; the compiled programs go to a temporary persistent cache so that the
LocalCluster's spawned workers load them instead of compiling again.
"""

import json
import os
import shutil

import jax
import numpy as np
import pytest
from jax.experimental.compilation_cache import compilation_cache

from conftest import compilations
from tactile_jax.batch import run_batch
from tactile_jax.fit import FitOptions
from tactile_jax.io import write_recording
from tactile_jax.recording import Recording
from tactile_jax.results import read_results
from tactile_jax.scene import Scene, simulate

DEPTHS = (0.265e-3, 0.925e-3)
TRUTH = [(0.12, 0.0, 2e-3), (0.0, 0.10, 3e-3), (0.15, 0.0, 4e-3)]


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    before = jax.config.jax_compilation_cache_dir
    path = tmp_path_factory.mktemp("jax_cache")
    jax.config.update("jax_compilation_cache_dir", str(path))
    compilation_cache.reset_cache()
    yield str(path)
    jax.config.update("jax_compilation_cache_dir", before)
    compilation_cache.reset_cache()


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("dataset")
    pool = [simulate(Scene(velocity=(vx, vy), contact_radius=a, duration=2.048, seed=k, snr_db=50.0)).signals
            for k, (vx, vy, a) in enumerate(TRUTH)]
    write_recording(root / "multi.npz", Recording(np.stack(pool), 1000.0, DEPTHS))
    (root / "sub").mkdir()
    write_recording(root / "sub" / "one.h5", Recording(pool[2], 1000.0, DEPTHS))
    bad = np.stack([pool[0], pool[1]])
    bad[1, 2, 100] = np.nan
    np.savez(root / "sub" / "nan.npz", signals=bad, fs=1000.0, depths=DEPTHS)
    np.savez(root / "nofs.npz", signals=pool[0], depths=DEPTHS)
    np.savez(root / "shape.npz", signals=pool[0][:3], fs=1000.0, depths=DEPTHS)
    (root / "readme.txt").write_text("not data")
    (root / "broken.h5").write_bytes(b"not hdf5")
    return root


@pytest.fixture(scope="module")
def local_run(dataset, cache_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("out") / "results.json"
    summary = run_batch([dataset], out, chunk_size=8, progress=False)
    return summary, read_results(out)


def _by_key(rows):
    return {(r["file"], int(r["index"])): r for r in rows}


def test_rows_for_every_record_and_bad_input(local_run, dataset):
    summary, rows = local_run
    rows = _by_key(rows)
    multi, nan, one = str(dataset / "multi.npz"), str(dataset / "sub" / "nan.npz"), str(dataset / "sub" / "one.h5")
    expected = {(multi, 0), (multi, 1), (multi, 2), (one, 0), (nan, 0), (nan, 1),
                (str(dataset / "nofs.npz"), 0), (str(dataset / "shape.npz"), 0)}
    assert set(rows) == expected
    assert summary.n_rows == 8 and summary.n_fitted == 6 and summary.n_skipped == 0
    assert rows[(nan, 1)]["status"] == "nonfinite" and "nan.npz [record 1]" in rows[(nan, 1)]["message"]
    assert rows[(str(dataset / "nofs.npz"), 0)]["status"] == "missing_key"
    assert rows[(str(dataset / "shape.npz"), 0)]["status"] == "bad_shape"
    assert summary.n_failed == sum(r["status"] not in ("ok", "not_converged", "poor_fit") for r in rows.values())
    assert summary.n_failed >= 3
    assert any("readme.txt" in n for n in summary.notes) and any("broken.h5" in n for n in summary.notes)
    # slip along one axis: the joint pipeline of ``fit`` recovers the speed on that axis and the radius
    for key, (vx, vy, a) in (((multi, 0), TRUTH[0]), ((multi, 1), TRUTH[1]), ((one, 0), TRUTH[2])):
        row = rows[key]
        assert row["status"] == "ok" and row["model"] == "window", row["message"]
        speed, err = (row["vx"], row["vx_err"]) if vx > vy else (row["vy"], row["vy_err"])
        assert abs(speed - max(vx, vy)) < 5 * err and speed == pytest.approx(max(vx, vy), rel=0.05)
        assert row["a"] is None or abs(row["a"] - a) < 5 * row["a_err"]
        assert row["error_method"].startswith("laplace x jackknife") and row["error_scale"] > 0
    # the same record in two files gives the same numbers (padding and chunk position do not matter)
    assert rows[(multi, 2)]["vx"] == pytest.approx(rows[(one, 0)]["vx"], rel=1e-9)
    assert rows[(multi, 0)]["vx"] == pytest.approx(rows[(nan, 0)]["vx"], rel=1e-9)


def test_resume_skips_done_rows_and_redoes_transient(local_run, dataset, tmp_path):
    _, rows = local_run
    out = tmp_path / "results.json"
    multi = str(dataset / "multi.npz")
    partial = [dict(r) for r in rows if (r["file"], int(r["index"])) != (multi, 1)]
    for r in partial:
        if (r["file"], int(r["index"])) == (multi, 2):
            r.update(status="worker_error", vx=None)            # a transient failure: redone
    out.write_text(json.dumps(partial))
    with compilations() as events:
        summary = run_batch([dataset], out, chunk_size=8, progress=False)
    assert summary.n_fitted == 2 and summary.n_skipped == 6
    assert events == []                                                  # no new compilation
    again = _by_key(read_results(out))
    ref = _by_key(rows)
    assert set(again) == set(ref)
    for key in ((multi, 1), (multi, 2)):
        assert again[key]["status"] == ref[key]["status"]
        assert again[key]["vx"] == pytest.approx(ref[key]["vx"], rel=1e-9, abs=1e-12)
    assert not [p for p in os.listdir(tmp_path) if p.endswith(".tmp")]    # atomic writes leave no temp file


def test_bad_settings_raise_one_line(tmp_path, dataset):
    from tactile_jax.errors import TactileInputError

    with pytest.raises(TactileInputError, match="must end in"):
        run_batch([dataset], tmp_path / "r.txt", progress=False)
    with pytest.raises(TactileInputError, match="for fit_recording"):
        run_batch([dataset], tmp_path / "r.json", progress=False, options=FitOptions(model="auto"))
    with pytest.raises(TactileInputError, match="chunk_size"):
        run_batch([dataset], tmp_path / "r.json", progress=False, chunk_size=0)


@pytest.mark.slow
def test_dask_local_cluster_gives_the_same_rows(local_run, dataset, tmp_path):
    pytest.importorskip("dask.distributed")
    _, rows = local_run
    out = tmp_path / "dask.json"
    summary = run_batch([dataset], out, chunk_size=8, progress=False, workers=2)
    assert summary.n_rows == len(rows)
    assert read_results(out) == rows


def test_cli_batch_exit_zero_with_failures(dataset, tmp_path, cache_dir, local_run):
    from click.testing import CliRunner

    from tactile_jax.cli import main

    src = tmp_path / "in"
    shutil.copytree(dataset, src)
    out = tmp_path / "r.csv"
    result = CliRunner().invoke(main, ["batch", str(src), "--out", str(out), "--chunk-size", "8", "--quiet"])
    assert result.exit_code == 0, result.output
    rows = read_results(out)
    failed = sum(r["status"] not in ("ok", "not_converged", "poor_fit") for r in rows)
    assert f"{failed} failed" in result.output and failed == local_run[0].n_failed
    assert len(rows) == 8 and {"nonfinite", "missing_key", "bad_shape"} <= {r["status"] for r in rows}
