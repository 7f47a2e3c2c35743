"""Tests run in float64 (chosen here, as the library leaves it to the entry points).

The suite is compile-bound: a joint fit's programs take 25-35 s of XLA compilation on a
2-core machine and run in a few seconds. Session 13 tried XLA's backend optimisation off
(``--xla_backend_optimization_level=0``): a joint fit's compilation fell from 33 s to 21 s,
but the tests that run long (profile walks, MCMC) ran up to 3x slower and the whole suite
took longer. The modules run in parallel instead (pytest-xdist, ``--dist loadfile`` in
pyproject.toml), each module's tests in one process so that they share its fixtures, and the
processes share one compilation cache per run (below).
"""

import os

# not the user's cache: importing tactile_jax.cli would switch on ~/.cache/tactile_jax/jax for the
# whole run, and tests should not write there (the run's own cache is set below; the abort inside
# jax's cache write in a session-12 run probably came from the memory mappings near their limit)
os.environ["TACTILE_JAX_CACHE"] = ""

import shutil  # noqa: E402
import tempfile  # noqa: E402
import uuid  # noqa: E402

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)
# one compilation cache for the run, shared by its worker processes: a program another worker (or
# this one, before releasing its programs below) compiled is loaded, not compiled again. Per run
# (pytest-xdist's run id), in the temporary directory, so that no run starts warm.
_RUN = os.environ.get("PYTEST_XDIST_TESTRUNUID") or f"pid{os.getpid()}"
_CACHE_DIR = os.path.join(tempfile.gettempdir(), f"tactile_jax_tests_{_RUN}")
jax.config.update("jax_compilation_cache_dir", _CACHE_DIR)


def pytest_configure(config):
    """Under pytest-xdist the controlling process picks the run id itself (xdist would draw one only
    when its workers start), so that it knows which cache to remove at the end."""
    if not hasattr(config, "workerinput") and config.pluginmanager.hasplugin("xdist"):
        if getattr(config.option, "testrunuid", None) is None:
            config.option.testrunuid = uuid.uuid4().hex


def pytest_sessionfinish(session):
    """The run's compilation cache (about 16 MB) goes with the run: removed by the controlling
    process once every worker is done (a worker's ``config`` has ``workerinput``)."""
    config = session.config
    if not hasattr(config, "workerinput"):
        run = getattr(config.option, "testrunuid", None)       # None: xdist not installed
        for cache in {_CACHE_DIR, os.path.join(tempfile.gettempdir(), f"tactile_jax_tests_{run}")}:
            shutil.rmtree(cache, ignore_errors=True)       # _CACHE_DIR: the tests ran in this process (-n0)


#: memory mappings above which jax's compiled programs are released: after a test module, and
#: after any test; one joint fit's programs hold about 4,300 (session 13) and Linux's default
#: vm.max_map_count is 65,530
MAPPINGS_AFTER_MODULE = 20_000
MAPPINGS_AFTER_TEST = 40_000


def _mappings():
    """Number of the process's memory mappings (0 where /proc is not there)."""
    try:
        with open("/proc/self/maps", "rb") as maps:
            return sum(1 for _ in maps)
    except OSError:
        return 0


@pytest.fixture(autouse=True, scope="module")
def _release_after_module():
    """Every compiled executable keeps its own memory mappings. Twice in session 12 a whole run
    crashed near its end inside XLA's compiler (abort, then segfault), in tests that pass alone, with
    tens of thousands of mappings against vm.max_map_count. Releasing after every module kept a run
    under 18,100 but recompiled the same small programs module after module; releasing at a
    threshold keeps what modules share."""
    yield
    if _mappings() > MAPPINGS_AFTER_MODULE:
        jax.clear_caches()


@pytest.fixture(autouse=True)
def _release_after_test():
    yield
    if _mappings() > MAPPINGS_AFTER_TEST:
        jax.clear_caches()
