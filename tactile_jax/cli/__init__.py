"""The ``tactile-jax`` command line: one module per command."""

from .app import main as main
