"""Joint estimation of slip velocity, contact radius, gains and texture spectrum, with error bars.

``fit_recording`` (probe signals) and ``fit_spectra`` (recorded spectra) run the
analysis program (``inference.analysis``) on one record: grouped periodograms on a
fixed grid (``spectral.segments``), the usable band and closed-form starts, the 2-D
joint model of both pairs and their cross-pair chain fitted by fixed-iteration
Levenberg-Marquardt, every model choice (window, texture, slip direction) made
inside the program, Laplace errors scaled by the delete-one-group jackknife.
``batch`` runs the same program on chunks, and both turn its arrays into a row with
``result_of``. On top, for one record only: profile-likelihood bounds for a minor
speed component (``uncertainty.profile``), ``model="auto"``/"slip", texture
cross-sections (Eq. 18-19) and the problem emcee samples.
Nothing here raises on a fit that fails: the result's ``status`` and ``message``
say why (bad input raises ``TactileInputError``; ``batch`` turns it into a row).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..contract import SENSOR_DEFAULT, Recording, validate_recording
from ..errors import TactileInputError
from ..model import hertz as hertz_mod
from ..model import lines
from ..model.sensor import PAPER_SENSOR
from ..status import Status
from ..uncertainty.profile import add_profiles
from . import run
from . import select as model_select
from .analysis import WINDOWS, Analysis, summary_of
from .core import Record, Settings, Summary
from .describe import result_from_analysis
from .forward import INDEX, PARAMS
from .options import FitOptions, analysis_settings, choices_of, known_gains, options_from_file, settings_of
from .pair_fit import fit_pair
from .problem import FitProblem
from .residuals import residuals as joint_residuals
from .result import A_BOUNDS, V_BOUNDS, FitResult, set_contact_depth, texture_sections


__all__ = ["fit_recording", "fit_spectra", "fit_record", "record_of", "result_of", "with_line_model",
           "result_from_lines", "NO_XY_MESSAGE"]

#: a smooth fit this far off (reduced chi-square) says nothing: a line model that found lines replaces it
_GROSS_REDCHI = 100.0
_I = {name: i for i, name in enumerate(PARAMS)}


def _fit_ratio_only(data, options: FitOptions) -> FitResult:
    """Ratios without PSDs: each pair's exact R curve on its own (the fast path)."""
    d1, d2 = data.depths
    omega = np.asarray(data.omega, float)
    log_ratio = np.log(np.asarray(data.ratio, float))
    err = np.asarray(data.ratio_err, float) if data.ratio_err is not None else np.full_like(log_ratio, 0.1)
    res = FitResult(model="pair", window="gaussian", file=data.source, solver=options.solver)
    gains = known_gains(options)
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
        res.set("vx", value=fx.speed, err=fx.speed_err)
    if fy is not None:
        res.set("vy", value=fy.speed, err=fy.speed_err)
    best = min((f for f in fits if f is not None), key=lambda f: f.a_err / f.a if f.a > 0 else np.inf)
    res.set("a", value=best.a, err=best.a_err)
    res.converged = all(f.converged for f in fits if f is not None)
    if not res.converged:
        res.status = "not_converged"
    res.redchi = float(np.mean([f.redchi for f in fits if f is not None]))
    res.n_bins = int(sum(f.n_bins for f in fits if f is not None))
    res.n_residuals = res.n_bins                      # one log ratio per bin
    for name, f, g in (("gain_ratio", fx, gains[0]), ("gain_ratio_y", fy, gains[1])):
        fitted = f is not None and options.fit_gain
        res.set(name, value=f.gain_ratio if f is not None else g, err=f.gain_ratio_err if fitted else None,
                fixed=not fitted)
    set_contact_depth(res, data.curvature_radius)
    res.message = ("ratios only: each pair fitted alone with the exact R curve (valid for slip along one axis "
                   "or a large contact; under oblique slip with a small contact the smaller speed is pulled "
                   "toward the larger)")
    return res


def _file_kernel(data):
    """A spectra file's spectral window as ``(offsets, weights)``, or a single bin."""
    if getattr(data, "kernel", None) is None:
        return ((0.0,), (1.0,))
    return tuple(tuple(float(x) for x in row) for row in np.asarray(data.kernel))


def _bounds(p, side):
    """Lower (side 0) or upper (side 1) bounds of the P parameters for the posterior's prior (log space)."""
    out = np.full(p, -np.inf if side == 0 else np.inf)
    for name, limits in (("log_vx", V_BOUNDS), ("log_vy", V_BOUNDS), ("log_a", A_BOUNDS), ("log_gx", (1e-3, 1e3)),
                         ("log_gy", (1e-3, 1e3))):
        out[_I[name]] = np.log(limits[side])
    return out


def _to_physical(curvature_radius):
    r = float(curvature_radius) if curvature_radius else PAPER_SENSOR.curvature_radius

    def to_physical(theta):
        theta = np.asarray(theta)
        a = np.exp(theta[..., _I["log_a"]])
        return {"vx": np.exp(theta[..., _I["log_vx"]]), "vy": np.exp(theta[..., _I["log_vy"]]), "a": a,
                "contact_depth": a ** 2 / r, "gain_ratio": np.exp(theta[..., _I["log_gx"]]),
                "gain_ratio_y": np.exp(theta[..., _I["log_gy"]])}

    return to_physical


# --------------------------------------------------------------------------- entry points


def record_of(signals, fs, depths, options: FitOptions, *, source=None) -> Record:
    """The pipeline's ``Record`` of one recording (4, N) under ``options`` (spectral estimator, known gains
    and velocity): what ``fit`` and ``batch`` fit. Raises ``TactileInputError`` for settings it cannot meet."""
    return run.record(np.asarray(signals, float), float(fs), depths, gains=known_gains(options), velocity=options.velocity,
                      method=options.method, nperseg=options.nperseg, prewhiten=options.prewhiten,
                      settings=settings_of(options), source=source)


def warm_up(options: FitOptions) -> None:
    """Compile (or load) the analysis program that ``options`` run, on a record of noise: its inputs have one shape
    whatever the recording, so a noise record stands for every file."""
    opts = model_select.options_for(options)
    noise = np.random.default_rng(0).standard_normal((4, 4096))
    rec = record_of(noise, 1000.0, (PAPER_SENSOR.d1, PAPER_SENSOR.d2), opts)
    run.analyse_one(rec, analysis_settings(opts), choices_of(opts))


def records_of(blocks, fs, depths, options: list[FitOptions]) -> list[Record]:
    """``record_of`` of many records of one length at once (``run.record_many``: their spectra in jnp), under
    options that differ at most in the known velocity and gains: what ``batch`` runs on an accelerator.
    blocks: (B, 4, N); fs: (B,) Hz; depths: (B, 2) m."""
    first = options[0]
    return run.record_many(np.asarray(blocks, float), fs, depths, gains=[known_gains(o) for o in options],
                           velocity=[o.velocity for o in options], nperseg=first.nperseg,
                           prewhiten=first.prewhiten, settings=settings_of(first))


def fit_recording(rec: Recording, options: FitOptions = FitOptions(), *, record: int = 0) -> FitResult:
    """Fit one record of a recording. Raises ``TactileInputError`` for bad input.

    The result's ``sensor`` is the recording's; where that is the paper's sensor assumed for an audio
    file (``SENSOR_DEFAULT``), a warning says so."""
    validate_recording(rec)
    one = rec.record(record)
    src = rec.source or "<recording>"
    options = options_from_file(options, one)
    precision = "float64" if jax.config.jax_enable_x64 else "float32"
    model_select.check_model(options.model, src)
    try:
        r = record_of(one.signals, one.fs, one.depths, options, source=src)
    except TactileInputError as err:
        raise err.with_source(src) from None
    res = fit_record(r, options, curvature_radius=one.curvature_radius)
    res = with_line_model(res, one.signals, one.fs, one.depths, options, curvature_radius=one.curvature_radius,
                          source=src)
    res.file, res.index, res.truth, res.precision = rec.source, record, dict(one.truth), precision
    res.sensor = rec.sensor
    if rec.sensor == SENSOR_DEFAULT:
        d1, d2, r = (1e3 * v for v in PAPER_SENSOR)
        res.warnings.append(f"sensor assumed: the paper's (probe depths {d1:g} and {d2:g} mm, R = {r:g} mm); "
                            "a sensor file (--sensor) gives the sensor's own")
    return res


def with_line_model(res: FitResult, signals, fs: float, depths, options: FitOptions, *, curvature_radius=None,
                    source: str | None = None) -> FitResult:
    """``res`` of the smooth texture models, or the line model's result where they find no band or do not fit.

    A grating, a wire net or a surface of few strong features has a spectrum of lines
    (``spectral.peaks``, on spectra that are not prewhitened: prewhitening notches a line) that
    ``inference.line_texture`` turns into wavenumbers and speeds. Where the smooth fit is not ``ok``
    (``no_band``, ``not_converged``, ``poor_fit``), the line model's result replaces it when it
    determines a speed (both, or a grating's speed along its normal), and replaces a ``no_band`` or
    ``not_converged`` one when it says what the lines leave undetermined; a ``poor_fit`` otherwise
    stays, its message saying what the lines show (a texture too fine for the probes' depths, lines
    heard by one pair only), and so does a lumpy texture's ``poor_fit`` whatever the lines show.
    ``fit`` and ``batch`` both call this.
    signals: (4, N); fs: Hz; depths: (d1, d2) m.
    """
    if res.status not in (Status.NO_BAND, Status.POOR_FIT, Status.NOT_CONVERGED) or options.texture is not None:
        return res
    from ..spectral.peaks import find_lines
    from .line_texture import fit_lines

    try:
        lines = find_lines(np.asarray(signals, float), float(fs), source=source)
        fit = fit_lines(lines, depths, gain_ratio=known_gains(options), velocity=options.velocity,
                        window=options.window)
    except Exception as err:  # noqa: BLE001 - the line model is a second opinion: never let it sink the fit
        res.warnings.append(f"line model not run: {type(err).__name__}: {err}")
        return res
    if res.status == Status.POOR_FIT and "lumpy" in (res.texture or ""):
        # a poor fit whose misfit has no trend across frequency is a lumpy texture's, many persistent modes: the
        # line model reads a few of them as lines, and two lines fit it almost exactly (on a 300-mode texture of
        # benchmarks/textures.py, (8.97, 5.94) +/- (0.02, 0.01) cm/s for a slip of (7.01, 2.73)); its reading stays
        # a note
        res.message = "; ".join(m for m in (res.message, f"line model, not used on a lumpy texture: {fit.message}")
                                if m)
        return res
    determined = fit.status == "ok" or (fit.status == "undetermined" and fit.v_n is not None)
    # a poor smooth fit keeps its (inflated) errors unless it is grossly wrong: lines dominate the spectra
    gross = res.status == Status.POOR_FIT and (res.redchi or 0.0) > _GROSS_REDCHI
    if determined or ((res.status != Status.POOR_FIT or gross) and fit.status == "undetermined"):
        return result_from_lines(fit, options, curvature_radius=curvature_radius, smooth=res)
    if res.status == Status.NO_BAND:            # the line model's reading of the raw spectra replaces the diagnosis
        found_none = fit.n_lines == 0 and not np.any(np.asarray(lines.shallow_only))
        diagnosis = "; ".join(res.message.split("; ")[1:]) if found_none else ""
        res.message = "; ".join(m for m in (f"only {res.n_bins} usable bins for a smooth texture", fit.message,
                                            diagnosis) if m)
    else:
        res.message = "; ".join(m for m in (res.message, f"line model: {fit.message}") if m)
    return res


def _finite_or_none(x):
    return float(x) if x is not None and np.isfinite(x) else None


def result_from_lines(fit, options: FitOptions, *, curvature_radius=None, smooth: FitResult | None = None) -> FitResult:
    """A ``FitResult`` of the line model's ``LineFit``: speeds (or a grating's speed along its normal with
    the other component undetermined), a, the normal's angle; texture "grating" or "lines"."""
    res = FitResult(model="lines", window=fit.window, texture="grating" if fit.texture == "grating" else "lines",
                    status=Status(fit.status), message=fit.message, converged=True, solver="optimistix",
                    redchi=_finite_or_none(fit.redchi), chi2=_finite_or_none(fit.chi2), n_bins=int(fit.n_used),
                    n_residuals=int(fit.n_used), n_params=0)
    bounds = fit.speed_bounds or (None, None)
    for name, value, err, bound in (("vx", fit.vx, fit.vx_err, bounds[0]), ("vy", fit.vy, fit.vy_err, bounds[1])):
        if options.velocity is not None:
            res.set(name, value=abs(options.velocity[name == "vy"]), fixed=True)
        elif value is not None:
            res.set(name, value=float(value), err=None if err is None else float(err))
        elif bound is not None:
            res.set(name, lo2=float(bound[0]), hi2=float(bound[1]))
    if fit.a is not None:
        res.set("a", value=float(fit.a), err=None if fit.a_err is None else float(fit.a_err))
    if fit.v_n is not None:
        res.set("v_normal", value=float(fit.v_n), err=None if fit.v_n_err is None else float(fit.v_n_err))
    elif fit.v_n_bounds is not None:
        res.set("v_normal", lo2=float(fit.v_n_bounds[0]), hi2=float(fit.v_n_bounds[1]))
    if fit.normal_angle is not None:
        res.set("normal_angle", value=float(fit.normal_angle),
                err=None if fit.normal_angle_err is None else float(fit.normal_angle_err))
    gains = known_gains(options)
    res.set("gain_ratio", value=gains[0], fixed=True)
    res.set("gain_ratio_y", value=gains[1], fixed=True)
    set_contact_depth(res, curvature_radius)
    if smooth is not None:
        res.file, res.index, res.truth, res.precision = smooth.file, smooth.index, smooth.truth, smooth.precision
        res.warnings.append(f"the smooth texture model gave {smooth.status.value}: "
                            f"{(smooth.message or '').split(';')[0]}")
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
    options = options_from_file(options, data)
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
                                gains=known_gains(options), velocity=options.velocity, source=data.source)
    res = fit_record(r, options, curvature_radius=data.curvature_radius, has_xy=xy is not None)
    res.warnings.extend(warnings)
    if xy is None and res.status not in ("unsupported", "failed"):
        res.message = "; ".join(m for m in (res.message, NO_XY_MESSAGE) if m)
    res.file = data.source
    return res


def fit_record(rec: Record, options: FitOptions = FitOptions(), *, curvature_radius=None,
               has_xy: bool = True) -> FitResult:
    """The analysis program (``inference.analysis``) on one ``inference.core.Record``, with what only a single
    record needs layered on top (see the module). Never raises for a fit that fails: see ``status``."""
    try:
        options = model_select.options_for(options)
        if options.cross_pairs not in (None, 0, 1, 2):
            return FitResult(status="unsupported", message=f"cross_pairs must be None, 0, 1 or 2, not "
                                                           f"{options.cross_pairs!r}")
        settings = analysis_settings(options, has_xy=has_xy)
        a = run.analyse_one(rec, settings, choices_of(options))
        return _layered(rec, settings, a, options, curvature_radius)
    except TactileInputError:
        raise
    except Exception as err:  # a bug or a numerical corner must not sink a batch: report it as data
        return FitResult(window=options.window or "hertz", solver=options.solver, status="failed",
                         message=f"the fit failed: {type(err).__name__}: {' '.join(str(err).split())}")


# --------------------------------------------------------------------------- one record's extras


class _Refitter(NamedTuple):
    """Refits of one record through the analysis program, every choice held (``inference.run.refit_analysis``)."""

    rec: Record
    settings: Settings
    window: str
    lumps: np.ndarray | None = None
    lump_rows: np.ndarray | None = None

    def __call__(self, theta, free) -> Summary:
        return run.refit_analysis(self.rec, self.settings, theta, free, self.window, self.lumps, self.lump_rows)


class _Oblique(NamedTuple):
    """The fit with both speeds free where the slip direction holds one (its profile bounds the held one)."""

    theta: np.ndarray
    free: np.ndarray
    scales: np.ndarray
    chi2: float


def result_of(a: Analysis, rec: Record, options: FitOptions, *, curvature_radius=None, file=None, index: int = 0,
              extras=None, summary: Summary | None = None) -> FitResult:
    """The row of one record's ``Analysis``: what ``fit`` reports before its extras, and ``batch`` writes."""
    s = summary_of(a) if summary is None else summary
    return result_from_analysis(a, velocity=options.velocity, curvature_radius=curvature_radius,
                                model=model_select.model_name(s.free, options.velocity is not None), segments=rec.seg,
                                file=file, index=index, extras=extras, summary=summary)


def _layered(rec: Record, settings: Settings, a: Analysis, options: FitOptions, curvature_radius) -> FitResult:
    window = WINDOWS[int(a.window)]
    lumps = np.asarray(a.lumps)
    refit = _Refitter(rec, settings, window, lumps, np.asarray(a.summary.data.lump_rows))
    s = summary_of(a)
    chosen, note = _select(refit, s, options)
    margin = None
    if chosen is not None:
        _, s, margin = chosen
    o_free = np.asarray(a.oblique_free, bool)
    # the held speed's bound profiles the oblique fit, which a lumpy texture's refit does not have
    oblique = (_Oblique(np.asarray(a.oblique_theta), o_free, np.asarray(a.oblique_scales), float(a.oblique_chi2))
               if (o_free != np.asarray(s.free, bool)).any() and not lumps.any() else None)

    def extras(res, s):
        add_profiles(res, s, refit, profile_minor=options.profile_minor, oblique=oblique)

    res = result_of(a, rec, options, curvature_radius=curvature_radius, extras=extras,
                    summary=None if chosen is None else s)
    res.model_margin = margin
    if note:
        res.message = "; ".join(m for m in (note, res.message) if m)
    try:
        res.texture_x, res.texture_y = texture_sections(s)
    except Exception as err:  # pragma: no cover - reporting extra, never fatal
        res.warnings.append(f"texture cross-sections not computed: {err}")
    res.problem = _problem(s, res, curvature_radius, settings.hertz if window == "hertz" else None)
    res.data = s.data
    res.summary = s
    model_select.annotate(res)
    return res


def _select(refit: _Refitter, s: Summary, options: FitOptions):
    """``options.model`` "slip" or "auto": ((name, summary, margin) or None, note)."""
    if options.model in ("slip", "auto"):
        sel = model_select.select(s, np.asarray(s.free, bool),
                                  lambda th, fr: (lambda f: (f, float(f.chi2)))(refit(th, fr)), options,
                                  bin_factor=float(refit.rec.seg.bin_factor))
        return (sel.name, s if sel.fit is None else sel.fit, sel.margin), sel.note
    return None, ""


#: a sampler's walkers read the Hertz table's corner out to this factor times the fit's largest |k| a (plus
#: ``CORNER_PAD``); a walker whose line integrals reach beyond it (its radius, or its frequency-to-wavenumber map,
#: about half again the fit's: tens of the posterior's sds) has no log-probability
CORNER_FACTOR = 1.5
CORNER_PAD = 4.0


def _sampling_args(data, hertz, theta):
    """The Hertz problem's arguments for a sampler: the table cut to the corner its walkers read (``hertz.corner``),
    whose lookups cost a fraction of the whole table's (a 1 mm disk reads a twentieth of it), and kept in float32 as
    the table is stored, so that each walker's slices of it are contracted in float32 (``hertz._value_slices``)."""
    p = jnp.exp(jnp.asarray(np.asarray(theta)[[INDEX["log_vx"], INDEX["log_vy"], INDEX["log_a"]]]))
    kappa = float(lines.hertz_kappa(p, jnp.asarray(data.grid_abs), jnp.asarray(data.depths)[0]))
    return data, hertz_mod.corner(hertz, CORNER_FACTOR * kappa + CORNER_PAD)


def _problem(s: Summary, res: FitResult, curvature_radius, hertz=None) -> FitProblem:
    scales = np.asarray(s.scales)
    pooled = float(s.pooled)
    return FitProblem(residuals=joint_residuals, args=(s.data, hertz), theta=np.asarray(s.theta),
                      sampling_args=None if hertz is None else functools.partial(_sampling_args, s.data, hertz,
                                                                                   s.theta),
                      free=tuple(bool(f) for f in np.asarray(s.free)), names=res.names, lower=_bounds(s.theta.size, 0),
                      upper=_bounds(s.theta.size, 1), cov=np.asarray(s.cov), scale=pooled,
                      to_physical=_to_physical(curvature_radius), stretch=np.sqrt(scales / pooled),
                      # under the Hertz disk the conditioned deep PSDs cancel to about 1e-6 of S22, below float32's
                      # rounding of the entries (docs/posterior.md): a float32 chain would be thrown away
                      precision="float32" if hertz is None else "float64")
