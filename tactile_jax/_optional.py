"""Optional dependencies, imported where they are used, with one line naming the extra that installs them."""

from __future__ import annotations

import importlib
from types import ModuleType

__all__ = ["MissingExtra", "need"]


class MissingExtra(ImportError):
    """An optional dependency is not installed; the message names the pip extra that brings it."""


def need(module: str, extra: str, purpose: str) -> ModuleType:
    """Import ``module`` or raise :class:`MissingExtra` saying ``purpose`` needs ``pip install "tactile_jax[extra]"``."""
    try:
        return importlib.import_module(module)
    except ImportError:
        top = module.split(".")[0]
        raise MissingExtra(f"{purpose} needs {top}: pip install \"tactile_jax[{extra}]\"") from None
