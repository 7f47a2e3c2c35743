"""Tests run in float64 (chosen here, as the library leaves it to the entry points).

Every joint fit runs one compiled program (``inference.core``: its inputs have one shape whatever the
recording), so the suite pays its compilation once. The modules run in parallel (pytest-xdist,
``--dist loadgroup`` in pyproject.toml): every module that runs the joint pipeline goes to one
worker (``JOINT_MODULES``), a module with costly fixtures to one worker, the other tests one by one, and the
processes share one compilation cache per run (below).
"""

import os

# not the user's cache: importing tactile_jax.cli would switch on ~/.cache/tactile_jax for the whole run
os.environ["TACTILE_JAX_CACHE"] = ""
# The suite is bound by compilation: its programs run for milliseconds and compile for seconds. XLA's CPU
# loop emitters at LLVM optimisation level 1 compile the Gaussian window's analysis program in 13 s against
# 27 s with the default fusion emitters, and run it a third slower (0.57 s against 0.42 s warm); the default
# tier takes 25 % less time with them. Users' programs keep XLA's defaults. Set before jax starts its
# backend (pytest-xdist's workers inherit it); an XLA that does not know the flags would abort at its start,
# so a child process tries them first (once, in the controlling process).
_FAST_COMPILE = "--xla_cpu_use_fusion_emitters=false --xla_backend_optimization_level=1"
if "TACTILE_JAX_TEST_XLA_FLAGS" not in os.environ:
    import subprocess  # noqa: E402
    import sys  # noqa: E402

    _flags = " ".join([os.environ.get("XLA_FLAGS", ""), _FAST_COMPILE]).strip()
    _probe = subprocess.run([sys.executable, "-c", "import jax; jax.devices('cpu')"], capture_output=True,
                            env={**os.environ, "XLA_FLAGS": _flags})
    os.environ["TACTILE_JAX_TEST_XLA_FLAGS"] = "1"
    if _probe.returncode == 0:
        os.environ["XLA_FLAGS"] = _flags

import contextlib  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402
import uuid  # noqa: E402

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)
# one compilation cache for the run, shared by its worker processes, in the temporary directory (per
# pytest-xdist run id), so that no run starts warm
_RUN = os.environ.get("PYTEST_XDIST_TESTRUNUID") or f"pid{os.getpid()}"
_CACHE_DIR = os.path.join(tempfile.gettempdir(), f"tactile_jax_tests_{_RUN}", "jax")
jax.config.update("jax_compilation_cache_dir", _CACHE_DIR)
# only programs worth sharing between the workers (the pipeline's take seconds): caching every eager
# operation's tiny program costs more disk writes than it saves
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)


#: the options of the default tier's end-to-end tests: the Gaussian window's program alone (the default
#: compiles the Hertz disk's program too, about 20 s more; the slow tier runs it: the demo, the window choice)
GAUSS = {"window": "gaussian"}


def pytest_configure(config):
    """Under pytest-xdist the controlling process picks the run id itself (xdist would draw one only
    when its workers start), so that it knows which cache to remove at the end."""
    if not hasattr(config, "workerinput") and config.pluginmanager.hasplugin("xdist"):
        if getattr(config.option, "testrunuid", None) is None:
            config.option.testrunuid = uuid.uuid4().hex


def pytest_sessionfinish(session):
    """The run's caches go with the run: removed by the controlling process once every worker is done
    (a worker's ``config`` has ``workerinput``)."""
    config = session.config
    if not hasattr(config, "workerinput"):
        run = getattr(config.option, "testrunuid", None)       # None: xdist not installed
        for cache in {os.path.dirname(_CACHE_DIR), os.path.join(tempfile.gettempdir(), f"tactile_jax_tests_{run}")}:
            shutil.rmtree(cache, ignore_errors=True)


#: modules that run the joint pipeline end to end: one worker runs them all, so that its compiled program
#: serves every one of them (a second worker would compile it again); the others run beside it
JOINT_MODULES = {"test_fit.py", "test_cli_edges.py", "test_batch.py", "test_fit_cli.py", "test_model_select.py",
                 "test_cli.py", "test_examples.py", "test_stability.py", "test_reproduce.py", "test_spectra_files.py",
                 "test_analysis.py"}


#: modules whose module-scoped fixtures take seconds: each runs on one worker, so that they are built once
FIXTURE_MODULES = {"test_leakage.py", "test_posterior.py", "test_pair_fit.py"}


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """The joint modules go to one worker, each module of ``FIXTURE_MODULES`` to one; every other test is
    scheduled alone, so that the workers finish together."""
    for item in items:
        name = item.path.name
        if name in JOINT_MODULES:
            item.add_marker(pytest.mark.xdist_group("joint"))
        elif name in FIXTURE_MODULES:
            item.add_marker(pytest.mark.xdist_group(name))


@contextlib.contextmanager
def compilations():
    """Collects the XLA backend compilations (their events) made inside the block, in the yielded list."""
    events = []

    def listen(event, duration, **_):
        if event.endswith("backend_compile_duration"):
            events.append(event)

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        yield events
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
