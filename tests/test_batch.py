"""Batch reprocessing (issue 7): rows for every record, bad input as rows, resume, atomic output, Dask.

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

from tactile_jax import batch_fit
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
    # slip along one axis: the pair model recovers the speed on that axis and the contact radius
    for key, (vx, vy, a) in (((multi, 0), TRUTH[0]), ((multi, 1), TRUTH[1]), ((one, 0), TRUTH[2])):
        row = rows[key]
        assert row["status"] in ("ok", "poor_fit") and row["model"] == "pair"
        speed = row["vx"] if vx > vy else row["vy"]
        assert speed == pytest.approx(max(vx, vy), rel=0.1)
        assert row["a"] == pytest.approx(a, rel=0.5)
        assert row["error_method"] == "laplace x max(redchi, 1) x bin_factor" and row["error_scale"] is None
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
    compiled = batch_fit._fit_stage._cache_size()
    summary = run_batch([dataset], out, chunk_size=8, progress=False)
    assert summary.n_fitted == 2 and summary.n_skipped == 6
    assert batch_fit._fit_stage._cache_size() == compiled               # no new compilation
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
    with pytest.raises(TactileInputError, match="unknown model"):
        run_batch([dataset], tmp_path / "r.json", progress=False, model="nope")
    with pytest.raises(TactileInputError, match="chunk_size"):
        run_batch([dataset], tmp_path / "r.json", progress=False, chunk_size=0)
    with pytest.raises(TactileInputError, match="cross-pair chain"):
        run_batch([dataset], tmp_path / "r.json", progress=False, options=FitOptions(cross_pairs=2))


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


# --------------------------------------------------------------------------- the chunk solver (gauss_newton)


@pytest.fixture(scope="module")
def hard_chunk(dataset):
    """The 3 simulated records, one of independent noise (no band), one whose deep probes repeat the
    shallow ones (a flat ratio: the speed runs away), the first again with only its y pair flat, and
    the other 2 again: a chunk of 8 records."""
    from tactile_jax.io import read_recording

    good = np.asarray(read_recording(dataset / "multi.npz").signals, float)
    rng = np.random.default_rng(0)
    common = good[0].copy()
    for p in (0, 2):
        common[p + 1] = common[p] * (1 + 1e-3 * rng.standard_normal(common.shape[-1]))
    one_flat = good[0].copy()
    one_flat[3] = common[3]
    one_flat[2] = common[2]
    x = np.concatenate([good, rng.standard_normal((1, 4, good.shape[-1])), common[None], one_flat[None], good[1:]])
    b = len(x)
    meta = batch_fit.ChunkMeta(fs=np.full(b, 1000.0), depths=np.tile(DEPTHS, (b, 1)), gains=np.ones((b, 2)),
                               velocity=np.zeros((b, 2)), known=np.zeros(b, bool), curvature_radius=np.full(b, 0.03))
    return x, meta


def test_gauss_newton_agrees_with_minpack_and_flags_hard_records(hard_chunk):
    """The chunk solver against MINPACK's Levenberg-Marquardt (scipy) on the chunk's pair problems: the
    same fits relative to the error bars; no band and a running-away speed come out as statuses.

    (The comparison with optimistix LM, the solver the batch used before, is in
    ``benchmarks/throughput.py --compare-solvers``: optimistix compiles this residual in ~30 s.)
    """
    import jax.numpy as jnp
    from scipy.optimize import least_squares as minpack

    from tactile_jax.gauss_newton import gauss_newton

    x, meta = hard_chunk
    fit = batch_fit.FitProgram(solver="gauss_newton")(x, meta)
    assert list(fit.status[:3]) == ["ok"] * 3
    assert fit.status[3] == "no_band"
    assert fit.status[4] == "not_converged" and "did not converge (gauss_newton)" in fit.message[4]
    # one flat pair (no slip along y) runs away alone: vy not determined, the record still fitted
    assert fit.status[5] == "ok" and np.isnan(fit.vy[5]) and "vy not determined: its pair's log ratio is flat" in fit.message[5]
    assert fit.vx[5] == pytest.approx(fit.vx[0], rel=1e-6)
    # the chunk's pair problems, as the program builds them
    options = FitOptions()
    stage = batch_fit._spectral_stage(jnp.asarray(x), jnp.asarray(meta.fs), jnp.asarray(meta.depths),
                                      jnp.asarray(meta.gains), options=options, nperseg=None)
    spec = jax.eval_shape(lambda s: batch_fit._spectra(s, 1000.0, options, None), jnp.asarray(x[0]))
    kernel = tuple(map(tuple, spec.kernel))
    offsets, weights = batch_fit._kept_kernel(kernel)
    span = batch_fit._pair_span(np.asarray(stage["band"]), kernel, 64)
    assert span > 0                                             # the half-bin grid layout is the one used
    theta0, args, free = jax.vmap(lambda st, d: batch_fit._pair_problems_grid(
        st, d, jnp.ones(2), jnp.zeros(2), jnp.zeros(2, bool), span, options, offsets, jnp.log(jnp.asarray(weights))))(
        stage, jnp.asarray(meta.depths))
    flat = jax.tree_util.tree_map(lambda t: t.reshape((-1,) + t.shape[2:]), (theta0, args, free))
    res = batch_fit._GridResiduals(batch_fit._grid_shifts(offsets))
    # the hand-written Jacobian is forward-mode AD's
    _, j_a = jax.vmap(res.value_and_jac)(flat[0], flat[1])
    j_f = jax.vmap(jax.jacfwd(res))(flat[0], flat[1])
    np.testing.assert_allclose(j_a, j_f, rtol=1e-9, atol=1e-9 * float(jnp.max(jnp.abs(j_f))))
    gn = jax.vmap(lambda t, a, f: gauss_newton(res, t, a, f, value_and_jac=res.value_and_jac))(*flat)
    fitted = np.flatnonzero(np.asarray(flat[2]).any(-1))
    good = [i for i in fitted if i < 6]                         # pairs of the 3 simulated records
    assert len(good) >= 3 and all(bool(gn.converged[i]) for i in good)
    assert not bool(np.all(gn.converged[8:10]))                 # the running-away pairs
    residual = jax.jit(res)
    for i in good:
        theta_i, args_i, _ = jax.tree_util.tree_map(lambda t, i=i: t[i], flat)
        ref = minpack(lambda p, a=args_i: np.asarray(residual(jnp.asarray([p[0], p[1], 0.0]), a)),
                      np.asarray(theta_i[:2]), method="lm", xtol=1e-12, ftol=1e-12)
        sd = np.sqrt(np.diag(np.asarray(gn.cov[i])))[:2]
        assert np.all(np.abs(np.asarray(gn.theta[i, :2]) - ref.x) < 1e-3 * sd), i


def test_main_band_drops_stray_bins_keeps_harmonics():
    m = 64
    band = np.zeros((3, m), bool)
    band[0, 1:12] = True
    band[0, 50] = True                              # a lone coherent noise bin far above the band
    band[1, [4, 5, 8, 9, 12, 13, 16]] = True        # a grating's lines: kept
    band[2, 1:10] = True
    band[2, m - 1] = True                           # the Nyquist bin
    kept = np.asarray(batch_fit._main_band(jax.numpy.asarray(band)))
    assert kept[0].sum() == 11 and not kept[0, 50]
    assert np.array_equal(kept[1], band[1])
    assert kept[2].sum() == 9 and not kept[2, m - 1]


def test_resolution_nperseg_follows_the_slowest_majority():
    fs, d = np.full(3, 1000.0), np.tile(DEPTHS, (3, 1))
    ok = np.array([[True, False]] * 3)
    rule = batch_fit.resolution_nperseg
    # 0.66 mm x 2 pi x 1 kHz / 0.15 = 27.6 / v samples: 0.2 m/s -> 138 -> the default 1024
    assert rule(np.array([[0.2, 0.0]] * 3), ok, fs, d, 8192, 1024) == 1024
    assert rule(np.array([[0.02, 0.0]] * 3), ok, fs, d, 8192, 1024) == 2048        # 1383 -> 2048
    assert rule(np.array([[0.002, 0.0]] * 3), ok, fs, d, 8192, 1024) == 2048       # capped: 6 segments left
    assert rule(np.array([[0.002, 0.0]] * 3), ok, fs, d, 8000, 512) == 2048        # 2 N / 7 = 2285 -> 2048
    # a fast slip whose band is narrow: 10 bins at 1024 -> 24 wanted -> 2458 -> capped at 2048
    assert rule(np.array([[0.2, 0.0]] * 3), ok, fs, d, 8192, 1024, n_band=np.array([[10, 40]] * 3)) == 2048
    assert rule(np.array([[0.2, 0.0]] * 3), ok, fs, d, 65536, 1024, n_band=np.array([[10, 40]] * 3)) == 4096
    assert rule(np.array([[0.2, 0.0]] * 3), ok, fs, d, 65536, 1024, n_band=np.array([[30, 2]] * 3)) == 1024
    # the joint model's floor (FitOptions.min_band_bins = 8): 5 bins -> 1638 -> 2048; 10 bins: kept
    assert rule(np.array([[0.2, 0.0]] * 3), ok, fs, d, 8192, 1024, n_band=np.array([[5, 40]] * 3), min_band_bins=8) == 2048
    assert rule(np.array([[0.2, 0.0]] * 3), ok, fs, d, 8192, 1024, n_band=np.array([[10, 40]] * 3), min_band_bins=8) == 1024
    assert rule(np.array([[0.02, 0.0]] * 3), ok, fs, d, 65536, 1024) == 2048
    assert rule(np.array([[0.005, 0.0]] * 3), ok, fs, d, 65536, 1024) == 8192       # 5530 -> 8192
    mixed = np.array([[0.2, 0.0], [0.2, 0.0], [0.005, 0.0]])                        # the median record's
    assert rule(mixed, ok, fs, d, 65536, 1024) == 1024
    assert rule(mixed, np.zeros((3, 2), bool), fs, d, 65536, 1024) == 1024          # no speed: the default
    # no speed on either pair, but a band of 3 + 1 bins (speed_vs_error's 10 dB, 1.5 cm/s, 8 s recording, which
    # ended no_band): stretched by its widest band's count, 8 / 3 x 512 = 1365 -> 2048, as fit_recording does
    none = np.zeros((3, 2), bool)
    assert rule(mixed, none, fs, d, 8000, 512, n_band=np.array([[3, 1]] * 3), min_band_bins=8) == 2048
    assert rule(mixed, none, fs, d, 8000, 512, n_band=np.array([[3, 1]] * 3), min_band_bins=0) == 512
    assert rule(mixed, none, fs, d, 8000, 512, n_band=np.zeros((3, 2), int), min_band_bins=8) == 512
    # one such record beside two with a fast slip: the median record's (the default)
    some = np.array([[True, False], [True, False], [False, False]])
    assert rule(mixed, some, fs, d, 8000, 512, n_band=np.array([[40, 40], [40, 40], [3, 1]]), min_band_bins=8) == 512
    wants = batch_fit.resolution_wants(mixed, some, fs, d, 8000, 512, n_band=np.array([[40, 40], [40, 40], [3, 1]]),
                                       min_band_bins=8)
    assert wants.tolist() == [512, 512, 2048]              # the third is refitted at 2048 if it ends no_band
    assert batch_fit.resolution_wants(mixed, none, fs, d, 8000, 512).tolist() == [0, 0, 0]


@pytest.mark.skipif(not os.environ.get("TACTILE_JAX_SLOW"),
                    reason="two batch programs compile for ~110 s: set TACTILE_JAX_SLOW=1")
@pytest.mark.parametrize("model", ["pair", "joint"])
def test_a_narrow_low_snr_band_gets_finer_bins(model):
    """test_stability's 10 dB, 1.5 cm/s, 8 s recording (3 + 1 band bins at 512 samples, no Eq. 6 slope) through
    the batch; before session 20 it ended no_band there. Alone (joint), the chunk's segment is stretched by the
    band's bin count to 2048 samples; beside two faster records (pair), the chunk keeps the default and the
    record is refitted at its own 2048 (``_refit_narrow``)."""
    from tactile_jax.scene import RandomTexture
    scene = Scene(texture=RandomTexture(), velocity=(0.015, 0.0), contact_radius=1.5e-3, snr_db=10.0,
                  duration=8.0, seed=415)
    x = [simulate(scene).signals]
    if model == "pair":
        x += [simulate(Scene(velocity=(0.15, 0.0), contact_radius=a, snr_db=40.0, duration=8.0, seed=1)).signals
              for a in (1.0e-3, 1.5e-3)]                  # 71 and 63 band bins at 512: they want 512
    b = len(x)
    meta = batch_fit.ChunkMeta(fs=np.full(b, 1000.0), depths=np.tile(DEPTHS, (b, 1)), gains=np.ones((b, 2)),
                               velocity=np.zeros((b, 2)), known=np.zeros(b, bool), curvature_radius=np.full(b, 0.03))
    program = batch_fit.FitProgram(model=model)
    rows = batch_fit.chunk_rows(program(np.stack(x), meta), meta, ["chunk"] * b, range(b), model=model,
                                options=program.options)
    row = rows[0]
    assert row["status"] == "ok" and row["n_bins"] >= 8, row
    assert abs(row["vx"] - 0.015) < 3 * row["vx_err"] and abs(row["a"] - 1.5e-3) < 3 * row["a_err"], row
    if model == "pair":
        assert program.last_nperseg == 512, program.last_nperseg
        assert row["message"].startswith("refitted with 2048-sample segments (the chunk's 512 left"), row["message"]
        assert all(r["status"] == "ok" and "refitted" not in r["message"] for r in rows[1:]), rows[1:]
    else:
        assert program.last_nperseg == 2048 and "refitted" not in row["message"], (program.last_nperseg, row)


@pytest.mark.skipif(not os.environ.get("TACTILE_JAX_SLOW"),
                    reason="the batch's joint program compiles for ~65 s beside another worker: set TACTILE_JAX_SLOW=1")
def test_joint_model_error_bars_from_the_jackknife():
    """The batch's joint model scales its errors by each record's delete-one-segment jackknife, as
    ``fit_recording`` does (16 s records, oblique slip: both pairs carry the slip)."""
    truth = [(0.03, 0.012, 1.5e-3), (0.015, 0.03, 1.2e-3)]
    x = np.stack([simulate(Scene(velocity=(vx, vy), contact_radius=a, snr_db=45.0, seed=20 + k)).signals
                  for k, (vx, vy, a) in enumerate(truth)])
    b = len(truth)
    meta = batch_fit.ChunkMeta(fs=np.full(b, 1000.0), depths=np.tile(DEPTHS, (b, 1)), gains=np.ones((b, 2)),
                               velocity=np.zeros((b, 2)), known=np.zeros((b, 2), bool),
                               curvature_radius=np.full(b, 0.03))
    program = batch_fit.FitProgram(model="joint")
    rows = batch_fit.chunk_rows(program(x, meta), meta, ["chunk"] * b, range(b), model="joint",
                                options=program.options)
    for row, (vx, vy, a) in zip(rows, truth):
        assert row["status"] == "ok" and row["error_method"].startswith("laplace x jackknife"), row
        assert 0.3 < row["error_scale"] < 5
        for name, true in (("vx", vx), ("vy", vy), ("a", a)):
            assert abs(row[name] - true) < 4 * row[name + "_err"], (name, row[name], row[name + "_err"], true)
