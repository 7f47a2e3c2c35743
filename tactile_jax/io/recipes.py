"""Scene recipes: TOML files that say how to fit a kind of scene (``fits/*.toml``), read into plain dicts.

Schema (shared with the paper-experiment recipes)::

    description = "what scene this is for"
    [fit]        # FitOptions fields, plus model = "auto" or a model name (inference.select.MODELS)
    method = "welch"
    velocity = [0.047, 0.0]      # m/s, known from the arm: held fixed
    model = "auto"
    [simulate]   # optional: the scene a recipe reproduces (scene.Scene fields; ignored by `fit --scene`)
    velocity = [0.047, 0.0]
    contact_radius = 2.2e-3
    [simulate.texture]           # optional: name = a texture class + its fields (RandomTexture, DirectionalTexture,
    name = "WireNet"             #   StretchedTexture, ModeTexture, Grating, WireNet)
    pitch = 0.5e-3
    [sweep]      # optional, free-form: read by fits/reproduce.py only

SI units throughout (m, m/s, Hz). Unknown keys or wrong types are a one-line
``TactileInputError`` naming the file and the key. This module checks the file's layout
and the [simulate] keys; the [fit] table stays a dict (``Recipe.fit``), which
``inference.options.recipe_options(recipe.fit, recipe.path)`` checks and turns into
``FitOptions`` (the files import no fitting).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import NamedTuple

import tomllib

from ..errors import TactileInputError

__all__ = ["Recipe", "list_recipes", "load_recipe", "scene_from_recipe"]

_TOP_KEYS = ("description", "fit", "simulate", "sweep")
_TEXTURES = ("RandomTexture", "DirectionalTexture", "StretchedTexture", "ModeTexture", "Grating", "WireNet")


class Recipe(NamedTuple):
    """A loaded recipe: name (file stem), description, the [fit] table (a dict, ``{}`` where the file has none;
    ``inference.options.recipe_options`` makes FitOptions of it), the scene it reproduces (dict or None)."""

    name: str
    description: str
    fit: dict
    simulate: dict | None
    path: str


def _bad(path, problem: str) -> TactileInputError:
    return TactileInputError(problem, source=str(path), code="bad_setting")


def _scene_table(table, path) -> dict:
    from ..simulation.scene import Scene

    if not isinstance(table, dict):
        raise _bad(path, "[simulate] must be a table")
    fields = {f.name for f in dataclasses.fields(Scene)}
    for key in table:
        if key not in fields:
            raise _bad(path, f"unknown key [simulate] {key!r}; expected Scene fields ({', '.join(sorted(fields))})")
    if "texture" in table and not (isinstance(table["texture"], dict) and "name" in table["texture"]):
        raise _bad(path, f"[simulate.texture] must be a table with a name ({', '.join(_TEXTURES)})")
    return dict(table)


def load_recipe(path) -> Recipe:
    """Read and check a TOML recipe. Raises ``TactileInputError`` (one line, naming the file) for bad ones."""
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            doc = tomllib.load(fh)
    except FileNotFoundError:
        raise _bad(p, "recipe file not found") from None
    except tomllib.TOMLDecodeError as err:
        raise _bad(p, f"not valid TOML: {err}") from None
    for key in doc:
        if key not in _TOP_KEYS:
            raise _bad(p, f"unknown key {key!r}; expected {', '.join(_TOP_KEYS)}")
    description = doc.get("description", "")
    if not isinstance(description, str):
        raise _bad(p, "description must be a string")
    fit = doc.get("fit", {})
    if not isinstance(fit, dict):
        raise _bad(p, "[fit] must be a table")
    sim = _scene_table(doc["simulate"], p) if "simulate" in doc else None
    return Recipe(p.stem, description, dict(fit), sim, str(p))


def scene_from_recipe(recipe: Recipe):
    """The ``scene.Scene`` of a recipe's [simulate] table ([simulate.texture]: ``name`` = class, then its fields)."""
    from ..simulation import texture as textures
    from ..simulation.scene import Scene

    if recipe.simulate is None:
        raise _bad(recipe.path, "the recipe has no [simulate] table")
    table = dict(recipe.simulate)
    tex = dict(table.pop("texture", {"name": "RandomTexture"}))
    name = tex.pop("name")
    if name not in _TEXTURES:
        raise _bad(recipe.path, f"[simulate.texture] name = {name!r}: expected {', '.join(_TEXTURES[:-1])} or {_TEXTURES[-1]}")
    if "contact_depth" in table and "contact_radius" not in table:
        table["contact_radius"] = None
    for key in ("velocity", "gains", "dc_offset"):
        if key in table:
            table[key] = tuple(float(v) for v in table[key])
    try:
        return Scene(texture=getattr(textures, name)(**tex), **table)
    except TypeError as err:
        raise _bad(recipe.path, f"[simulate]: {err}") from None


def list_recipes(folder="fits") -> list[Recipe]:
    """Every recipe in a folder, sorted by name."""
    return [load_recipe(p) for p in sorted(Path(folder).glob("*.toml"))]
