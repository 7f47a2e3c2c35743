"""The ``tactile-jax`` command group; each command lives in its own module of this package."""

from __future__ import annotations

import click

from .batch import batch
from .compare_r import compare_r
from .demo import demo
from .fit import fit
from .simulate import simulate
from .spectra import spectra
from .track import track

__all__ = ["main"]


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="tactile_jax")
def main():
    """Slip velocity, contact radius and texture spectra from a vertical-sampling tactile sensor."""


for _command in (simulate, spectra, demo, fit, batch, track, compare_r):
    main.add_command(_command)

if __name__ == "__main__":  # pragma: no cover
    main()
