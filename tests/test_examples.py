"""Every example runs, with tiny sizes."""

import runpy
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def test_simulate_and_measure(tmp_path):
    mod = runpy.run_path(str(EXAMPLES / "simulate_and_measure.py"))
    fit = mod["main"](duration=6.0, out=str(tmp_path / "scene.h5"))
    assert fit.converged and fit.speed == pytest.approx(0.03, rel=0.05)
