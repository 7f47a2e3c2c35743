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

from conftest import GAUSS, compilations
from tactile_jax.batch.run import run_batch
from tactile_jax.inference.options import FitOptions
from tactile_jax.io.files import write_recording
from tactile_jax.io.recording import Recording
from tactile_jax.io.results import read_results
from tactile_jax.simulation.scene import Scene, simulate

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
    summary = run_batch([dataset], out, chunk_size=64, progress=False, options=FitOptions(**GAUSS))
    return summary, read_results(out)


def _by_key(rows):
    return {(r["file"], int(r["index"])): r for r in rows}


def test_rows_for_every_record_and_bad_input(local_run, dataset):
    summary, rows = local_run
    rows = _by_key(rows)
    multi, nan, one = str(dataset / "multi.npz"), str(dataset / "sub" / "nan.npz"), str(dataset / "sub" / "one.h5")
    expected = {(multi, 0), (multi, 1), (multi, 2), (one, 0), (nan, 0), (nan, 1),
                (str(dataset / "nofs.npz"), 0), (str(dataset / "shape.npz"), 0),
                (str(dataset / "readme.txt"), 0), (str(dataset / "broken.h5"), 0)}
    assert set(rows) == expected                              # every file the walk finds has a row
    assert summary.n_rows == 10 and summary.n_fitted == 6 and summary.n_skipped == 0
    assert rows[(nan, 1)]["status"] == "nonfinite" and "nan.npz [record 1]" in rows[(nan, 1)]["message"]
    assert rows[(str(dataset / "nofs.npz"), 0)]["status"] == "missing_key"
    assert rows[(str(dataset / "shape.npz"), 0)]["status"] == "bad_shape"
    for name in ("readme.txt", "broken.h5"):
        row = rows[(str(dataset / name), 0)]
        assert row["status"] == "not_recording" and row["message"].startswith(str(dataset / name))
    assert summary.n_failed == sum(r["status"] not in ("ok", "not_converged", "poor_fit") for r in rows.values())
    assert summary.n_failed == 5
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
        summary = run_batch([dataset], out, chunk_size=64, progress=False, options=FitOptions(**GAUSS))
    assert summary.n_fitted == 2 and summary.n_skipped == 8
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
    summary = run_batch([dataset], out, chunk_size=64, progress=False, workers=2, options=FitOptions(**GAUSS))
    assert summary.n_rows == len(rows)
    assert read_results(out) == rows


@pytest.mark.slow
def test_chunks_on_spawned_processes_give_the_same_rows(cache_dir, tmp_path):
    """The default on a CPU: chunks on one spawned process per core (each loading the compiled program from
    the persistent cache, pinned to its core) give the rows of the chunks run in this process: the same
    statuses and messages, numbers within 1e-6 relative (XLA splits its reductions by its thread count, and a
    margin is a difference of chi-squares)."""
    pool = [simulate(Scene(velocity=(0.03, 0.01 * (k % 3)), contact_radius=1.5e-3, duration=2.048, seed=k,
                           snr_db=50.0)).signals for k in range(16)]
    write_recording(tmp_path / "many.npz", Recording(np.stack(pool), 1000.0, DEPTHS))
    here, there = tmp_path / "here.json", tmp_path / "there.json"
    run_batch([tmp_path / "many.npz"], here, progress=False, processes=1, options=FitOptions(**GAUSS))
    summary = run_batch([tmp_path / "many.npz"], there, progress=False, processes=2, options=FitOptions(**GAUSS))
    assert summary.n_rows == 16 and summary.n_failed == 0
    for got, want in zip(read_results(there), read_results(here), strict=True):
        assert got.keys() == want.keys()
        for key, value in want.items():
            if isinstance(value, float) and not isinstance(value, bool):
                assert got[key] == pytest.approx(value, rel=1e-6, abs=1e-15), key
            else:
                assert got[key] == value, key


def test_cli_batch_exit_zero_with_failures(dataset, tmp_path, cache_dir, local_run):
    from click.testing import CliRunner

    from tactile_jax.cli import main

    src = tmp_path / "in"
    shutil.copytree(dataset, src)
    out = tmp_path / "r.csv"
    result = CliRunner().invoke(main, ["batch", str(src), "--out", str(out), "--chunk-size", "8", "--quiet", "--window",
                                       "gaussian", "--direction", "oblique"])
    assert result.exit_code == 0, result.output
    rows = read_results(out)
    # a given slip direction: both speeds fitted on every record, no refit to choose, and the row says so
    ok = [r for r in rows if r["status"] == "ok"]
    assert ok and all(r["direction"] == "oblique" and r["vy_err"] is not None for r in ok)
    assert all("direction='oblique'" in r["options"] for r in rows)
    failed = sum(r["status"] not in ("ok", "not_converged", "poor_fit") for r in rows)
    assert f"{failed} failed" in result.output and failed == local_run[0].n_failed
    assert len(rows) == 10 and {"nonfinite", "missing_key", "bad_shape", "not_recording"} <= {r["status"] for r in rows}


def test_rows_do_not_depend_on_chunk_size_and_no_resume_refits(local_run, dataset, tmp_path):
    _, rows = local_run                                     # chunk size 64
    out = tmp_path / "results.json"
    out.write_text(json.dumps(rows))
    summary = run_batch([dataset], out, chunk_size=1, progress=False, resume=False, options=FitOptions(**GAUSS))
    assert summary.n_fitted == 6 and summary.n_skipped == 0                 # every record fitted again
    again, ref = _by_key(read_results(out)), _by_key(rows)
    assert set(again) == set(ref)
    for key, row in ref.items():
        assert again[key]["status"] == row["status"]
        for name in ("vx", "vx_err", "vy", "vy_err", "a", "a_err"):
            if row[name] is not None:
                assert again[key][name] == pytest.approx(row[name], rel=1e-9), (key, name)


def test_resume_with_other_options_refuses_naming_the_difference(local_run, dataset, tmp_path):
    from tactile_jax.errors import TactileInputError

    _, rows = local_run
    assert {r["options"] for r in rows} == {"window='gaussian'"}
    from tactile_jax.io.results import write_results

    out = tmp_path / "results.csv"
    write_results(out, rows)
    with pytest.raises(TactileInputError, match=r"results.csv: holds rows fitted with fit_gain=False, this run has "
                                                r"fit_gain=True: rerun with --no-resume"):
        run_batch([dataset], out, options=FitOptions(fit_gain=True, **GAUSS), progress=False)
    untagged = [{k: v for k, v in r.items() if k != "options"} for r in rows]
    write_results(out, untagged)
    with pytest.raises(TactileInputError, match="options=not recorded"):
        run_batch([dataset], out, progress=False, options=FitOptions(**GAUSS))


def test_folder_without_recordings_is_an_error(tmp_path):
    from click.testing import CliRunner

    from tactile_jax.cli import main

    folder = tmp_path / "notes"
    folder.mkdir()
    (folder / "a.txt").write_text("text")
    result = CliRunner().invoke(main, ["batch", str(folder), "--out", str(tmp_path / "r.csv")])
    assert result.exit_code == 2
    assert result.output.strip() == f"error: {folder}: no recording files (.h5, .hdf5, .npz with 'signals') in this " \
                                    "folder or below"
    assert not (tmp_path / "r.csv").exists()


def test_workers_without_dask_name_the_extra(dataset, tmp_path, monkeypatch):
    import sys

    from click.testing import CliRunner

    from tactile_jax.cli import main

    monkeypatch.setitem(sys.modules, "dask", None)
    monkeypatch.setitem(sys.modules, "dask.distributed", None)
    result = CliRunner().invoke(main, ["batch", str(dataset), "--out", str(tmp_path / "r.csv"), "--workers", "2"])
    assert result.exit_code == 2
    assert result.output.strip() == 'error: a Dask run (--workers, --scheduler) needs dask: pip install ' \
                                    '"tactile_jax[batch]"'


@pytest.mark.slow
def test_near_axis_slips_no_ok_row_beyond_3_sigma(tmp_path):
    """50 slips within 10 deg of an axis (16 s, 50 dB, a 1.5-3 mm): each speed of an ``ok`` row is within
    3 sigma of the truth, or reported undetermined with a bound that holds it, or held at 0 by the slip
    direction where the truth is below 3 % of |v| (the fits' speed errors are about 0.5 % of |v|)."""
    rng = np.random.default_rng(2031)
    truth, records = [], []
    for k in range(50):
        speed, angle = rng.uniform(0.02, 0.08), np.deg2rad(rng.uniform(-10.0, 10.0))
        along_y = k % 5 == 4
        v = (speed * np.cos(angle), speed * np.sin(angle))
        v = (v[1], v[0]) if along_y else v
        a = rng.uniform(1.5e-3, 3e-3)
        records.append(simulate(Scene(velocity=v, contact_radius=a, seed=100 + k, snr_db=50.0)).signals)
        truth.append((abs(v[0]), abs(v[1])))
    write_recording(tmp_path / "near_axis.npz", Recording(np.stack(records), 1000.0, DEPTHS))
    out = tmp_path / "r.csv"
    run_batch([tmp_path / "near_axis.npz"], out, progress=False)
    rows = sorted(read_results(out), key=lambda r: int(r["index"]))
    bad = []
    for row, (vx, vy) in zip(rows, truth):
        if row["status"] != "ok":
            continue
        for name, t in (("vx", vx), ("vy", vy)):
            value, err, upper = row[name], row[f"{name}_err"], row.get(f"{name}_upper")
            if value is None:
                assert upper is not None and t <= upper, (row["index"], name, t, upper)
            elif err is None:           # held at 0: the minor speed of a slip along the other axis
                assert value == 0.0 and row["direction"] == f"along {'y' if name == 'vx' else 'x'}", row
                if t > 0.03 * np.hypot(vx, vy):
                    bad.append((int(row["index"]), name, t, value, "held"))
            elif abs(value - t) > 3 * err:
                bad.append((int(row["index"]), name, t, value, err))
    assert not bad, bad
    assert sum(r["status"] == "ok" for r in rows) >= 45


def test_chunk_spectra_at_once_give_the_same_rows(local_run, dataset, tmp_path, monkeypatch):
    """The accelerator's path (the chunk's spectra in one jnp program), run on the CPU: the rows of numpy's
    record-by-record spectra, a bad record still its own row."""
    import tactile_jax.batch.run as batch_run

    monkeypatch.setattr(batch_run, "DEVICE_SPECTRA", True)
    out = tmp_path / "rows.json"
    run_batch([dataset / "sub" / "nan.npz"], out, chunk_size=64, progress=False, processes=1,
              options=FitOptions(**GAUSS))
    new, old = _by_key(read_results(out)), _by_key(local_run[1])
    assert sorted(row["status"] for row in new.values()) == ["nonfinite", "ok"]
    for key, row in new.items():
        assert row["status"] == old[key]["status"], key
        for name in ("vx", "vy", "a"):
            value, err = old[key].get(name), old[key].get(name + "_err")
            if value is not None:
                assert abs(row[name] - value) <= 1e-6 * (err if err else abs(value)), (key, name)


def test_workers_get_one_blas_thread_unless_the_user_set_it(monkeypatch):
    """Spawned workers inherit one BLAS thread each (threaded BLAS calls of two workers contend for the same
    cores); a value the user set is kept, and the parent's environment is restored."""
    from tactile_jax.batch import run as batch_run

    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    before = dict(os.environ)
    with batch_run._worker_environ():
        assert os.environ["OPENBLAS_NUM_THREADS"] == "1"
        assert os.environ["OMP_NUM_THREADS"] == "3"
    assert dict(os.environ) == before


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2,
                    reason="pins workers where the process may run on two cores")
def test_workers_run_on_a_core_each():
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from tactile_jax.batch import run as batch_run

    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(2, mp_context=context, **batch_run._pinning(context, 2)) as pool:
        seen = [pool.submit(os.sched_getaffinity, 0) for _ in range(8)]
        cores = {frozenset(f.result()) for f in seen}
    assert all(len(c) == 1 for c in cores) and len(cores) <= 2
    assert batch_run._pinning(context, len(os.sched_getaffinity(0)) + 1) == {}    # more workers than cores


def test_the_program_is_compiled_once_before_the_workers_start(monkeypatch, tmp_path):
    """With a persistent cache the batch compiles the analysis program here first (the workers then load it), for
    the batch's options, once for these sources; a failure leaves it to the workers, and programs this process
    held stay."""
    from tactile_jax.batch import run as batch_run
    from tactile_jax.inference import run

    cache = str(tmp_path / "jax")
    calls = []
    monkeypatch.setattr(run, "analyse_one", lambda rec, settings, choices: calls.append(settings.hertz is None))
    batch_run._compile_here(FitOptions(window="gaussian"), cache)
    batch_run._compile_here(FitOptions(), cache)
    batch_run._compile_here(FitOptions(), cache)            # done already: the marker says so
    assert calls == [True, False]

    def broken(*args):
        raise RuntimeError("no")

    monkeypatch.setattr(run, "analyse_one", broken)
    run._programs()
    batch_run._compile_here(FitOptions(), str(tmp_path / "other" / "jax"))     # no exception
    assert run._programs.cache_info().currsize == 1        # held before: kept
    assert not (tmp_path / "other" / "export").exists()


def test_a_first_run_compiles_quickly_until_the_optimised_form_is_cached(tmp_path):
    """``run.quick_first``: where no process has compiled a kept program's optimised form into the persistent cache
    (no marker beside its export), it is compiled with ``run.QUICK_COMPILE``; a process that compiles the optimised
    form leaves the marker, and later quick-first processes use it. Off, the optimised form is compiled at once."""
    import jax.numpy as jnp

    from tactile_jax.inference import run

    before = jax.config.jax_compilation_cache_dir
    jax.config.update("jax_compilation_cache_dir", str(tmp_path / "jax"))
    compilation_cache.reset_cache()
    x = jnp.linspace(0.0, 1.0, 5)
    try:
        run.quick_first(True)
        quick = run._exported(lambda v: jnp.sin(v) * 2.0, "quick_probe")
        np.testing.assert_allclose(np.asarray(quick(x)), 2.0 * np.sin(np.asarray(x)), rtol=1e-12)
        assert run.quick_used() and not list((tmp_path / "export").glob("*.optimised"))
        run._QUICK["used"] = False
        run.quick_first(False)
        optimised = run._exported(lambda v: jnp.sin(v) * 2.0, "quick_probe")        # a later run: optimised
        np.testing.assert_allclose(np.asarray(optimised(x)), np.asarray(quick(x)), rtol=1e-12)
        assert not run.quick_used() and len(list((tmp_path / "export").glob("*.optimised"))) == 1
        run.quick_first(True)
        again = run._exported(lambda v: jnp.sin(v) * 2.0, "quick_probe")            # marked: optimised
        again(x)
        assert not run.quick_used()
    finally:
        run.quick_first(False)
        run._QUICK["used"] = False
        jax.config.update("jax_compilation_cache_dir", before)
        compilation_cache.reset_cache()
