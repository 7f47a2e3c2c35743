"""Why a record has no usable band: what its spectra hold instead (from its ``Segments``, after the fit).

The smooth joint models need a broadband texture: runs of coherent bins where the
deep probe stands above its noise. When the band selection finds too few, the
spectra usually hold one of two things, and the user should be told which:

- **lines**: a periodic texture (grating, wire net, knurl) puts its power in
  a few coherent bins, with incoherent leakage between them: the line model
  (``inference.line_texture``) takes such a record;
- **nothing coherent in the deep probes**: the texture's wavenumbers are so
  high that exp(-|k| d2) has taken its signal below the deep probe's noise
  (or the signal is too weak, or the deep gains are wrong).
"""

from __future__ import annotations

import numpy as np

from . import band
from .segments import Segments

__all__ = ["LINE_DB", "LINE_COHERENCE", "no_band_reason"]

#: a line bin stands this far above the deep probe's median level (dB) ...
LINE_DB = 10.0
#: ... with at least this magnitude-squared coherence between the pair's probes
LINE_COHERENCE = 0.9


def _lines(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) of the runs of True in ``mask``."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return list(zip(edges[::2], edges[1::2]))


def no_band_reason(seg: Segments) -> str:
    """One sentence on what the spectra of a record without a usable band hold (lines, or no coherent
    deep signal), naming the strongest line's frequency (Hz), height (dB) and coherence."""
    n = int(seg.n_valid)
    spec = band.spectra(seg)
    deep = np.asarray(spec.psd, float)[1::2, 1:n]                               # (2, n - 1) from bin 1
    g2 = np.asarray(band.coherence(spec), float)[:, 1:n]
    hz = np.asarray(spec.omega, float)[1:n] / (2.0 * np.pi)
    found = []
    for p, name in enumerate("xy"):
        s22, coh = deep[p], g2[p]
        pos = s22 > 0
        ref = np.median(s22[pos]) if pos.any() else 1.0
        with np.errstate(divide="ignore"):
            level = 10.0 * np.log10(np.where(pos, s22 / ref, 1.0))
        runs = _lines((level > LINE_DB) & (coh > LINE_COHERENCE))
        if runs:
            peak = max(runs, key=lambda r: level[r[0]:r[1]].max())
            i = peak[0] + int(np.argmax(level[peak[0]:peak[1]]))
            found.append(f"the deep {name} probe holds {len(runs)} coherent line{'s' * (len(runs) > 1)} (strongest "
                         f"at {hz[i]:.1f} Hz, {level[i]:.0f} dB above its median, coherence {coh[i]:.2f})")
    if found:
        return ("; ".join(found) + ": a periodic texture (grating, wire net), whose line spectrum the smooth models "
                "do not describe")
    return ("the deep probes hold no coherent texture line or band above their noise: the texture may be too fine "
            "for the probes' depths (its signal falls as exp(-|k| d) with depth), or the signal too weak")
