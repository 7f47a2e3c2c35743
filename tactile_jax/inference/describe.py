"""The analysis program's arrays turned into a result and words: what ``fit`` and ``batch`` both report.

``result_from_analysis`` makes the ``FitResult`` of one record's ``analysis.Analysis``:
the kept fit's values, errors and status (``result.result_from_summary``), the
choices the program made (window, texture, slip direction) with their margins and a
note on each, and, where the data barely tell two models apart, vx, vy and a averaged
over both by their Akaike weights (``select.average_models``).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ..status import Status
from .analysis import A_NEGLIGIBLE, DIRECTIONS, TEXTURES, WINDOWS, Analysis, summary_of
from .core import Summary
from .forward import INDEX
from .result import FitResult, result_from_summary
from .select import average_models, average_windows, lobe_of, texture_name

__all__ = ["result_from_analysis", "notes_of"]

_I_V = (INDEX["log_vx"], INDEX["log_vy"])


def _lobe(coef) -> str:
    along, anisotropy = lobe_of(np.asarray(coef, float))
    return f"power along {along:.0f} deg, anisotropy {anisotropy:.2f}"


def _window_margin(a: Analysis) -> float | None:
    """The margin as reported: chi-square units, the kept window's lead where decisive (positive favours the
    Hertz disk where the windows are averaged)."""
    m = float(a.window_margin)
    if not np.isfinite(m):
        return None
    return -m if (int(a.window) == 0 and float(a.window_weight) == 1.0) else m


def notes_of(a: Analysis) -> tuple[list[str], list[str]]:
    """What to say of the choices the program made: (notes for the message, warnings)."""
    notes, warnings = [], []
    if bool(a.explored):
        h1, hx = (float(x) for x in a.explored_chi2)
        notes.append(f"the Hertz window's own starts found a better fit than the Gaussian scouting's (chi-square "
                     f"{hx:.1f} against {h1:.1f})")
    m = float(a.window_margin)
    if np.isfinite(m):
        averaged = float(a.window_weight) < 1.0
        if not averaged and int(a.window) == 0:
            notes.append(f"Gaussian contact window (chi-square margin {-m:.1f} over the Hertz disk)")
        elif averaged:
            keep_gauss = int(a.window) == 0
            w_hertz = 1.0 / (1.0 + np.exp(-0.5 * m))
            vx, vy, r = np.exp(np.asarray(a.window_other, float))
            other = "Hertz" if keep_gauss else "Gaussian"
            notes.append(
                f"the data cannot tell the contact windows apart (margin {m:+.1f}): vx, vy and a are the average over "
                f"both windows (Akaike weights: Hertz {w_hertz:.2f}, Gaussian {1 - w_hertz:.2f}; the other window's a "
                f"scaled to the same second moment) and their errors include the windows' difference; the "
                f"{'Gaussian' if keep_gauss else 'Hertz'} window's fit is the one shown"
                f"{', as only it describes the spectra' if keep_gauss else ''}; the {other} window alone gives "
                f"|vx| = {100 * vx:.4g}, |vy| = {100 * vy:.4g} cm/s, a = {1e3 * r:.4g} mm")
    note = int(a.texture_note)
    margin = float(a.texture_margin)
    if note == 1:
        notes.append("the directional texture model did not fit")
    elif note == 2:
        notes.append(f"a directional lobe lowers the reduced chi-square only to {float(a.texture_redchi[1]):.2f}: it "
                     "does not describe these spectra")
    elif note == 3:
        notes.append(f"directional texture (AIC margin {margin:.1f} over isotropic): {_lobe(a.texture_lobe)}")
    elif note == 4:
        weight = float(a.texture_weight)
        name = TEXTURES[int(a.texture)]
        other_name = TEXTURES[1 - int(a.texture)]
        kept = np.asarray(a.summary.theta, float)[[*_I_V, INDEX["log_a"]]]
        sd = np.maximum(np.asarray(a.summary.sd, float)[[*_I_V, INDEX["log_a"]]], 1e-300)
        free = np.asarray(a.summary.free, bool)[[*_I_V, INDEX["log_a"]]]
        moved = np.max((1.0 - weight) * np.abs(np.asarray(a.texture_other, float) - kept) / sd * free)
        if moved >= 0.1:        # said where the average moves vx, vy or a by a tenth of its error or more
            notes.append(f"{name} texture by AIC {margin:.1f} only" + (f" ({_lobe(a.texture_lobe)})" if
                                                                         name == "directional" else "")
                         + f": vx, vy, a averaged with the {other_name} fit (weight {1.0 - weight:.2f})")
    direction = DIRECTIONS[int(a.direction)]
    if direction != "oblique":
        q = "vy" if direction == "along x" else "vx"
        if bool(a.direction_forced):
            notes.append(f"slip {direction} (given): {q} held at 0")
        elif np.isfinite(float(a.direction_margin)):
            notes.append(f"slip {direction}: {q} held at 0 (margin {float(a.direction_margin):.1f} over a fitted "
                         f"{q}, in units of its error scale: the data do not need it)")
    if not bool(a.window_needed):
        warnings.append(f"holding a at {1e3 * A_NEGLIGIBLE:.0f} mm changes chi2 by {float(a.window_rise):+.2f}, below "
                        f"the 95 % threshold {float(a.window_threshold):.2f}: the data do not need the contact window")
    return notes, warnings


def _other_result(theta, sd) -> FitResult:
    """vx, vy and a of another model (log values and their errors) as a ``FitResult`` to average with."""
    other = FitResult()
    for q, x, e in zip(("vx", "vy", "a"), np.asarray(theta, float), np.asarray(sd, float)):
        other.set(q, value=float(np.exp(x)), err=float(np.exp(x) * e))
    return other


def result_from_analysis(a: Analysis, *, velocity=None, curvature_radius=None, model: str = "joint", segments=None,
                         file=None, index: int = 0, extras: Callable | None = None, summary: Summary | None = None
                         ) -> FitResult:
    """The ``FitResult`` of one record's ``Analysis`` (numpy): see the module. extras(res, summary): what ``fit``
    adds for one record (profile intervals), run before the models are averaged, as their bounds move with
    the average. summary: the fit to report in place of the kept one (``model="auto"``'s choice)."""
    s = summary_of(a) if summary is None else summary
    window = WINDOWS[int(a.window)]
    res = result_from_summary(s, velocity=velocity, curvature_radius=curvature_radius, model=model,
                              window_weak=not bool(a.window_needed), segments=segments, file=file, index=index)
    notes, warnings = notes_of(a)
    res.window, res.window_margin = window, _window_margin(a)
    res.texture = texture_name(s.free) + (", lumpy" if bool(s.lumpy) else "")
    res.texture_margin = None if not np.isfinite(float(a.texture_margin)) else float(a.texture_margin)
    res.direction = DIRECTIONS[int(a.direction)]
    res.direction_margin = None if not np.isfinite(float(a.direction_margin)) else float(a.direction_margin)
    res.message = "; ".join(m for m in (res.message, *notes) if m)
    res.warnings.extend(warnings)
    if extras is not None:
        extras(res, s)
    if res.status in (Status.NO_BAND, Status.FAILED):
        return res
    if float(a.window_weight) < 1.0:
        average_windows(res, _other_result(a.window_other, a.window_other_sd), float(a.window_weight), window)
    if float(a.texture_weight) < 1.0:
        average_models(res, _other_result(a.texture_other, a.texture_other_sd), float(a.texture_weight))
    return res
