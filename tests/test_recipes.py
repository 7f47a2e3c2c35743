"""Scene recipes (fits/*.toml) and ``tactile-jax fit --scene / --model``: loading, checks, precedence."""

from pathlib import Path

import pytest
from click.testing import CliRunner

from tactile_jax.cli import fit as cli
from tactile_jax.cli import main
from tactile_jax.errors import TactileInputError
from tactile_jax.inference.options import FitOptions, recipe_options
from tactile_jax.inference.select import MODELS
from tactile_jax.io.recipes import list_recipes, load_recipe, scene_from_recipe

FITS = Path(__file__).resolve().parents[1] / "fits"


def options_of(recipe):
    """A recipe's FitOptions: the file layer reads the [fit] table as a dict, the analysis checks it."""
    return recipe_options(recipe.fit, recipe.path)


def test_every_shipped_recipe_loads_and_names_a_known_model():
    recipes = list_recipes(FITS)
    names = {r.name for r in recipes}
    assert {"default", "auto", "large_contact", "uncalibrated_gains", "noisy", "slow_slip", "hertz_window"} <= names
    for r in recipes:
        assert isinstance(r.fit, dict)
        opts = options_of(r)
        assert isinstance(opts, FitOptions)
        assert opts.model is None or opts.model in MODELS
        assert opts.window in (None, "gaussian", "hertz")
        assert r.description
        if r.simulate is not None:
            scene = scene_from_recipe(r)
            assert scene.a > 0


def test_recipe_values_reach_fit_options():
    r = options_of(load_recipe(FITS / "slow_slip.toml"))
    assert (r.nperseg, r.fmax, r.model) == (2048, 100.0, "auto")
    r = load_recipe(FITS / "large_contact.toml")
    assert options_of(r).model == "slip" and r.simulate is None
    opts = recipe_options({"velocity": [-0.047, 0.0], "gain_ratio": [1.1, 0.9], "prewhiten": 0})
    assert opts.velocity == (0.047, 0.0) and opts.gain_ratio == (1.1, 0.9) and opts.prewhiten is None


@pytest.mark.parametrize("text, words", [
    ('[fit]\nbogus = 1\n', ["bad.toml", "bogus"]),
    ('colour = "red"\n', ["bad.toml", "colour"]),
    ('[fit]\nmodel = "magic"\n', ["bad.toml", "magic", "auto"]),
    ('[fit]\nmethod = 3\n', ["bad.toml", "method"]),
    ('[fit]\nvelocity = 0.04\n', ["bad.toml", "velocity"]),
    ('[fit]\nnperseg = -4\n', ["bad.toml", "nperseg"]),
    ('fit = 3\n', ["bad.toml", "[fit]", "table"]),
    ('[simulate]\nspeed = 1\n', ["bad.toml", "speed"]),
    ('[fit\n', ["bad.toml", "TOML"]),
])
def test_bad_recipes_are_one_line_errors_naming_file_and_key(tmp_path, text, words):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(TactileInputError) as info:
        options_of(load_recipe(path))
    msg = str(info.value)
    assert "\n" not in msg
    for w in words:
        assert w in msg


def test_missing_recipe_file(tmp_path):
    with pytest.raises(TactileInputError, match="nothere.toml"):
        load_recipe(tmp_path / "nothere.toml")


@pytest.fixture
def captured(monkeypatch):
    """Replace the per-file fit by a recorder of the options it would get."""
    seen = []

    def fake_fit_file(path, options, record):
        seen.append(options)
        return iter(())

    monkeypatch.setattr(cli, "_fit_file", fake_fit_file)
    return seen


def test_fit_scene_recipe_first_explicit_flags_override(tmp_path, captured):
    out = str(tmp_path / "r.json")
    res = CliRunner().invoke(main, ["fit", "x.h5", "--out", out, "--scene", str(FITS / "noisy.toml")])
    assert res.exit_code == 0, res.output
    assert (captured[-1].model, captured[-1].min_snr, captured[-1].method) == ("window+noise", 2.0, "welch")
    res = CliRunner().invoke(main, ["fit", "x.h5", "--out", out, "--scene", str(FITS / "noisy.toml"),
                                        "--method", "multitaper", "--model", "auto"])
    assert res.exit_code == 0, res.output
    assert (captured[-1].model, captured[-1].min_snr, captured[-1].method) == ("auto", 2.0, "multitaper")
    # a default-valued flag that was not typed does not override the recipe
    res = CliRunner().invoke(main, ["fit", "x.h5", "--out", out, "--scene", str(FITS / "uncalibrated_gains.toml")])
    assert captured[-1].method == "multitaper" and captured[-1].model == "window+gain"


def test_fit_bad_scene_or_model_exits_2_with_one_line(tmp_path, captured):
    bad = tmp_path / "bad.toml"
    bad.write_text("[fit]\nwindw = 'hertz'\n")
    res = CliRunner().invoke(main, ["fit", "x.h5", "--out", str(tmp_path / "r.json"), "--scene", str(bad)])
    assert res.exit_code == 2
    assert "bad.toml" in res.output and "windw" in res.output
    res = CliRunner().invoke(main, ["fit", "x.h5", "--out", str(tmp_path / "r.json"), "--model", "nope"])
    assert res.exit_code == 2 and "nope" in res.output and not captured
