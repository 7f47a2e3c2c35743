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

__all__ = ["CACHE", "user_errors", "parse_floats"]

# float64 is chosen here, at the entry point (the library never switches it on itself)
jax.config.update("jax_enable_x64", True)
#: compiled programs persist across runs (set TACTILE_JAX_CACHE="" to disable)
CACHE = os.environ.get("TACTILE_JAX_CACHE", os.path.join(os.path.expanduser("~"), ".cache", "tactile_jax", "jax"))
if CACHE:
    jax.config.update("jax_compilation_cache_dir", CACHE)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)


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


