"""Tests run in float64 (chosen here, as the library leaves it to the entry points)."""

import os

import jax

# no persistent compilation cache from the tests: importing tactile_jax.cli would switch on
# ~/.cache/tactile_jax/jax for the whole run; a clean-clone run (session 12) aborted inside jax's
# cache write (compilation_cache.put_executable_and_time), and tests should not write there anyway
os.environ["TACTILE_JAX_CACHE"] = ""
jax.config.update("jax_enable_x64", True)


import pytest  # noqa: E402


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop jax's compiled programs after each test module. Every executable keeps its own memory
    mappings; a whole run holds thousands, and twice in session 12 a run near its end crashed inside
    XLA's compiler (abort, then segfault), in tests that pass alone: the process's mappings against
    vm.max_map_count (65530) is the suspect. Modules share their compiled functions through
    module-scoped fixtures, not across modules."""
    yield
    jax.clear_caches()
