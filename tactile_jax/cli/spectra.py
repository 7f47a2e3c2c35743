"""``tactile-jax spectra``: a recording's spectra, as ``fit`` estimates them, written as a spectra file."""

from __future__ import annotations

import click

from ..errors import TactileInputError
from .common import user_errors


@click.command(short_help="Estimate a recording's spectra into a spectra file.")
@click.argument("recording", type=click.Path(dir_okay=False))
@click.option("--out", "out", required=True, type=click.Path(dir_okay=False), help="Spectra file to write (.h5 or .npz).")
@click.option("--method", type=click.Choice(["welch", "multitaper"]), default="welch", show_default=True)
@click.option("--nperseg", type=int, default=None,
              help="Welch segment length, samples (default: as `fit` chooses it, N/8 rounded down to a power of two, "
                   "longer for slow slips).")
@click.option("--prewhiten", type=int, default=8, show_default=True, help="AR order of the prewhitening filter (0: off).")
@click.option("--record", type=int, default=0, show_default=True, help="Record index in a multi-record file.")
@user_errors
def spectra(recording, out, method, nperseg, prewhiten, record):
    """Estimate a recording's spectra as `fit` does; write a spectra file that fits like the recording.

    The file holds the 4 x 4 spectral matrix (psd, csd, xy), each group of segments' spectra (the
    jackknife's), the estimator (kernel, bin factor, prewhitening filters) and the amplitude ratios.
    """
    import numpy as np

    from ..inference.options import FitOptions, options_from_file
    from ..inference.fit import record_of
    from ..io.files import SpectraData, read_recording, write_spectra
    from ..spectral.segments import to_spectra

    rec = read_recording(recording)
    if not 0 <= record < rec.n_records:
        raise TactileInputError(f"--record {record} out of range: the file holds {rec.n_records} record(s)",
                                source=recording, code="bad_setting")
    one = rec.record(record)
    options = options_from_file(FitOptions(method=method, nperseg=nperseg, prewhiten=prewhiten), one)
    try:
        seg = record_of(one.signals, one.fs, one.depths, options, source=recording).seg
    except TactileInputError as err:
        raise err.with_source(recording) from None
    data = SpectraData(**to_spectra(seg), depths=one.depths, curvature_radius=one.curvature_radius,
                       velocity=one.velocity, gain_ratio=one.gain_ratio)
    path = write_spectra(out, data)
    segs = f"nperseg {int(seg.nperseg)}, " if method == "welch" else ""
    click.echo(f"wrote {path}: {data.omega.size} bins up to {data.omega[-1] / (2 * np.pi):g} Hz "
               f"({method}, {segs}K_eff = {float(seg.dof):.1f}, {data.group_count.size} groups, "
               f"prewhiten AR({prewhiten}))")
