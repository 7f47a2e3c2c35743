"""What every command shares: float64 and the compilation cache chosen at the entry point, one-line errors.

Flags take SI units (m, m/s, Hz); output for people is in mm and cm/s, labelled.
Bad input ends with one line ``error: <file>: <problem>`` and exit status 2.
"""

from __future__ import annotations

import functools
import os
import sys

import click
import jax

from .._optional import MissingExtra
from ..errors import TactileInputError

__all__ = ["CACHE", "user_errors", "parse_floats", "quick_first", "optimise_later"]

# float64 is chosen here, at the entry point (the library never switches it on itself)
jax.config.update("jax_enable_x64", True)
#: compiled programs persist across runs (set TACTILE_JAX_CACHE="" to disable)
CACHE = os.environ.get("TACTILE_JAX_CACHE", os.path.join(os.path.expanduser("~"), ".cache", "tactile_jax", "jax"))
if CACHE:
    jax.config.update("jax_compilation_cache_dir", CACHE)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)


def quick_first() -> None:
    """For a command that fits a few records (``fit``, ``demo``): where no run has compiled the analysis program's
    optimised form into the cache, compile it quickly (``inference.run.quick_first``). TACTILE_JAX_QUICK_FIRST=0
    always compiles the optimised form."""
    from ..inference import run

    if CACHE and os.environ.get("TACTILE_JAX_QUICK_FIRST", "1") != "0":
        run.quick_first()


def optimise_later(window: str | None) -> None:
    """After a command that compiled the analysis program quickly, compile its optimised form into the cache in a
    separate background process at low priority (``tactile_jax.cli.precompile``), so that later runs load it; the
    command itself returns at once. TACTILE_JAX_BACKGROUND_COMPILE=0 leaves it to the next run that needs it."""
    import subprocess

    from ..inference import run

    if not (CACHE and run.quick_used()) or os.environ.get("TACTILE_JAX_BACKGROUND_COMPILE", "1") == "0":
        return
    try:
        subprocess.Popen([sys.executable, "-m", "tactile_jax.cli.precompile", window or "default"],
                         stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                         start_new_session=True, env={**os.environ, "TACTILE_JAX_CACHE": CACHE})
    except OSError:             # the next run compiles it
        pass


def user_errors(fn):
    """Turn input errors into one line on stderr and exit status 2, never a traceback."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except (TactileInputError, MissingExtra) as err:
            click.echo(f"error: {err}", err=True)
            sys.exit(2)
        except OSError as err:
            click.echo(f"error: {getattr(err, 'filename', None) or ''}: {err.strerror or err}", err=True)
            sys.exit(2)

    return wrapper


def parse_floats(text: str, n: int, name: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise TactileInputError(f"--{name} must be {n} comma-separated numbers, got {text!r}", code="bad_setting") from None
    if len(values) != n:
        raise TactileInputError(f"--{name} must be {n} comma-separated numbers, got {text!r}", code="bad_setting")
    return values


