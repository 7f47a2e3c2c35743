"""Tests run in float64 (chosen here, as the library leaves it to the entry points)."""

import os

import jax

# no persistent compilation cache from the tests: importing tactile_jax.cli would switch on
# ~/.cache/tactile_jax/jax for the whole run; a clean-clone run (session 12) aborted inside jax's
# cache write (compilation_cache.put_executable_and_time), and tests should not write there anyway
os.environ["TACTILE_JAX_CACHE"] = ""
jax.config.update("jax_enable_x64", True)
