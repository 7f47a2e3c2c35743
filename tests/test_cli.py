"""The command line: demo, simulate, spectra, and one-line errors with a non-zero exit."""

import numpy as np
import pytest
from click.testing import CliRunner

from tactile_jax.cli import main
from tactile_jax.io.files import read_recording, read_spectra


@pytest.fixture(scope="module")
def runner():
    return CliRunner()


@pytest.mark.slow
def test_demo_prints_truth_and_estimates(runner, tmp_path):
    """The README's first command end to end (both windows' programs compiled: about a minute)."""
    res = runner.invoke(main, ["demo", "--out-dir", str(tmp_path), "--duration", "4"])
    assert res.exit_code == 0, res.output
    assert "|vx|, Eq. 6 slope" in res.output and "|vx|, joint fit" in res.output and "a, joint fit" in res.output
    assert (tmp_path / "fig5_demo.png").stat().st_size > 10_000


def test_simulate_then_spectra(runner, tmp_path):
    rec_path = tmp_path / "scene.h5"
    res = runner.invoke(main, ["simulate", "--out", str(rec_path), "--duration", "2", "--records", "2",
                               "--velocity", "0.02,0.01", "--contact-depth", "1e-4"])
    assert res.exit_code == 0, res.output
    rec = read_recording(rec_path)
    assert rec.signals.shape == (2, 4, 2000)
    assert rec.truth["a"] == pytest.approx(np.sqrt(0.03 * 1e-4))
    spec_path = tmp_path / "spec.npz"
    res = runner.invoke(main, ["spectra", str(rec_path), "--out", str(spec_path), "--record", "1"])
    assert res.exit_code == 0, res.output
    spec = read_spectra(spec_path)
    assert spec.psd.shape[0] == 4 and spec.ratio.shape == (2, spec.omega.size)


def test_simulate_a_brushed_texture_writes_its_truth(runner, tmp_path):
    rec_path = tmp_path / "brushed.npz"
    res = runner.invoke(main, ["simulate", "--out", str(rec_path), "--duration", "0.5", "--texture", "brushed",
                               "--angle", "30", "--contact-radius", "1e-3"])
    assert res.exit_code == 0, res.output
    tex = read_recording(rec_path).truth["texture"]
    assert tex["name"] == "StretchedTexture" and tex["angle"] == pytest.approx(np.radians(30.0))


def test_simulate_a_sheared_net_writes_its_truth(runner, tmp_path):
    rec_path = tmp_path / "net.npz"
    res = runner.invoke(main, ["simulate", "--out", str(rec_path), "--duration", "0.5", "--texture", "net",
                               "--angle", "20", "--shear", "10", "--contact-radius", "1e-3"])
    assert res.exit_code == 0, res.output
    tex = read_recording(rec_path).truth["texture"]
    assert tex["name"] == "WireNet" and tex["angle"] == pytest.approx(np.radians(20.0))
    assert tex["shear"] == pytest.approx(np.radians(10.0))


@pytest.mark.parametrize(
    "args, needle",
    [
        (["simulate", "--out", "{tmp}/x.h5", "--shear", "5"], "--shear applies to --texture net only"),
        (["spectra", "{tmp}/missing.h5", "--out", "{tmp}/o.npz"], "missing.h5: file not found"),
        (["spectra", "{tmp}/garbage.h5", "--out", "{tmp}/o.npz"], "garbage.h5: not a readable HDF5 file"),
        (["spectra", "{tmp}/short.npz", "--out", "{tmp}/o.npz"], "short.npz: recording has N=10 samples"),
        (["simulate", "--out", "{tmp}/x.h5", "--velocity", "0,0"], "velocity must be non-zero"),
        (["simulate", "--out", "{tmp}/x.h5", "--gains", "1,2"], "--gains must be 4"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(runner, tmp_path, args, needle):
    (tmp_path / "garbage.h5").write_bytes(b"not hdf5 at all")
    from tactile_jax.io.files import write_recording
    from tactile_jax.io.recording import Recording

    write_recording(tmp_path / "short.npz", Recording(np.zeros((4, 10)), 1000.0, (0.265e-3, 0.925e-3)))
    res = runner.invoke(main, [a.format(tmp=tmp_path) for a in args])
    assert res.exit_code == 2
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and needle in lines[0], res.output
    assert "Traceback" not in res.output


def test_one_background_compile_at_a_time(monkeypatch, tmp_path):
    """``tactile-jax`` commands that compiled the analysis program quickly start ``cli.precompile`` in the
    background: it compiles the optimised form unless another one holds its lock (a lock older than
    ``LOCK_AGE`` is taken for a dead one's), and nothing starts where no quick compile ran."""
    import os
    import time

    from tactile_jax.cli import common, precompile
    from tactile_jax.inference import fit

    calls = []
    monkeypatch.setattr(common, "CACHE", str(tmp_path / "jax"))
    monkeypatch.setattr(fit, "warm_up", lambda options: calls.append(options.window))
    lock = tmp_path / "export" / "precompile-gaussian.lock"
    lock.parent.mkdir()
    lock.touch()
    precompile.main(["gaussian"])                       # another one runs
    assert calls == []
    old = time.time() - 2 * precompile.LOCK_AGE
    os.utime(lock, (old, old))
    precompile.main(["gaussian"])                       # a dead one's lock
    precompile.main(["default"])
    assert calls == ["gaussian", None] and not lock.exists()

    spawned = []
    monkeypatch.setattr("subprocess.Popen", lambda *a, **k: spawned.append(a))
    common.optimise_later(None)                         # no quick compile in this process
    assert spawned == []
