"""Nested scene models of the joint fit and an information criterion that picks one per recording.

The models differ only in which entries of the joint model's parameter vector
(``forward.PARAMS``) are free, so they share one compiled solve
(``run.refit_analysis`` takes the free mask as data):

    slip           slip velocity and texture; the window is negligible
                   (a -> infinity: a is held at ``A_NEGLIGIBLE`` and reported
                   as a 95 % lower bound, R = exp(-alpha eps), Eq. 5)
    window         + the contact window (a free; Hertz or Gaussian, chosen per record): the
                   default (model None adds gains / noise floor as FitOptions.fit_gain /
                   noise_floor say)
    window+gain    + unknown deep/shallow gain ratios of both pairs
    window+noise   + a white noise floor on the shallow probes
    window+gain+noise
A velocity known from the arm (paper section 4.3, ``FitOptions.velocity``)
is held fixed in every model and the name gets ``+v_known``.

``model="auto"`` fits the nested candidates around the base fit, each started
from it, and keeps the lowest BIC with the correlated-bin correction

    BIC = chi2 / (b c) + k ln(n / b)

(b: the spectra's ``bin_factor``, adjacent bins are not independent; c: the
reduced chi-square of the largest candidate, at least 1, a quasi-likelihood
scale so that misfit is not read as evidence; k free parameters, n bins).
The margin is the BIC of the runner-up minus the chosen one's.

Whatever ``model`` says, ``fit`` and ``batch`` choose per record inside the
analysis program (``inference.analysis``): the contact window, the texture
model and the slip direction (a minor speed the data do not need is held at 0),
each with its margin; models the data barely tell apart are averaged here
(``average_models``).
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import numpy as np

from ..errors import TactileInputError
from ..model.lines import log_angular
from .analysis import (A_NEGLIGIBLE, AXIS_FLOOR, DETECTING, DIRECTION_TESTED, DIRECTIONAL_EXPLAINS, DIRECTIONS,
                       TEXTURE_AVERAGED, TEXTURES, WINDOW_DECISIVE, WINDOW_TEST_REL_ERR)
from .core import HERTZ_PER_GAUSS
from .forward import ANISO, PARAMS
from .result import update_contact_depth

__all__ = [
    "A_NEGLIGIBLE", "AXIS_FLOOR", "DETECTING", "DIRECTION_TESTED", "DIRECTIONAL_EXPLAINS", "DIRECTIONS", "MODELS",
    "TEXTURE_AVERAGED", "TEXTURES", "WINDOW_DECISIVE", "WINDOW_TEST_REL_ERR", "Candidate", "Selection", "annotate",
    "check_model", "information_criterion", "model_name", "options_for", "select", "texture_name", "lobe_of",
    "average_windows", "average_models",
]

MODELS = ("auto", "slip", "window", "window+gain", "window+noise", "window+gain+noise")

_I = {name: i for i, name in enumerate(PARAMS)}
_I_A, _I_GAINS, _I_NOISE = _I["log_a"], (_I["log_gx"], _I["log_gy"]), _I["log_noise"]
_I_ANISO = tuple(_I[name] for name in ANISO)


class Candidate(NamedTuple):
    """One fitted model: name, its refit (None: the base fit), free mask (P,) and criterion value."""

    name: str
    fit: Any
    free: np.ndarray
    bic: float


class Selection(NamedTuple):
    """The chosen model: its fit and free mask, the margin (BIC units, None if forced) and the others."""

    name: str
    fit: Any
    free: np.ndarray
    margin: float | None
    candidates: tuple
    note: str


def check_model(name: str | None, source: str | None = None) -> str | None:
    """The model name (None: from the options' flags), or a one-line ``TactileInputError`` naming the choices."""
    if name is not None and name not in MODELS:
        raise TactileInputError(f"unknown model {name!r}; expected one of {', '.join(MODELS)}", source=source,
                                code="bad_setting")
    return name


def options_for(options):
    """``FitOptions`` with the flags a named model needs (fit_gain, noise_floor); None, auto and hertz unchanged."""
    name = check_model(options.model)
    if name in (None, "auto"):
        return options
    return dataclasses.replace(options, fit_gain="gain" in name, noise_floor="noise" in name)


def model_name(free, velocity_known: bool) -> str:
    """Name of the model a free mask (joint-model order) fits."""
    free = np.asarray(free, bool)
    name = "window" if free[_I_A] else "slip"
    if free[list(_I_GAINS)].any():
        name += "+gain"
    if free[_I_NOISE]:
        name += "+noise"
    return name + ("+v_known" if velocity_known else "")


def information_criterion(chi2, n_free, n_data, *, bin_factor=1.0, scale=1.0, kind: str = "bic") -> float:
    """BIC (or AIC) of a least-squares fit with correlated bins: chi2 / (b c) + k ln(n / b) (or 2 k)."""
    b = max(float(bin_factor), 1.0)
    c = max(float(scale), 1.0)
    penalty = np.log(max(float(n_data) / b, 2.0)) if kind == "bic" else 2.0
    return float(chi2) / (b * c) + penalty * int(n_free)


def _slip_mask_theta(theta, free):
    th = np.asarray(theta).copy()
    fr = np.asarray(free).copy()
    th[_I_A] = np.log(A_NEGLIGIBLE)
    fr[_I_A] = False
    return th, fr


def select(summary, free, refit, options, *, bin_factor: float = 1.0) -> Selection:
    """Apply ``options.model`` ("slip" or "auto") to the base fit ``summary`` (``inference.core.Summary``).

    refit(theta, free) -> (fit, chi2): the joint solve from ``theta`` over ``free`` (``fit.theta``
    its parameters). "slip" refits with a held at ``A_NEGLIGIBLE``; "auto" fits slip, +gain and
    +noise around the base (each from its optimum) and keeps the lowest ``information_criterion``.
    """
    free = np.asarray(free, bool)
    known = options.velocity is not None
    theta = np.asarray(summary.theta)
    if options.model == "slip":
        th, fr = _slip_mask_theta(theta, free)
        fit, _ = refit(th, fr)
        return Selection(model_name(fr, known), fit, fr, None, (), "")
    n_data = float(summary.n_data)
    fits = [(free, None, float(summary.chi2))]
    th, fr = _slip_mask_theta(theta, free)
    fits.append((fr, *refit(th, fr)))
    if not free[list(_I_GAINS)].all():
        fr = free.copy()
        fr[list(_I_GAINS)] = True
        fits.append((fr, *refit(theta, fr)))
    if not free[_I_NOISE]:
        fr = free.copy()
        fr[_I_NOISE] = True
        th = theta.copy()
        th[_I_NOISE] = float(np.max(np.asarray(summary.data.log_noise)[:, 0]))
        fits.append((fr, *refit(th, fr)))
    fits = [(fr, f, c) for fr, f, c in fits if np.isfinite(c)]
    largest = max(fits, key=lambda t: int(t[0].sum()))
    scale = largest[2] / max(n_data - largest[0].sum(), 1.0)
    cands = sorted((Candidate(model_name(fr, known), f, fr,
                              information_criterion(c, fr.sum(), n_data, bin_factor=bin_factor, scale=scale))
                    for fr, f, c in fits), key=lambda c: c.bic)
    best = cands[0]
    margin = float(cands[1].bic - best.bic) if len(cands) > 1 else None
    note = (f"model {best.name} chosen by BIC (margin {margin:.1f} over {cands[1].name}; "
            + ", ".join(f"{c.name} {c.bic - best.bic:+.1f}" for c in cands[1:]) + ")") if margin is not None else ""
    return Selection(best.name, best.fit, best.free, margin, tuple(cands), note)


def annotate(res) -> None:
    """Say so where a reported value's error bar exceeds the value itself (and nothing said it yet)."""
    said = res.message or ""
    extra = []
    for name in ("vx", "vy", "a", "gain_ratio", "gain_ratio_y"):
        v, e = getattr(res, name, None), getattr(res, name + "_err", None)
        if v is None or e is None or not np.isfinite(e):
            continue
        if e > abs(v) and f"{name} is" not in said:
            extra.append(f"{name} is not determined: its error bar ({e:.3g}) exceeds its value ({v:.3g})")
    if extra:
        res.message = "; ".join([m for m in [said] if m] + extra)


def texture_name(free) -> str:
    """The texture model a free mask fits: "directional" where the angular factor is free."""
    return "directional" if np.asarray(free, bool)[list(_I_ANISO)].any() else "isotropic"


def lobe_of(coef) -> tuple[float, float]:
    """(direction of most power, deg in [0, 180); its power over the least's) of the angular factor with
    coefficients ``coef`` (p, q, p4, q4) (``model.lines.log_angular``), on a 0.25 deg grid."""
    theta = np.radians(np.arange(0.0, 180.0, 0.25))
    log_a = np.asarray(log_angular(np.cos(2 * theta), np.sin(2 * theta), np.asarray(coef, float))[0])
    return float(np.degrees(theta[np.argmax(log_a)])), float(np.exp(np.ptp(log_a)))


def average_windows(res, other, weight: float, window: str) -> None:
    """Where the data cannot tell the contact windows apart: ``average_models`` of ``res`` (a ``FitResult`` of
    ``window``, of Akaike weight ``weight``) and ``other`` (the other window's), the other window's radius
    entering as ``window``'s radius of the same second moment (``HERTZ_PER_GAUSS``)."""
    average_models(res, other, weight, a_factor=HERTZ_PER_GAUSS if window == "hertz" else 1.0 / HERTZ_PER_GAUSS)


def average_models(res, other, weight: float, *, a_factor: float = 1.0) -> None:
    """``res``'s vx, vy and a become the average with ``other``'s (another model's ``FitResult``) by the Akaike
    weight ``weight`` of ``res``'s model, each error sqrt(sum_i w_i (err_i^2 + (v_i - mean)^2)) (model
    averaging), and a minor speed's interval and bounds are widened to hold the other model's value shifted
    alike. ``other``'s a enters times ``a_factor``; the contact depth follows a. A fixed quantity (a known
    speed, or one the slip direction holds at 0) stays."""
    for q in ("vx", "vy", "a"):
        mine, theirs = res[q], other[q]
        if mine.value is None or theirs.value is None or mine.fixed:     # a held or known speed stays
            continue
        f = a_factor if q == "a" else 1.0
        v0, e0 = mine.value, mine.err or 0.0
        v1, e1 = theirs.value * f, (theirs.err or 0.0) * f
        mean = weight * v0 + (1.0 - weight) * v1
        var = weight * (e0 ** 2 + (v0 - mean) ** 2) + (1.0 - weight) * (e1 ** 2 + (v1 - mean) ** 2)
        fields = {"value": float(mean), "err": None if mine.err is None else float(np.sqrt(var))}
        shift = v1 - v0
        for b in ("lo", "lo2"):
            if getattr(mine, b) is not None:
                fields[b] = max(0.0, min(getattr(mine, b), getattr(mine, b) + shift))
        for b in ("hi", "hi2", "upper"):
            if getattr(mine, b) is not None:
                fields[b] = max(getattr(mine, b), getattr(mine, b) + shift)
        res.set(q, **fields)
    update_contact_depth(res)
