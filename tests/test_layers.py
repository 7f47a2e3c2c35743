"""The package's layers: file -> spectra -> analysis -> row, each importing only downwards.

The analysis (``inference``, ``model``, ``spectral``) imports no files, figures, simulator, command line,
batch or tracker; the file layer (``io``) imports no fitting. Both share the data contract
(``tactile_jax.contract``), which imports neither. Checked on the source (``ast``), every import
statement counted, those inside functions too, so that importing the package (whose ``__init__``
imports everything) does not hide a crossing.
"""

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "tactile_jax"

ANALYSIS = ("inference", "model", "spectral")
FILES = ("io",)
#: what each layer must not import (module prefixes)
FORBIDDEN = {
    **{layer: ("tactile_jax.io", "tactile_jax.viz", "tactile_jax.simulation", "tactile_jax.cli",
               "tactile_jax.batch", "tactile_jax.track", "tactile_jax.studies") for layer in ANALYSIS},
    **{layer: ("tactile_jax.inference", "tactile_jax.uncertainty", "tactile_jax.batch", "tactile_jax.track",
               "tactile_jax.cli", "tactile_jax.studies") for layer in FILES},
}


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported(path: Path) -> set[tuple[str, int]]:
    """(module, line) for every import in ``path``, relative ones resolved; ``from a import b`` gives both
    ``a`` and ``a.b`` (b may be a module); ``importlib.import_module("...")`` with a literal counts too."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = module_name(path).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update((alias.name, node.lineno) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            out.add((module, node.lineno))
            out.update((f"{module}.{alias.name}", node.lineno) for alias in node.names)
        elif (isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant)
              and isinstance(node.args[0].value, str)
              and (getattr(node.func, "attr", None) == "import_module"
                   or getattr(node.func, "id", None) in ("import_module", "__import__"))):
            out.add((node.args[0].value, node.lineno))
    return out


def crossings(layer: str) -> list[str]:
    """'path:line imports module' for each forbidden import under ``layer`` (``from a.b import C``: a.b alone)."""
    bad = []
    for path in sorted((ROOT / layer).rglob("*.py")):
        found = {}
        for module, line in sorted(imported(path), key=lambda ml: (ml[1], ml[0])):
            if any(module == f or module.startswith(f + ".") for f in FORBIDDEN[layer]):
                if not any(module.startswith(m + ".") for m in found.get(line, ())):
                    found.setdefault(line, []).append(module)
        bad += [f"{path.relative_to(ROOT.parent)}:{line} imports {m}" for line, ms in found.items() for m in ms]
    return bad


@pytest.mark.parametrize("layer", ANALYSIS + FILES)
def test_layer_imports_only_downwards(layer):
    assert (ROOT / layer).is_dir()
    assert crossings(layer) == []


@pytest.mark.parametrize("layer", ANALYSIS + FILES)
def test_no_crossing_through_another_module(layer):
    """Nor through a module between the layers (``uncertainty.profile``, ``contract``, ...): the modules each
    module of ``layer`` imports, followed to the end, include no forbidden one (the package's ``__init__``,
    which imports everything for users, not counted)."""
    modules = {module_name(p): p for p in ROOT.rglob("*.py")}
    root = ROOT.name
    reached = {}                                  # module -> the module that imports it first
    todo = [m for m in modules if m.startswith(f"{root}.{layer}.") or m == f"{root}.{layer}"]
    for m in todo:
        reached[m] = None
    while todo:
        m = todo.pop()
        for dep, _ in imported(modules[m]):
            if dep in modules and dep != root and dep not in reached:
                reached[dep] = m
                todo.append(dep)
    bad = []
    for m in reached:
        if any(m == f or m.startswith(f + ".") for f in FORBIDDEN[layer]):
            chain = [m]
            while reached[chain[-1]] is not None:
                chain.append(reached[chain[-1]])
            bad.append(" <- ".join(chain))
    assert bad == []


def test_the_data_contract_imports_no_layer():
    """``contract`` is what io and inference share: it may import only the package's leaf modules."""
    leaves = ("tactile_jax.errors", "tactile_jax.status", "tactile_jax._numerics")
    mods = {m for m, _ in imported(ROOT / "contract.py") if m.startswith("tactile_jax")}
    assert all(any(m == leaf or m.startswith(leaf + ".") for leaf in leaves) for m in mods), mods


def test_the_check_sees_relative_and_local_imports(tmp_path, monkeypatch):
    """A crossing inside a function, written relatively, is found (the check does not pass vacuously)."""
    fake = tmp_path / "tactile_jax"
    (fake / "inference").mkdir(parents=True)
    (fake / "inference" / "bad.py").write_text(
        "from . import core\n\ndef f():\n    from ..io.recording import Recording\n    from .. import viz\n"
        "    import importlib\n    importlib.import_module('tactile_jax.simulation.scene')\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", fake)
    assert crossings("inference") == ["tactile_jax/inference/bad.py:4 imports tactile_jax.io.recording",
                                      "tactile_jax/inference/bad.py:5 imports tactile_jax.viz",
                                      "tactile_jax/inference/bad.py:7 imports tactile_jax.simulation.scene"]


def test_public_names_stay_where_users_import_them():
    """The moved names are the same objects at their old homes."""
    import tactile_jax as tj
    from tactile_jax import contract
    from tactile_jax.inference import compare_r
    from tactile_jax.inference.result import RESULT_FIELDS
    from tactile_jax.io import recording
    from tactile_jax.studies import compare_r as study

    for name in ("CHANNELS", "SENSOR_DEFAULT", "SENSOR_FROM_FILE", "Recording", "validate_recording"):
        assert getattr(recording, name) is getattr(contract, name)
    assert tj.Recording is contract.Recording and tj.validate_recording is contract.validate_recording
    assert tj.CHANNELS is contract.CHANNELS and RESULT_FIELDS is contract.RESULT_FIELDS
    for name in compare_r.__all__:
        assert getattr(study, name) is getattr(compare_r, name) or name == "fit_bias"
