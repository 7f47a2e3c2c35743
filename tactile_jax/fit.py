"""Joint estimation of slip velocity, contact radius, gains and texture spectrum, with error bars.

``fit_recording`` (probe signals) and ``fit_spectra`` (recorded spectra) run the
compiled joint pipeline of ``joint`` on one record: grouped periodograms on a
fixed grid (``joint.segments``), the usable band and closed-form starts, the 2-D
joint model of both pairs and their cross-pair chain fitted by fixed-iteration
Levenberg-Marquardt from several starts, Laplace errors scaled by the
delete-one-group jackknife. ``batch`` runs the same program on chunks. On top,
for one record: more iterations where the fit has not settled, profile-likelihood
bounds for what the data cannot determine (a speed consistent with 0, a contact
window too weak to measure, a minor speed component), model selection, texture
cross-sections (Eq. 18-19) and the problem emcee samples. ``result_from_summary``
turns the pipeline's arrays into a ``FitResult``; fit and batch rows both come from it.
Nothing here raises on a fit that fails: the result's ``status`` and ``message``
say why (bad input raises ``TactileInputError``; ``batch`` turns it into a row).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple

import jax
import numpy as np

from . import model_select
from .errors import TactileInputError
from .joint import run
from .joint.core import STATUS, STEP_TOL, Record, Settings, Summary
from .joint.diagnose import no_band_reason
from .joint.model import N_PHYS, param_names
from .joint.residuals import residuals as joint_residuals
from .pair_fit import fit_pair
from .problem import FitProblem
from .recording import Recording, validate_recording
from .sensor import PAPER_SENSOR

__all__ = ["FitOptions", "FitResult", "TextureSection", "fit_recording", "fit_spectra", "fit_record",
           "result_from_summary", "settle", "settings_of", "model_curves", "RESULT_FIELDS"]

#: the data contract's result fields, in order (DESIGN.md); more follow in ``FitResult.to_record``
RESULT_FIELDS = ("file", "index", "vx", "vx_err", "vy", "vy_err", "a", "a_err", "contact_depth",
                 "contact_depth_err", "gain_ratio", "gain_ratio_err", "k0x", "k0y", "model", "window",
                 "converged", "status", "message")

_A_BOUNDS = (1e-5, 0.1)
_V_BOUNDS = (1e-6, 10.0)         # m/s
#: a speed component below this fraction of the other gets a profile-likelihood interval (``FitResult.vx_lo``)
MINOR_PROFILE = 0.3
#: the parameters with their own error scale (theta[:3]); every later one has the pooled scale
OWN_SCALE_PARAMS = ("vx", "vy", "a")
#: more solves (``joint.core.ITERATIONS[2]`` iterations each) for a fit that has not settled
_MORE_SOLVES = 3


@dataclasses.dataclass(frozen=True)
class FitOptions:
    """How to fit a scene (SI units). Defaults suit the paper's sensor at 1 kHz.

    method, prewhiten, nperseg: spectral estimator (``joint.segments.segments``): "welch"
        (Hann, half overlap; ``nperseg`` samples, at least ``joint.segments.min_nperseg()`` = 14,
        checked with the recording's name where the segments are made; default the largest power
        of two <= N / 8, lengthened for slow slips) or "multitaper"; the order of the Burg AR prewhitening
        filter (0 or None: off).
    velocity: known (|vx|, |vy|) in m/s (the arm's command, paper section 4.3): held fixed.
    gain_ratio: known deep/shallow gain ratios (gx, gy) or one for both; None: the
        file's ``gain_ratio`` if any, else 1. ``fit_gain``: fit them instead.
    noise_floor: fit a white noise floor on the shallow probes.
    smoothness: the prior sd of the log texture spectrum's second differences between its knots.
    min_snr, max_err, fmin, fmax: usable-band selection (``joint.band.select``; Hz).
    leakage_db: a bin whose shallow PSD lies this far below the highest within +/- 3 bins holds
        only spectral leakage (between the lines of a line texture) and is dropped.
    conditioned: fit each pair's conditioned deep PSD S22.1 = S22 - |S12|^2 / S11 too: the deep
        power the shallow probe does not explain, which 2-D slip through a small contact sets.
    cross_pairs: the y pair conditioned on the x pair (``cross_pair``): None (default) 2 where
        the data have the x-y cross-spectra (recordings, files from ``tactile-jax spectra``), else 0;
        0 off, 1 y1 given (x1, x2) in place of y1's PSD, 2 also y2 given (x1, x2, y1) in place of
        the y pair's ratio and S22.1.
    profile_minor: give a speed component below ``MINOR_PROFILE`` of the other a
        profile-likelihood interval (``FitResult.vx_lo`` ...).
    window: "gaussian" (the joint model's window).
    model: the scene model (``model_select.MODELS``): None (default: slip and contact window,
        plus gains / noise floor as ``fit_gain`` / ``noise_floor`` say; a window the data do
        not need is reported as a lower bound on a), "slip" (window negligible), "window",
        "window+gain", "window+noise", "window+gain+noise" (these set the two flags), "hertz"
        (each pair with the Hertz curve) or "auto" (chosen per recording by BIC; the choice
        and margin are in the result).
    solver: "optimistix" (Levenberg-Marquardt) or "jaxopt", for ratio-only spectra and the
        Hertz model, which fit each pair alone.
    """

    method: str = "welch"
    prewhiten: int | None = 8
    nperseg: int | None = None
    velocity: tuple[float, float] | None = None
    gain_ratio: Any = None
    fit_gain: bool = False
    noise_floor: bool = False
    smoothness: float = 1.0
    min_snr: float = 1.0
    max_err: float = 0.5
    fmin: float | None = None
    fmax: float | None = None
    leakage_db: float = 20.0
    conditioned: bool = True
    cross_pairs: int | None = None
    profile_minor: bool = True
    window: str = "gaussian"
    model: str | None = None
    solver: str = "optimistix"


def settings_of(options: FitOptions, *, has_xy: bool = True) -> Settings:
    """The pipeline's ``Settings`` (data, not a new program) for ``options``."""
    chain = (2 if has_xy else 0) if options.cross_pairs is None else int(options.cross_pairs)
    return Settings(min_snr=float(options.min_snr), max_err=float(options.max_err),
                    fmin=-np.inf if options.fmin is None else float(options.fmin),
                    fmax=np.inf if options.fmax is None else float(options.fmax),
                    leakage_db=float(options.leakage_db), smoothness=float(options.smoothness),
                    noise_floor=bool(options.noise_floor), fit_gain=bool(options.fit_gain),
                    conditioned=bool(options.conditioned), chain=chain if has_xy else 0)


class TextureSection(NamedTuple):
    """A texture cross-section (Eq. 18 / 19): power spectrum along one axis.

    k: (n,) spatial frequencies, rad/m. power: (n,) texture POWER spectral
    density there (signal units^2 per rad/m, relative). log_power_err: (n,)
    one-sigma error of log(power) (spectral noise and the v, a uncertainty).
    """

    k: np.ndarray
    power: np.ndarray
    log_power_err: np.ndarray


@dataclasses.dataclass
class FitResult:
    """Everything a fit found, with error bars, and why not where it could not.

    Speeds in m/s, lengths in m. ``None`` means not determined (see ``message``).
    ``a_lower`` is a 95 % lower bound on the contact radius when the window is
    too weak to measure it; ``vx_upper``/``vy_upper`` 95 % upper bounds when a
    component is consistent with zero. ``vx_lo``/``vx_hi`` (and ``vx_lo2``/``vx_hi2``)
    the 1- (2-) sigma profile-likelihood interval of a minor speed component
    (below ``MINOR_PROFILE`` of the major one), where the spectra depend on it
    only quadratically and the Laplace error is too symmetric and too narrow
    (likewise for vy). ``error_scales``: the variance scale of the Laplace
    covariance behind the error bars of vx, vy and a (each its own jackknife ratio),
    ``error_scale`` that of every other parameter's (the three pooled; the MCMC's
    likelihood temperature), ``error_method`` how they were found, ``jackknife``
    their diagnostics (segments, per-parameter variance ratios).
    ``cross_pairs``: how many blocks of the y pair's chain on the x pair the fit used
    (``FitOptions.cross_pairs``; 0 where the spectra have no x-y entries). ``converged``: the
    last solve's Gauss-Newton decrement is negligible, or a full Gauss-Newton step would move every
    physical parameter by less than ``joint.core.STEP_TOL`` sigma (the message then says that texture
    knots were still moving); a fit that has not settled gets up to 3 more solves of the same program.
    """

    vx: float | None = None
    vx_err: float | None = None
    vy: float | None = None
    vy_err: float | None = None
    a: float | None = None
    a_err: float | None = None
    a_lower: float | None = None
    vx_upper: float | None = None
    vy_upper: float | None = None
    vx_lo: float | None = None
    vx_hi: float | None = None
    vx_lo2: float | None = None
    vx_hi2: float | None = None
    vy_lo: float | None = None
    vy_hi: float | None = None
    vy_lo2: float | None = None
    vy_hi2: float | None = None
    contact_depth: float | None = None
    contact_depth_err: float | None = None
    gain_ratio: float | None = None
    gain_ratio_err: float | None = None
    gain_ratio_y: float | None = None
    gain_ratio_y_err: float | None = None
    k0x: float | None = None
    k0y: float | None = None
    model: str = "joint-2d"
    window: str = "gaussian"
    converged: bool = False
    model_margin: float | None = None
    status: str = "ok"
    message: str = ""
    file: str | None = None
    index: int = 0
    redchi: float | None = None
    chi2: float | None = None
    n_bins: int = 0
    n_residuals: int = 0
    n_params: int = 0
    cond: float | None = None
    aic: float | None = None
    bic: float | None = None
    solver: str = "optimistix"
    precision: str = "float64"
    names: tuple = ()
    error_scale: float | None = None
    error_scales: dict = dataclasses.field(default_factory=dict)
    error_method: str = ""
    cross_pairs: int = 0
    jackknife: dict | None = dataclasses.field(default=None, repr=False)
    correlations: np.ndarray | None = None
    texture_x: TextureSection | None = None
    texture_y: TextureSection | None = None
    curvature_radius: float | None = None
    spectrum: dict | None = dataclasses.field(default=None, repr=False)
    truth: dict = dataclasses.field(default_factory=dict)
    warnings: list = dataclasses.field(default_factory=list)
    problem: FitProblem | None = dataclasses.field(default=None, repr=False)
    data: Any = dataclasses.field(default=None, repr=False)
    summary: Any = dataclasses.field(default=None, repr=False)
    posterior: Any = dataclasses.field(default=None, repr=False)

    def to_record(self) -> dict:
        """One flat row of the data contract (JSON/CSV ready: floats, bools, str, None)."""
        row = {name: _plain(getattr(self, name)) for name in RESULT_FIELDS}
        for extra in ("a_lower", "vx_upper", "vy_upper", "vx_lo", "vx_hi", "vx_lo2", "vx_hi2", "vy_lo", "vy_hi",
                      "vy_lo2", "vy_hi2", "gain_ratio_y", "gain_ratio_y_err", "redchi", "n_bins",
                      "cond", "aic", "bic", "solver", "precision", "model_margin", "error_scale", "error_method",
                      "cross_pairs"):
            row[extra] = _plain(getattr(self, extra))
        if self.posterior is not None:
            row.update(self.posterior_record())
        return row

    def posterior_record(self) -> dict:
        post = self.posterior
        out = {"mcmc_acceptance": float(post.acceptance_fraction), "mcmc_ess": float(post.ess),
               "mcmc_tau_max": float(np.nanmax(post.tau)) if np.size(post.tau) else None,
               "mcmc_warnings": "; ".join(post.warnings)}
        for name, s in post.summary().items():
            out[f"{name}_post_mean"] = float(s["mean"])
            out[f"{name}_post_sd"] = float(s["sd"])
        return out


def _plain(v):
    if isinstance(v, (np.floating, np.integer)):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def _options_from_file(options: FitOptions, rec) -> FitOptions:
    if options.velocity is None and rec.velocity is not None:
        options = dataclasses.replace(options, velocity=tuple(abs(float(v)) for v in rec.velocity))
    if options.gain_ratio is None and rec.gain_ratio is not None:
        options = dataclasses.replace(options, gain_ratio=rec.gain_ratio)
    return options


def _fit_ratio_only(data, options: FitOptions) -> FitResult:
    """Ratios without PSDs: each pair's exact R curve on its own (the fast path)."""
    d1, d2 = data.depths
    omega = np.asarray(data.omega, float)
    log_ratio = np.log(np.asarray(data.ratio, float))
    err = np.asarray(data.ratio_err, float) if data.ratio_err is not None else np.full_like(log_ratio, 0.1)
    res = FitResult(model="pair", file=data.source, solver=options.solver)
    gains = _gains(options)
    fits = []
    if data.ratio_err is None:
        res.warnings.append("no ratio_err given: every finite bin is used with a guessed error of 0.1, "
                            "rescaled by the reduced chi-square")
    for p in range(2):
        mask = np.isfinite(log_ratio[p]) & np.isfinite(err[p]) & (omega > 0) & (err[p] <= options.max_err)
        if mask.sum() < 4:
            fits.append(None)
            continue
        fits.append(fit_pair(omega, log_ratio[p], err[p], mask, d1, d2, gain_ratio=gains[p], fit_gain=options.fit_gain,
                             bin_factor=data.bin_factor or 1.0, kernel=_file_kernel(data),
                             solver=options.solver, speed0=None if options.velocity is None else max(options.velocity[p], 1e-4)))
    if all(f is None for f in fits):
        res.status, res.message = "no_band", "fewer than 4 finite ratio bins in either pair"
        return res
    fx, fy = fits
    if fx is not None:
        res.vx, res.vx_err = fx.speed, fx.speed_err
    if fy is not None:
        res.vy, res.vy_err = fy.speed, fy.speed_err
    best = min((f for f in fits if f is not None), key=lambda f: f.a_err / f.a if f.a > 0 else np.inf)
    res.a, res.a_err = best.a, best.a_err
    res.converged = all(f.converged for f in fits if f is not None)
    if not res.converged:
        res.status = "not_converged"
    res.redchi = float(np.mean([f.redchi for f in fits if f is not None]))
    res.n_bins = int(sum(f.n_bins for f in fits if f is not None))
    res.n_residuals = res.n_bins                      # one log ratio per bin
    res.gain_ratio = fx.gain_ratio if fx is not None else gains[0]
    res.gain_ratio_err = fx.gain_ratio_err if fx is not None else None
    res.gain_ratio_y = fy.gain_ratio if fy is not None else gains[1]
    res.gain_ratio_y_err = fy.gain_ratio_err if fy is not None else None
    _contact_depth(res, data.curvature_radius)
    res.message = ("ratios only: each pair fitted alone with the exact R curve (valid for slip along one axis "
                   "or a large contact; under oblique slip with a small contact the smaller speed is pulled "
                   "toward the larger)")
    return res


def _file_kernel(data):
    """A spectra file's spectral window as ``(offsets, weights)``, or a single bin."""
    if getattr(data, "kernel", None) is None:
        return ((0.0,), (1.0,))
    return tuple(tuple(float(x) for x in row) for row in np.asarray(data.kernel))


def _gains(options: FitOptions) -> tuple[float, float]:
    g = options.gain_ratio
    if g is None:
        return 1.0, 1.0
    g = np.atleast_1d(np.asarray(g, float))
    return (float(g[0]), float(g[-1]))


def _contact_depth(res: FitResult, curvature_radius):
    r = float(curvature_radius) if curvature_radius else PAPER_SENSOR.curvature_radius
    res.curvature_radius = r
    if res.a is not None:
        res.contact_depth = res.a ** 2 / r
        res.contact_depth_err = None if res.a_err is None else 2 * res.a * res.a_err / r
    if not curvature_radius:
        res.warnings.append(f"curvature_radius not given: contact depth assumes R = {1e3 * r:g} mm")


def _lower(p):
    lo = np.full(p, -np.inf)
    lo[:3] = [np.log(_V_BOUNDS[0]), np.log(_V_BOUNDS[0]), np.log(_A_BOUNDS[0])]
    lo[3:5] = np.log(1e-3)
    return lo


def _upper(p):
    hi = np.full(p, np.inf)
    hi[:3] = [np.log(_V_BOUNDS[1]), np.log(_V_BOUNDS[1]), np.log(_A_BOUNDS[1])]
    hi[3:5] = np.log(1e3)
    return hi


def _to_physical(curvature_radius):
    r = float(curvature_radius) if curvature_radius else PAPER_SENSOR.curvature_radius

    def to_physical(theta):
        theta = np.asarray(theta)
        a = np.exp(theta[..., 2])
        return {"vx": np.exp(theta[..., 0]), "vy": np.exp(theta[..., 1]), "a": a,
                "contact_depth": a ** 2 / r, "gain_ratio": np.exp(theta[..., 3]),
                "gain_ratio_y": np.exp(theta[..., 4])}

    return to_physical


def _fmt_speed(v):
    return "n/a" if v is None else f"{100 * v:.3g} cm/s"




# --------------------------------------------------------------------------- entry points


def record_of(signals, fs, depths, options: FitOptions, *, source=None) -> Record:
    """The pipeline's ``Record`` of one recording (4, N) under ``options`` (spectral estimator, known gains
    and velocity): what ``fit`` and ``batch`` fit. Raises ``TactileInputError`` for settings it cannot meet."""
    return run.record(np.asarray(signals, float), float(fs), depths, gains=_gains(options), velocity=options.velocity,
                      method=options.method, nperseg=options.nperseg, prewhiten=options.prewhiten,
                      settings=settings_of(options), source=source)


def fit_recording(rec: Recording, options: FitOptions = FitOptions(), *, record: int = 0) -> FitResult:
    """Fit one record of a recording. Raises ``TactileInputError`` for bad input."""
    validate_recording(rec)
    one = rec.record(record)
    src = rec.source or "<recording>"
    options = _options_from_file(options, one)
    precision = "float64" if jax.config.jax_enable_x64 else "float32"
    model_select.check_model(options.model, src)
    if options.model == "hertz":
        return _fit_hertz(one, options, src, record, precision)
    try:
        r = record_of(one.signals, one.fs, one.depths, options, source=src)
    except TactileInputError as err:
        raise err.with_source(src) from None
    res = fit_record(r, options, curvature_radius=one.curvature_radius)
    res.file, res.index, res.truth, res.precision = rec.source, record, dict(one.truth), precision
    return res


#: what a spectra file without the x-y cross-spectra costs its fit (``FitResult.message``)
NO_XY_MESSAGE = ("the spectra have no x-y cross-spectra ('xy'): the y pair is fitted without conditioning on the "
                 "x pair (the x-y chain is off), so the information both pairs share under oblique slip is lost "
                 "and the errors of vx, vy and a are typically larger than a fit of the recording gives")


def fit_spectra(data, options: FitOptions = FitOptions()) -> FitResult:
    """Fit recorded spectra (``io.SpectraData``): PSD/CSD (with the x-y cross-spectra and the groups of
    segments where given) through the joint pipeline, ratios alone per pair.

    A file that ``tactile-jax spectra`` wrote from a recording gives the recording's fit: the same
    ``Segments`` go into the same program."""
    options = _options_from_file(options, data)
    if data.psd is None or data.csd is None:
        return _fit_ratio_only(data, options)
    xy = getattr(data, "xy", None)
    count = getattr(data, "group_count", None)
    groups = None if count is None else (count, data.group_psd, data.group_csd, data.group_xy)
    warnings = []
    n_segments = data.n_segments or (float(np.sum(count)) if count is not None else None)
    if not n_segments:
        warnings.append("n_segments not given: errors assume 1 segment (very conservative)")
    if groups is None:
        warnings.append("no groups of segments (group_*): no jackknife; the errors are the Laplace errors times "
                        "max(redchi, 1) times the bin factor")
    r = run.record_from_spectra(data.omega, data.psd, data.csd, data.depths, n_segments=float(n_segments or 1),
                                xy=xy, groups=groups,
                                kernel=None if getattr(data, "kernel", None) is None else _file_kernel(data),
                                bin_factor=data.bin_factor, whitening=data.whitening, fs=data.fs,
                                gains=_gains(options), velocity=options.velocity, source=data.source)
    res = fit_record(r, options, curvature_radius=data.curvature_radius, has_xy=xy is not None)
    res.warnings.extend(warnings)
    if xy is None and res.status not in ("unsupported", "failed"):
        res.message = "; ".join(m for m in (res.message, NO_XY_MESSAGE) if m)
    res.file = data.source
    return res


def fit_record(rec: Record, options: FitOptions = FitOptions(), *, curvature_radius=None,
               has_xy: bool = True) -> FitResult:
    """The joint pipeline on one ``joint.core.Record`` with what only a single record needs layered on
    top (see the module). Never raises for a fit that fails: see ``status``."""
    try:
        options = model_select.options_for(options)
        if options.window != "gaussian":
            return FitResult(window=options.window, solver=options.solver, status="unsupported",
                             message=f"the joint model has the Gaussian window only; window {options.window!r} "
                                     "is not fitted")
        if options.cross_pairs not in (None, 0, 1, 2):
            return FitResult(status="unsupported", message=f"cross_pairs must be None, 0, 1 or 2, not "
                                                           f"{options.cross_pairs!r}")
        settings = settings_of(options, has_xy=has_xy)
        return _layered(_Refitter(rec, settings), run.fit_one(rec, settings), options, curvature_radius)
    except TactileInputError:
        raise
    except Exception as err:  # a bug or a numerical corner must not sink a batch: report it as data
        return FitResult(window=options.window, solver=options.solver, status="failed",
                         message=f"the fit failed: {type(err).__name__}: {' '.join(str(err).split())}")


# --------------------------------------------------------------------------- one record's extras


class _Refitter(NamedTuple):
    """Refits of one record through the pipeline's program (``joint.run.refit``)."""

    rec: Record
    settings: Settings

    def __call__(self, theta, free) -> Summary:
        return run.refit(self.rec, self.settings, theta, free)


def _layered(refit: _Refitter, s: Summary, options: FitOptions, curvature_radius) -> FitResult:
    warnings = []
    if int(s.status) == STATUS.index("not_converged"):
        s, more = _continue(refit, s)
        warnings.append(f"the fit took {more} more solves of {run.ITERATIONS[2]} iterations to settle"
                        if int(s.status) != STATUS.index("not_converged") else
                        f"{more} more solves of {run.ITERATIONS[2]} iterations did not settle the fit")
    chosen, window_weak, note = _select(refit, s, options)
    margin = None
    if chosen is not None:
        _, s, margin = chosen
    model = model_select.model_name(s.free, options.velocity is not None)
    res = result_from_summary(s, velocity=options.velocity, curvature_radius=curvature_radius, model=model,
                              window_weak=window_weak, segments=refit.rec.seg)
    res.model_margin = margin
    _profiles(res, s, options, refit)
    if note and note.startswith("model "):
        res.message = "; ".join(m for m in (note, res.message) if m)
    elif note:
        warnings.append(note)
    res.warnings.extend(warnings)
    try:
        res.texture_x, res.texture_y = _texture_sections(s)
    except Exception as err:  # pragma: no cover - reporting extra, never fatal
        res.warnings.append(f"texture cross-sections not computed: {err}")
    res.problem = _problem(s, res, curvature_radius)
    res.data = s.data
    res.summary = s
    model_select.annotate(res)
    return res


def settle(rec: Record, settings: Settings, s: Summary) -> tuple[Summary, int]:
    """More solves of the pipeline's program from where a fit stopped unsettled (``fit`` and ``batch``):
    the last summary and how many solves ran (0 where it had settled)."""
    if int(s.status) != STATUS.index("not_converged"):
        return s, 0
    return _continue(_Refitter(rec, settings), s)


def _continue(refit: _Refitter, s: Summary):
    """More solves from where a fit stopped unsettled; the last summary and how many solves ran."""
    for k in range(1, _MORE_SOLVES + 1):
        s = refit(s.theta, s.free)
        if int(s.status) != STATUS.index("not_converged"):
            return s, k
    return s, _MORE_SOLVES


def _select(refit: _Refitter, s: Summary, options: FitOptions):
    """``options.model``: ((name, summary, margin) or None, window_weak, note)."""
    free = np.asarray(s.free, bool)
    if options.model in ("slip", "auto"):
        sel = model_select.select(s, free, lambda th, fr: (lambda f: (f, float(f.chi2)))(refit(th, fr)), options,
                                  bin_factor=float(refit.rec.seg.bin_factor))
        return (sel.name, s if sel.fit is None else sel.fit, sel.margin), False, sel.note
    if options.model is None:
        needed, note = model_select.window_needed(s, free, lambda th, fr: float(refit(th, fr).chi2))
        return None, not needed, note
    return None, False, ""


def result_from_summary(s: Summary, *, velocity=None, curvature_radius=None, model: str = "joint",
                        window_weak: bool = False, solver: str = "levenberg-marquardt, 3 starts", file=None,
                        index: int = 0, segments=None) -> FitResult:
    """A ``FitResult`` from one record's ``joint.core.Summary`` (numpy): the values, errors, status and
    message that ``fit`` and ``batch`` both report. ``segments``: the record's ``Segments``, which say
    what a record without a usable band holds instead (``joint.diagnose``)."""
    res = FitResult(model=model, solver=solver, file=file, index=index)
    theta, free = np.asarray(s.theta), np.asarray(s.free, bool)
    status = STATUS[int(s.status)]
    res.status = status
    res.converged = bool(s.converged)
    res.n_bins = int(s.n_bins)
    res.cross_pairs = int(np.asarray(s.data.mask_xy).any(axis=-1).sum())
    loc = s.located
    for p, attr in ((0, "k0x"), (1, "k0y")):
        k0 = float(loc.k0[p])
        setattr(res, attr, k0 if np.isfinite(k0) else None)
    if status == "no_band":
        res.message = (f"only {res.n_bins} usable bins (coherent, deep probe above noise, not leakage): too few to "
                       "fit; check the gains, the SNR or the band limits")
        if segments is not None:
            res.message += "; " + no_band_reason(segments)
        return res
    if status == "failed":
        res.message = "the fit produced non-finite values"
        return res
    names = param_names(theta.size - N_PHYS)
    res.names = names
    res.redchi, res.chi2, res.cond = float(s.redchi), float(s.chi2), float(s.cond)
    n_free, n = int(free.sum()), float(s.n_data)
    res.n_params, res.n_residuals = n_free, int(n)
    res.aic = float(n * np.log(max(res.chi2, 1e-300) / max(n, 1)) + 2 * n_free)
    res.bic = float(n * np.log(max(res.chi2, 1e-300) / max(n, 1)) + np.log(max(n, 1)) * n_free)
    scales = np.asarray(s.scales)
    res.error_scale = float(s.pooled)
    res.error_scales = {name: float(scales[i]) for i, name in enumerate(OWN_SCALE_PARAMS) if free[i]}
    res.error_method = ("laplace x jackknife (vx, vy, a each their own)" if bool(s.jackknife)
                        else "laplace x max(redchi, 1) x bin_factor")
    cov = np.asarray(s.cov)
    fidx = np.flatnonzero(free)
    sub = cov[np.ix_(fidx, fidx)]
    dsd = np.sqrt(np.clip(np.diag(sub), 1e-300, None))
    res.correlations = sub / np.outer(dsd, dsd)
    sd = np.asarray(s.sd)
    notes = []
    if status == "not_converged":
        notes.append("the solver did not converge (fixed-iteration Levenberg-Marquardt)")
    elif bool(s.settled):
        notes.append("the solver stopped with texture knots still moving; a full Gauss-Newton step moves the speeds, "
                     f"radius and gains by less than {STEP_TOL} sigma, so their values and errors stand")
    vx, vy, a = np.exp(theta[:3])
    for i, (name, v) in enumerate((("vx", vx), ("vy", vy))):
        if not free[i]:
            setattr(res, name, float(abs(velocity[i])) if velocity is not None else float(v))
            continue
        err = float(v * sd[i])
        setattr(res, name, float(v))
        setattr(res, name + "_err", err)
        if err > 0.5 * v or v < 1e-3 * max(vx, vy):
            notes.append(f"{name} is consistent with 0")
    a_err = float(a * sd[2])
    if not free[2]:
        res.a, res.a_lower = None, float(a)
        notes.append(f"the contact window is held negligible (a > {1e3 * a:.3g} mm)")
    elif window_weak or a_err > 0.5 * a or a > 0.5 * _A_BOUNDS[1]:
        res.a, res.a_err = None, None
        notes.append("the contact window is too weak to measure a")
    else:
        res.a, res.a_err = float(a), a_err
    for i, (name, name_err) in ((3, ("gain_ratio", "gain_ratio_err")), (4, ("gain_ratio_y", "gain_ratio_y_err"))):
        g = float(np.exp(theta[i]))
        setattr(res, name, g)
        setattr(res, name_err, float(g * sd[i]) if free[i] else None)
    _contact_depth(res, curvature_radius)
    if res.cond > 1e10:
        notes.append(f"near-degenerate parameters (condition number {res.cond:.2g}): see the correlations")
    if status == "poor_fit":
        notes.insert(0, f"poor fit: reduced chi-square {res.redchi:.1f}; the joint model does not describe these "
                        "spectra (a line texture, another window, or a wrong basin): check the plot before trusting "
                        "the numbers")
    n_leak = int(loc.n_leak)
    if n_leak:
        res.warnings.append(f"{n_leak} coherent bins dropped as spectral leakage between texture lines")
    res.message = "; ".join(notes)
    return res


def _profiles(res: FitResult, s: Summary, options: FitOptions, refit: _Refitter) -> None:
    """Profile-likelihood bounds and intervals where the Laplace error does not describe a parameter."""
    if res.status in ("no_band", "failed"):
        return
    theta, free = np.asarray(s.theta), np.asarray(s.free, bool)
    scale = np.asarray(s.scales)
    sd = np.asarray(s.sd)
    vx, vy = np.exp(theta[:2])
    notes = []
    for i, name in enumerate(("vx", "vy")):
        v, err = getattr(res, name), getattr(res, name + "_err")
        if not free[i] or err is None or not (err > 0.5 * v or v < 1e-3 * max(vx, vy)):
            continue
        upper = _profile_bound(refit, s, free, i, direction=+1, scale=scale[i])
        upper = None if (upper is not None and upper > _V_BOUNDS[1]) else upper
        setattr(res, name + "_upper", upper)
        notes.append((f"{name} is consistent with 0", f"{name} is consistent with 0 at 2 sigma (95 % upper bound "
                                                        f"{_fmt_speed(upper)})" if upper else
                      f"{name} is not determined (consistent with 0)"))
    minor = int(vy < vx)
    name = ("vx", "vy")[minor]
    if (options.profile_minor and free[0] and free[1] and getattr(res, name + "_upper") is None
            and min(vx, vy) < MINOR_PROFILE * max(vx, vy)):
        (lo, hi), (lo2, hi2) = _profile_interval(refit, s, free, minor, sd[minor], scale=scale[minor])
        for suffix, value in (("_lo", lo), ("_hi", hi), ("_lo2", lo2), ("_hi2", hi2)):
            setattr(res, name + suffix, value)
        res.message = "; ".join(m for m in (res.message, f"{name} is a minor component (the spectra depend on it "
                                            f"quadratically): profile-likelihood 1-sigma interval [{_fmt_speed(lo)}, "
                                            f"{_fmt_speed(hi)}]") if m)
        if lo2 == 0.0 and hi2 is not None:
            setattr(res, name + "_upper", hi2)
            res.message += f"; {name} is consistent with 0 at 2 sigma (95 % upper bound {_fmt_speed(hi2)})"
    if free[2] and res.a is None:
        lower = _profile_bound(refit, s, free, 2, direction=-1, scale=scale[2])
        res.a_lower = lower
        notes.append(("the contact window is too weak to measure a",
                      f"the contact window is too weak to measure a: a > {1e3 * lower:.3g} mm (95 % lower bound)"
                      if lower else "the contact window is too weak to measure a"))
    for old, new in notes:
        res.message = res.message.replace(old, new, 1)


def _profile_walk(refit: _Refitter, s: Summary, free, i, direction, step, c_stop, *, limit=None, n_max=24,
                  growth=1.5):
    """Step log-parameter i from the best fit (direction -1: down, +1: up), the others refitted
    (warm-started), until chi2 rises by ``c_stop`` or x passes ``limit``; the step grows by
    ``growth`` each time. Returns the finite points (x, chi2 - chi2_min), starting with (x_best, 0)."""
    others = np.asarray(free).copy()
    others[i] = False
    chi0 = float(s.chi2)
    theta = np.asarray(s.theta).copy()
    x = float(theta[i])
    points = [(x, 0.0)]
    for _ in range(n_max):
        if limit is not None and direction * (x + direction * step - limit) > 0:
            break
        x = x + direction * step
        step *= growth
        theta[i] = x
        fit = refit(theta, others)
        chi2 = float(fit.chi2)
        if not np.isfinite(chi2):
            continue
        points.append((x, chi2 - chi0))
        theta = np.asarray(fit.theta).copy()
        if chi2 - chi0 >= c_stop:
            break
    return points, x


def _profile_bound(refit: _Refitter, s: Summary, free, i, *, direction, scale, delta=2.71, n_max=24):
    """One-sided 95 % profile-likelihood bound of parameter i (log space), exp of the crossing of
    chi2_min + delta * scale (interpolated), or the last value tried below / None above."""
    points, x_last = _profile_walk(refit, s, free, i, direction, 0.1, delta * scale, n_max=n_max)
    if len(points) > 1 and points[-1][1] >= delta * scale:
        (x0, c0), (x1, c1) = points[-2], points[-1]
        frac = (delta * scale - c0) / max(c1 - c0, 1e-12)
        return float(np.exp(x0 + frac * (x1 - x0)))
    return float(np.exp(x_last)) if direction < 0 else None


def _profile_interval(refit: _Refitter, s: Summary, free, i, sd_log, *, scale, n_sigma=(1.0, 2.0)):
    """Profile-likelihood intervals of speed i (m/s), one (lo, hi) per ``n_sigma``; the crossing of
    chi2_min + n^2 scale is interpolated linearly in sqrt(chi2 - chi2_min) (exact for a quadratic
    profile). A side that never reaches it gives 0 (below) or None (above)."""
    v_major = float(np.max(np.asarray(s.theta)[:2]))
    limits = {-1: v_major + np.log(1e-3), +1: v_major + np.log(2.0)}
    c_stop = max(n_sigma) ** 2 * scale
    step = 0.5 * max(float(sd_log), 0.02)
    sides = {d: _profile_walk(refit, s, free, i, d, step, c_stop, limit=limits[d], n_max=16)[0] for d in (-1, +1)}
    out = []
    for n in n_sigma:
        target = n * np.sqrt(scale)
        bounds = []
        for d in (-1, +1):
            value = None
            for (x0, c0), (x1, c1) in zip(sides[d][:-1], sides[d][1:]):
                r0, r1 = np.sqrt(max(c0, 0.0)), np.sqrt(max(c1, 0.0))
                if r1 >= target:
                    value = float(np.exp(x0 + (target - r0) / max(r1 - r0, 1e-12) * (x1 - x0)))
                    break
            bounds.append(0.0 if (value is None and d < 0) else value)
        out.append(tuple(bounds))
    return out


def _problem(s: Summary, res: FitResult, curvature_radius) -> FitProblem:
    scales = np.asarray(s.scales)
    pooled = float(s.pooled)
    return FitProblem(residuals=joint_residuals, args=s.data, theta=np.asarray(s.theta),
                      free=tuple(bool(f) for f in np.asarray(s.free)), names=res.names, lower=_lower(s.theta.size),
                      upper=_upper(s.theta.size), cov=np.asarray(s.cov), scale=pooled,
                      to_physical=_to_physical(curvature_radius), stretch=np.sqrt(scales / pooled))


def _hertz_spectra(one, options):
    from .spectra import estimate_spectra

    kw = {"nperseg": options.nperseg} if (options.nperseg and options.method == "welch") else {}
    return estimate_spectra(np.asarray(one.signals, float), one.fs, method=options.method, prewhiten=options.prewhiten,
                            **kw)


def _fit_hertz(one, options, src, record, precision) -> FitResult:
    try:
        spec = _hertz_spectra(one, options)
    except TactileInputError as err:
        raise err.with_source(src) from None
    res = model_select.fit_hertz(spec, one.depths, options, one.curvature_radius)
    res.file, res.index, res.truth, res.precision = one.source, record, dict(one.truth), precision
    return res


# --------------------------------------------------------------------------- texture sections and plots


def _texture_sections(s: Summary):
    """The pipeline's Eq. 18/19 cross-sections (``joint.core.texture_sections``) on each pair's fitted bins."""
    k, logp, err = np.asarray(s.texture)
    out = []
    for p in range(2):
        m = np.asarray(s.data.mask_s11[p])
        out.append(TextureSection(k[p][m], np.exp(logp[p][m]), err[p][m]) if m.any() else None)
    return tuple(out)


def model_curves(result: FitResult) -> dict | None:
    """Measured and fitted log|P2/P1| of both pairs for plots (Fig. 7 style).

    Returns dict with ``omega`` (L,) rad/s; ``log_ratio``, ``log_ratio_err``, ``mask`` (2, L)
    measured; ``model`` (2, L) at the fit and ``model_sd`` (2, L) its one-sigma band from the
    covariance (on the fitted bins); None when the fit has no joint-model data.
    """
    s = getattr(result, "summary", None)
    if s is None:
        return None
    data = s.data
    n_fit = np.asarray(data.omega).size
    err = np.where(np.asarray(data.mask_h), np.asarray(data.h_err), np.nan)
    jac_h = -np.asarray(s.jac)[2 * n_fit:4 * n_fit].reshape(2, n_fit, -1) * np.nan_to_num(err)[..., None]
    var = np.einsum("plk,km,plm->pl", jac_h, np.asarray(s.cov), jac_h)
    mask = np.asarray(data.mask_h) | np.asarray(data.mask_xy[1])[None] & np.array([False, True])[:, None]
    return {"omega": np.asarray(data.omega), "log_ratio": np.where(mask, np.asarray(data.meas.log_h), np.nan),
            "log_ratio_err": np.asarray(data.h_err), "mask": mask, "model": np.asarray(s.model.log_h),
            "model_sd": np.sqrt(np.clip(var, 0, None))}
