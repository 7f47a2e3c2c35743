"""Nested scene models of the joint fit and an information criterion that picks one per recording.

The models differ only in which entries of the joint model's parameter vector
(``forward.PARAMS``) are free, so they share one compiled solve
(``run.refit`` takes the free mask as data):

    slip           slip velocity and texture; the window is negligible
                   (a -> infinity: a is held at ``A_NEGLIGIBLE`` and reported
                   as a 95 % lower bound, R = exp(-alpha eps), Eq. 5)
    window         + the contact window (a free; Hertz or Gaussian, ``choose_window``): the
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

Whatever ``model`` says, ``fit`` and ``batch`` choose per record, through the
same program: the contact window (``choose_window``), the texture model
(``choose_texture``) and the slip direction (``choose_direction``: a minor
speed the data do not need is held at 0).
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import numpy as np

from ..errors import TactileInputError
from ..model.lines import log_angular
from ..status import FIT_CODES, Status
from .core import HERTZ_PER_GAUSS, POOR_FIT_REDCHI
from .forward import ANISO, PARAMS
from .options import DIRECTIONS
from .result import update_contact_depth

__all__ = [
    "A_NEGLIGIBLE",
    "MODELS",
    "Candidate",
    "Selection",
    "annotate",
    "check_model",
    "information_criterion",
    "model_name",
    "options_for",
    "select",
    "texture_name",
    "choose_texture",
    "choose_window",
    "Choice",
    "average_windows",
    "average_models",
    "WINDOW_DECISIVE",
    "TEXTURES",
    "DIRECTIONS",
    "choose_direction",
    "direction_name",
    "window_needed",
]

MODELS = ("auto", "slip", "window", "window+gain", "window+noise", "window+gain+noise")
#: contact radius (m) standing for "no window": its offset 3 (d2^2 - d1^2) / (2 a^2) is 1e-4 at the paper's depths
A_NEGLIGIBLE = 0.1

_I = {name: i for i, name in enumerate(PARAMS)}
_I_A, _I_GAINS, _I_NOISE = _I["log_a"], (_I["log_gx"], _I["log_gy"]), _I["log_noise"]
#: vx, vy and a: the quantities the window and texture averages move
_I_VVA = [_I["log_vx"], _I["log_vy"], _I_A]
_I_ANISO = tuple(_I[name] for name in ANISO)
#: the texture models of the joint fit (``FitOptions.texture``; None chooses per record)
TEXTURES = ("isotropic", "directional")
#: a minor speed below this fraction of the major one is tested against 0 (``uncertainty.profile.MINOR_PROFILE``)
DIRECTION_TESTED = 0.3
#: a speed held at 0 is held at this fraction of the other (the parameter is log|v|): its effect on the
#: spectra, quadratic in it, is 1e-6 of the major speed's
AXIS_FLOOR = 1e-3
#: a window margin (chi-square in units of the correlated-bin scale) at least this large decides between the windows
WINDOW_DECISIVE = 6.0
#: a poor isotropic fit is explained by a directional lobe when that brings its reduced chi-square this low
DIRECTIONAL_EXPLAINS = 1.5
#: angular coefficients (``forward.ANISO``) that detect a directional lobe: its second harmonic
DETECTING = 2
#: below this AIC margin the texture models are averaged by Akaike weight (the loser's weight above 0.7 %)
TEXTURE_AVERAGED = 10.0
#: ``window_needed`` tests a contact radius measured to worse than this relative error
WINDOW_TEST_REL_ERR = 0.05
#: chi2 rise (in units of the covariance scale) below which a -> infinity is not rejected: one-sided 95 %
_DELTA_95 = 2.71


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


def window_needed(summary, free, refit_chi2) -> tuple[bool, str]:
    """Does the data reject the slip model (a -> infinity)? Tested when a is loosely measured.

    A likelihood-ratio test: when holding a at ``A_NEGLIGIBLE`` (speeds, gains and texture
    refitted; ``refit_chi2(theta, free) -> chi2``) raises chi2 by less than 2.71 x a's variance
    scale, the data cannot tell the window from none at 95 %, and a fitted radius would be a
    number fitted into noise. Returns (needed, note). The caller keeps the window fit for the
    speeds (its errors include a's uncertainty) and reports a as a lower bound when not needed.
    """
    free = np.asarray(free, bool)
    if not free[_I_A]:
        return True, ""
    sd = np.asarray(summary.sd)
    if sd[_I_A] < WINDOW_TEST_REL_ERR:
        return True, ""
    scale = float(np.asarray(summary.scales)[_I_A])
    th, fr = _slip_mask_theta(summary.theta, free)
    chi2 = refit_chi2(th, fr)
    if not np.isfinite(chi2):
        return True, ""
    rise = chi2 - float(summary.chi2)
    if rise >= _DELTA_95 * scale:
        return True, ""
    return False, (f"holding a at {1e3 * A_NEGLIGIBLE:.0f} mm changes chi2 by {rise:+.2f}, below the 95 % threshold "
                   f"{_DELTA_95 * scale:.2f}: the data do not need the contact window")


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


#: ``Summary.status`` codes of fits that ran and gave values: the ones a choice of model compares
_RAN = tuple(FIT_CODES.index(s) for s in (Status.OK, Status.NOT_CONVERGED, Status.POOR_FIT))


def _compared(summary) -> bool:
    """Whether a fit gave values to compare (not no band, not failed)."""
    return int(summary.status) in _RAN


def texture_name(free) -> str:
    """The texture model a free mask fits: "directional" where the angular factor is free."""
    return "directional" if np.asarray(free, bool)[list(_I_ANISO)].any() else "isotropic"


def lobe_of(coef) -> tuple[float, float]:
    """(direction of most power, deg in [0, 180); its power over the least's) of the angular factor with
    coefficients ``coef`` (p, q, p4, q4) (``model.lines.log_angular``), on a 0.25 deg grid."""
    theta = np.radians(np.arange(0.0, 180.0, 0.25))
    log_a = np.asarray(log_angular(np.cos(2 * theta), np.sin(2 * theta), np.asarray(coef, float))[0])
    return float(np.degrees(theta[np.argmax(log_a)])), float(np.exp(np.ptp(log_a)))


def _akaike_weight(margin: float) -> float:
    """The Akaike weight of the one of two models ahead by ``margin`` (AIC or chi-square units)."""
    return 1.0 / (1.0 + np.exp(-0.5 * margin))


class Choice(NamedTuple):
    """A model choice for one record (``choose_window``, ``choose_texture``): the kept summary, the kept
    model's name, the margin (``choose_window``: chi-square units, positive favours the Hertz disk;
    ``choose_texture``: AIC, the loser's minus the winner's; None where not compared) and the note; where the
    data barely tell the models apart, the other model's summary and the kept model's Akaike weight (for
    ``average_models``; else None and 1)."""

    summary: Any
    name: str
    margin: float | None
    note: str
    other: Any = None
    weight: float = 1.0


def choose_texture(summary, refit, *, bin_factor: float = 1.0) -> Choice:
    """The texture model of one record: the isotropic fit ``summary`` against the directional one.

    refit(theta, free) -> ``core.Summary``: the same compiled program from ``theta`` over ``free``.
    The lobe is detected with its second harmonic (``DETECTING`` coefficients, freed from the isotropic
    optimum) and, where that is decisive, estimated with all four (freed from the second's optimum):
    the fourth harmonic is second order in the anisotropy, so a lobe too weak to detect decisively has
    none worth fitting, while a decisive lobe's shape moves the minor speed (``docs/model.md``). The
    lobe is kept where it lowers ``information_criterion`` (the quasi-likelihood scale is the
    directional fit's reduced chi-square, so that a misfit it does not remove is not read as
    evidence), and only if it describes the spectra (reduced chi-square at most
    ``DIRECTIONAL_EXPLAINS``): a lumpy spectrum of few discrete modes is not a directional texture, and
    more parameters fitted to its lumps would turn a poor fit into a confident one. Where the margin
    is below ``TEXTURE_AVERAGED`` the result averages the isotropic and second-harmonic fits by their
    Akaike weights (``average_models``): a weak lobe that AIC does not keep still moves the minor speed
    by about its error.
    """
    if not _compared(summary):
        return Choice(summary, "isotropic", None, "")
    free = np.asarray(summary.free, bool)

    def with_lobe(n_coef):
        """``free`` with the angular factor's first ``n_coef`` coefficients freed."""
        out = free.copy()
        out[list(_I_ANISO[:n_coef])] = True
        return out

    fr = with_lobe(DETECTING)
    directional = refit(np.asarray(summary.theta), fr)
    n_data = float(summary.n_data)
    if not np.isfinite(float(directional.chi2)):
        return Choice(summary, "isotropic", None, "the directional texture model did not fit")
    scale = float(directional.chi2) / max(n_data - fr.sum(), 1.0)
    ic_iso = information_criterion(float(summary.chi2), free.sum(), n_data, bin_factor=bin_factor, scale=scale,
                                    kind="aic")
    ic_dir = information_criterion(float(directional.chi2), fr.sum(), n_data, bin_factor=bin_factor, scale=scale,
                                    kind="aic")
    if float(directional.redchi) > DIRECTIONAL_EXPLAINS:
        poor = float(summary.redchi) > POOR_FIT_REDCHI and float(directional.redchi) < float(summary.redchi)
        note = (f"a directional lobe lowers the reduced chi-square only to {float(directional.redchi):.2f}: it "
                "does not describe these spectra" if poor else "")
        return Choice(summary, "isotropic", None, note)
    kept, other, name, margin = ((directional, summary, "directional", ic_iso - ic_dir) if ic_dir < ic_iso else
                                 (summary, directional, "isotropic", ic_dir - ic_iso))

    def lobe(fit):
        along, anisotropy = lobe_of(np.asarray(fit.theta, float)[list(_I_ANISO)])
        return f"power along {along:.0f} deg, anisotropy {anisotropy:.2f}"

    if margin >= TEXTURE_AVERAGED:
        if name == "isotropic":
            return Choice(kept, name, margin, "")
        shaped = refit(np.asarray(directional.theta), with_lobe(len(_I_ANISO)))
        if np.isfinite(float(shaped.chi2)) and float(shaped.chi2) <= float(directional.chi2) + 1e-6 * n_data:
            kept = shaped
        return Choice(kept, name, margin, f"directional texture (AIC margin {margin:.1f} over isotropic): {lobe(kept)}")
    weight = _akaike_weight(margin)
    other_name = "isotropic" if name == "directional" else "directional"
    # said where the average moves vx, vy or a by a tenth of its error or more (the row holds the margin always)
    i = _I_VVA
    shift = np.abs(np.asarray(other.theta, float)[i] - np.asarray(kept.theta, float)[i])
    moved = np.max((1.0 - weight) * shift / np.maximum(np.asarray(kept.sd, float)[i], 1e-300)
                   * np.asarray(kept.free, bool)[i])
    note = (f"{name} texture by AIC {margin:.1f} only" + (f" ({lobe(directional)})" if name == "directional" else "")
            + f": vx, vy, a averaged with the {other_name} fit (weight {1.0 - weight:.2f})") if moved >= 0.1 else ""
    return Choice(kept, name, margin, note, other, float(weight))


def direction_name(free) -> str:
    """The slip direction a free mask fits: "along x" where vy is held (and vx free), "along y" where vx is."""
    free = np.asarray(free, bool)
    vx, vy = free[_I["log_vx"]], free[_I["log_vy"]]
    if vx == vy:
        return "oblique"
    return "along x" if vx else "along y"


def choose_direction(summary, refit, forced: str | None = None):
    """The slip direction of one record: both speeds free ("oblique"), or along an axis (the minor one held at 0).

    refit(theta, free) -> ``core.Summary``: the same compiled program from ``theta`` over ``free``.
    Tested where both speeds are free and the minor one is below ``DIRECTION_TESTED`` of the major: the
    refit holds it at ``AXIS_FLOOR`` of the major (0 to the spectra), the other parameters started at
    the oblique optimum. Akaike's criterion in units of the minor speed's own error scale (its
    jackknife variance ratio, the unit of its profile intervals): the axis model is kept where holding
    the speed raises chi-square by at most 2 of that scale, i.e. where the speed is within 1.4 sigma of
    0 and a fitted value would be noise. The profile gives the held speed its 95 % upper bound.
    forced: a direction the user gives (``FitOptions.direction``): "oblique" keeps both speeds,
    "along x" / "along y" holds vy / vx at 0 whatever the data say (no margin).
    Returns (summary, name, margin in AIC units (the loser's minus the winner's; None where not
    tested), note).
    """
    free = np.asarray(summary.free, bool)
    iv = [_I["log_vx"], _I["log_vy"]]
    if forced == "oblique" or not _compared(summary) or not free[iv].all():
        return summary, direction_name(free), None, ""
    theta = np.asarray(summary.theta)
    minor = int(np.argmin(theta[iv])) if forced is None else int(forced == "along x")
    i, major = iv[minor], iv[1 - minor]
    if forced is None and theta[i] - theta[major] >= np.log(DIRECTION_TESTED):
        return summary, "oblique", None, ""
    th, fr = theta.copy(), free.copy()
    th[i], fr[i] = theta[major] + np.log(AXIS_FLOOR), False
    name, q = direction_name(fr), "vy" if minor == 1 else "vx"
    axis = refit(th, fr)
    if forced is not None:
        return axis, forced, None, f"slip {forced} (given): {q} held at 0"
    if not _compared(axis) or not np.isfinite(float(axis.chi2)):
        return summary, "oblique", None, ""
    scale = max(float(np.asarray(summary.scales)[i]), 1e-12)
    margin = 2.0 - (float(axis.chi2) - float(summary.chi2)) / scale      # AIC(oblique) - AIC(axis)
    if margin >= 0.0:
        return axis, name, margin, (f"slip {name}: {q} held at 0 (AIC margin {margin:.1f} over a fitted {q}, "
                                    f"in units of its error scale: the data do not need it)")
    return summary, "oblique", -margin, ""


def choose_window(summary, refit_gaussian, *, bin_factor: float = 1.0) -> Choice:
    """The contact window of one record: the Hertz fit ``summary`` against the Gaussian window.

    refit_gaussian(theta, free) -> ``core.Summary``: the Gaussian window's program from ``theta``. It
    starts from the Hertz optimum with the radius scaled to the Gaussian window of the same second
    moment. Both models have the same parameters, so the criterion is the chi-square difference in
    units of the correlated-bin scale (the bin factor times the better fit's reduced chi-square, at
    least 1, as the noise scale of an F test is the better model's): positive favours Hertz. Below
    ``WINDOW_DECISIVE`` the data cannot tell the windows apart: the summary kept is the Hertz fit (a
    fingertip's contact is a Hertz disk), unless only the Gaussian window describes the spectra (reduced
    chi-square below ``POOR_FIT_REDCHI``), and the result averages the two windows' estimates
    (``average_windows``) by their Akaike weights, exp(-margin / 2) relative.
    """
    if not _compared(summary):
        return Choice(summary, "hertz", None, "")
    theta = np.asarray(summary.theta).copy()
    theta[_I_A] -= np.log(HERTZ_PER_GAUSS)
    gauss = refit_gaussian(theta, np.asarray(summary.free, bool))
    chi_h, chi_g = float(summary.chi2), float(gauss.chi2)
    if not np.isfinite(chi_g):
        return Choice(summary, "hertz", None, "the Gaussian window did not fit")
    scale = max(float(bin_factor), 1.0) * max(min(float(summary.redchi), float(gauss.redchi)), 1.0)
    margin = (chi_g - chi_h) / scale
    if margin >= WINDOW_DECISIVE:
        return Choice(summary, "hertz", margin, "")
    if margin <= -WINDOW_DECISIVE:
        return Choice(gauss, "gaussian", -margin, f"Gaussian contact window (chi-square margin {-margin:.1f} "
                                                  "over the Hertz disk)")
    keep_gauss = float(summary.redchi) > POOR_FIT_REDCHI >= float(gauss.redchi)
    kept, other, name = (gauss, summary, "Hertz") if keep_gauss else (summary, gauss, "Gaussian")
    w_hertz = _akaike_weight(margin)
    vx, vy, a = np.exp(np.asarray(other.theta)[_I_VVA])
    note = (f"the data cannot tell the contact windows apart (margin {margin:+.1f}): vx, vy and a are the "
            f"average over both windows (Akaike weights: Hertz {w_hertz:.2f}, Gaussian {1 - w_hertz:.2f}; the other "
            f"window's a scaled to the same second moment) and their errors include the windows' difference; the "
            f"{'Gaussian' if keep_gauss else 'Hertz'} window's fit is the one shown"
            f"{', as only it describes the spectra' if keep_gauss else ''}; the {name} window alone gives "
            f"|vx| = {100 * vx:.4g}, |vy| = {100 * vy:.4g} cm/s, a = {1e3 * a:.4g} mm")
    return Choice(kept, "gaussian" if keep_gauss else "hertz", margin, note, other,
                  float(1.0 - w_hertz if keep_gauss else w_hertz))


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
