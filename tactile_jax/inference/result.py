"""What a fit reports: one ``Estimate`` per quantity inside a ``FitResult``, and the row flattened from them.

``result_from_summary`` turns the compiled pipeline's arrays (``core.Summary``)
into a ``FitResult``; ``fit`` and ``batch`` both report through it, and
``FitResult.to_record`` is the one place where a result becomes a flat row
of the data contract (docs/data-format.md).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple

import numpy as np

from ..contract import RESULT_FIELDS as RESULT_FIELDS   # the data contract's fields; re-exported here
from ..model.sensor import PAPER_SENSOR
from ..spectral.diagnose import no_band_reason
from ..status import FIT_CODES, Status
from .core import ROUGHNESS_MIN_ROWS, STEP_TOL, Summary
from .forward import N_PHYS, PARAMS, param_names
from .problem import FitProblem

__all__ = ["Estimate", "FitResult", "TextureSection", "QUANTITIES", "RESULT_FIELDS", "result_from_summary",
           "no_band_result", "set_contact_depth", "update_contact_depth", "plain", "model_curves", "A_BOUNDS", "V_BOUNDS", "OWN_SCALE_PARAMS"]

#: the reported quantities (SI units: m/s, m/s, m, m, ratio, ratio; a line texture's speed along its
#: lines' normal, m/s, and that normal's angle to the x axis, degrees in [0, 90])
QUANTITIES = ("vx", "vy", "a", "contact_depth", "gain_ratio", "gain_ratio_y", "v_normal", "normal_angle")
#: the bounds and intervals a row carries for each quantity, as ``<quantity>_<field>`` columns
_ROW_EXTRAS = {"vx": ("upper", "lo", "hi", "lo2", "hi2"), "vy": ("upper", "lo", "hi", "lo2", "hi2"),
               "a": ("lower",), "gain_ratio_y": ("value", "err"), "v_normal": ("value", "err", "lo2", "hi2"),
               "normal_angle": ("value", "err")}
#: plausible ranges of the contact radius and the speeds (m, m/s)
A_BOUNDS = (1e-5, 0.1)
V_BOUNDS = (1e-6, 10.0)
#: the parameters with their own error scale (the first three of ``forward.PARAMS``)
OWN_SCALE_PARAMS = ("vx", "vy", "a")


@dataclasses.dataclass
class Estimate:
    """One reported quantity, SI units.

    value: the estimate, or None where the data cannot determine it. err: one standard deviation
    (None where the quantity is fixed or undetermined). lo, hi / lo2, hi2: the 1- / 2-sigma
    profile-likelihood interval, where the Laplace error does not describe the quantity (a minor
    speed component). lower / upper: a one-sided 95 % bound (a contact window too weak to measure,
    a speed consistent with 0). fixed: held at a value given from outside (a known velocity or gain), or
    a minor speed held at 0 by the slip direction (``analysis``; ``upper`` bounds it).
    """

    value: float | None = None
    err: float | None = None
    lo: float | None = None
    hi: float | None = None
    lo2: float | None = None
    hi2: float | None = None
    lower: float | None = None
    upper: float | None = None
    fixed: bool = False

    @property
    def state(self) -> str:
        """"fixed", "fitted", "bounded" (no value, a bound) or "undetermined"."""
        if self.fixed:
            return "fixed"
        if self.value is not None:
            return "fitted"
        return "bounded" if (self.lower is not None or self.upper is not None) else "undetermined"


class TextureSection(NamedTuple):
    """A texture cross-section (Eq. 18 / 19): power spectrum along one axis.

    k: (n,) spatial frequencies, rad/m. power: (n,) texture POWER spectral
    density there (signal units^2 per rad/m, relative). log_power_err: (n,)
    one-sigma error of log(power) (spectral noise and the v, a uncertainty).
    """

    k: np.ndarray
    power: np.ndarray
    log_power_err: np.ndarray


def _estimate_field(quantity: str, field: str):
    def get(self):
        return getattr(self.estimates[quantity], field)

    get.__doc__ = f"``estimates['{quantity}'].{field}``"
    return property(get)


@dataclasses.dataclass
class FitResult:
    """Everything a fit found, with error bars, and why not where it could not.

    estimates: quantity (``QUANTITIES``) -> ``Estimate``; ``result["vx"]`` is
    ``result.estimates["vx"]``, and the read-only attributes ``vx``, ``vx_err``,
    ``vx_upper``, ``vx_lo`` ... ``a_lower`` read the same estimates. A None value
    means not determined (``message`` says why). ``error_scales``: the variance
    scale of the Laplace covariance behind the error bars of vx, vy and a (each its
    own jackknife ratio), ``error_scale`` that of every other parameter's (the three
    pooled; the MCMC's likelihood temperature), ``error_method`` how they were found.
    ``cross_pairs``: how many blocks of the y pair's chain on the x pair the fit used.
    ``sensor``: where the sensor's depths and radius came from (``contract.Recording.sensor``:
    ``"file"``, a sensor file's path, ``"paper (default)"``), None where not known.
    ``converged``: the last solve's Gauss-Newton decrement is negligible, or a full
    Gauss-Newton step would move every physical parameter by less than
    ``core.STEP_TOL`` sigma. ``status``: a ``status.Status``.
    """

    estimates: dict = dataclasses.field(default_factory=lambda: {q: Estimate() for q in QUANTITIES})
    k0x: float | None = None
    k0y: float | None = None
    model: str = "joint-2d"
    window: str = "hertz"
    window_margin: float | None = None
    texture: str = "isotropic"
    texture_margin: float | None = None
    direction: str = "oblique"
    direction_margin: float | None = None
    converged: bool = False
    model_margin: float | None = None
    status: Status = Status.OK
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
    sensor: str | None = None
    names: tuple = ()
    error_scale: float | None = None
    error_scales: dict = dataclasses.field(default_factory=dict)
    error_method: str = ""
    cross_pairs: int = 0
    correlations: np.ndarray | None = None
    texture_x: TextureSection | None = None
    texture_y: TextureSection | None = None
    curvature_radius: float | None = None
    truth: dict = dataclasses.field(default_factory=dict)
    warnings: list = dataclasses.field(default_factory=list)
    problem: FitProblem | None = dataclasses.field(default=None, repr=False)
    data: Any = dataclasses.field(default=None, repr=False)
    summary: Any = dataclasses.field(default=None, repr=False)
    posterior: Any = dataclasses.field(default=None, repr=False)

    def __post_init__(self):
        self.status = Status(self.status)

    def __getitem__(self, quantity: str) -> Estimate:
        return self.estimates[quantity]

    def set(self, quantity: str, **fields) -> Estimate:
        """Replace fields of one quantity's ``Estimate`` (``set("vx", value=0.02, err=1e-4)``)."""
        est = dataclasses.replace(self.estimates[quantity], **fields)
        self.estimates[quantity] = est
        return est

    def to_record(self) -> dict:
        """One flat row of the data contract (JSON/CSV ready: floats, bools, str, None)."""
        scalars = {"file": self.file, "index": self.index, "k0x": self.k0x, "k0y": self.k0y, "model": self.model,
                   "window": self.window, "converged": self.converged, "status": Status(self.status).value,
                   "message": self.message}
        row = {}
        for name in RESULT_FIELDS:
            if name in scalars:
                row[name] = plain(scalars[name])
            elif name.endswith("_err"):
                row[name] = plain(self.estimates[name[:-len("_err")]].err)
            else:
                row[name] = plain(self.estimates[name].value)
        for quantity, fields in _ROW_EXTRAS.items():
            for field in fields:
                column = quantity if field == "value" else (f"{quantity}_err" if field == "err"
                                                            else f"{quantity}_{field}")
                row[column] = plain(getattr(self.estimates[quantity], field))
        for extra in ("window_margin", "texture", "texture_margin", "direction", "direction_margin", "redchi", "n_bins",
                      "cond", "aic", "bic", "solver", "precision", "sensor", "model_margin", "error_scale",
                      "error_method", "cross_pairs"):
            row[extra] = plain(getattr(self, extra))
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


for _q in QUANTITIES:
    for _field, _suffix in (("value", ""), ("err", "_err"), ("lo", "_lo"), ("hi", "_hi"), ("lo2", "_lo2"),
                            ("hi2", "_hi2"), ("lower", "_lower"), ("upper", "_upper")):
        setattr(FitResult, _q + _suffix, _estimate_field(_q, _field))
del _q, _field, _suffix


def plain(v):
    """A JSON/CSV-ready scalar: numpy scalars as Python ones, non-finite floats as None, enums as values."""
    if isinstance(v, Status):
        return v.value
    if isinstance(v, (np.floating, np.integer, np.bool_)):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def set_contact_depth(res: FitResult, curvature_radius) -> None:
    """Hertz contact depth d = a^2 / R (paper section 6.3) of ``res``'s a, with its error."""
    r = float(curvature_radius) if curvature_radius else PAPER_SENSOR.curvature_radius
    res.curvature_radius = r
    update_contact_depth(res)
    if not curvature_radius:
        res.warnings.append(f"curvature_radius not given: contact depth assumes R = {1e3 * r:g} mm")


_I = {name: i for i, name in enumerate(PARAMS)}


def update_contact_depth(res: FitResult) -> None:
    """``res``'s contact depth d = a^2 / R at its ``curvature_radius`` R, from its a (value and error, or lower
    bound): after a changes (``set_contact_depth`` sets R)."""
    r, a = res.curvature_radius, res["a"]
    if not r:
        return
    if a.value is not None:
        res.set("contact_depth", value=a.value ** 2 / r, err=None if a.err is None else 2 * a.value * a.err / r)
    elif a.lower is not None:
        res.set("contact_depth", lower=a.lower ** 2 / r)


def _set_k0(res: FitResult, k0) -> None:
    """``res``'s Eq. 4 wavenumbers k0x, k0y from the band's k0 (2,), None where not finite."""
    for p, attr in ((0, "k0x"), (1, "k0y")):
        k = float(k0[p])
        setattr(res, attr, k if np.isfinite(k) else None)


def no_band_result(res: FitResult, n_bins: int, k0, segments=None) -> FitResult:
    """``res`` as the row of a record whose band holds ``n_bins`` usable bins, too few to fit (``no_band``), with
    the band's Eq. 4 wavenumbers k0 (2,) and what the record's ``Segments`` hold instead."""
    res.status, res.n_bins = Status.NO_BAND, int(n_bins)
    _set_k0(res, k0)
    res.message = (f"only {res.n_bins} usable bins (coherent, deep probe above noise, not leakage): too few to "
                   "fit; check the gains, the SNR or the band limits")
    if segments is not None:
        res.message += "; " + no_band_reason(segments)
    return res


def result_from_summary(s: Summary, *, velocity=None, curvature_radius=None, model: str = "joint",
                        window_weak: bool = False, solver: str = "levenberg-marquardt, 3 starts", file=None,
                        index: int = 0, segments=None) -> FitResult:
    """A ``FitResult`` from one record's ``core.Summary`` (numpy): the values, errors, status and
    message that ``fit`` and ``batch`` both report. ``segments``: the record's ``Segments``, which say
    what a record without a usable band holds instead (``spectral.diagnose``)."""
    res = FitResult(model=model, solver=solver, file=file, index=index)
    theta, free = np.asarray(s.theta), np.asarray(s.free, bool)
    status = FIT_CODES[int(s.status)]
    res.status = status
    res.converged = bool(s.converged)
    res.n_bins = int(s.n_bins)
    res.cross_pairs = int(np.asarray(s.data.mask_xy).any(axis=-1).sum())
    if status == Status.NO_BAND:
        return no_band_result(res, res.n_bins, s.located.k0, segments)
    _set_k0(res, s.located.k0)
    if status == Status.FAILED:
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
    res.error_scales = {name: float(scales[_I["log_" + name]]) for name in OWN_SCALE_PARAMS
                        if free[_I["log_" + name]]}
    res.error_method = ("laplace x jackknife (vx, vy, a each their own)" if bool(s.jackknife)
                        else "laplace x max(redchi, 1) x bin_factor")
    spread = [name for name in OWN_SCALE_PARAMS if np.asarray(s.spread, bool)[_I["log_" + name]]]   # free ones
    if spread:
        res.error_method += f"; {', '.join(spread)} from the misfit's spread across frequency"
    cov = np.asarray(s.cov)
    fidx = np.flatnonzero(free)
    sub = cov[np.ix_(fidx, fidx)]
    dsd = np.sqrt(np.clip(np.diag(sub), 1e-300, None))
    res.correlations = sub / np.outer(dsd, dsd)
    sd = np.asarray(s.sd)
    notes = []
    if status == Status.NOT_CONVERGED:
        notes.append("the solver did not converge (fixed-iteration Levenberg-Marquardt)")
    elif bool(s.settled):
        notes.append("the solver stopped with texture knots still moving; a full Gauss-Newton step moves the speeds, "
                     f"radius and gains by less than {STEP_TOL} sigma, so their values and errors stand")
    speeds = {"vx": float(np.exp(theta[_I["log_vx"]])), "vy": float(np.exp(theta[_I["log_vy"]]))}
    for axis, name in enumerate(("vx", "vy")):
        i, v = _I["log_" + name], speeds[name]
        if not free[i]:         # a known velocity, or a minor speed held at 0 (slip along an axis)
            res.set(name, value=float(abs(velocity[axis])) if velocity is not None else 0.0, fixed=True)
            continue
        err = v * float(sd[i])
        res.set(name, value=v, err=err)
        if err > 0.5 * v or v < 1e-3 * max(speeds.values()):
            notes.append(f"{name} is consistent with 0")
    i_a = _I["log_a"]
    a = float(np.exp(theta[i_a]))
    a_err = a * float(sd[i_a])
    if not free[i_a]:
        res.set("a", lower=a)
        notes.append(f"the contact window is held negligible (a > {1e3 * a:.3g} mm)")
    elif window_weak or a_err > 0.5 * a or a > 0.5 * A_BOUNDS[1]:
        notes.append("the contact window is too weak to measure a")
    else:
        res.set("a", value=a, err=a_err)
    for name, param in (("gain_ratio", "log_gx"), ("gain_ratio_y", "log_gy")):
        i = _I[param]
        g = float(np.exp(theta[i]))
        res.set(name, value=g, err=g * float(sd[i]) if free[i] else None, fixed=not free[i])
    set_contact_depth(res, curvature_radius)
    if spread:
        notes.append(f"the errors of {', '.join(spread)} come from the misfit's spread across frequency, "
                     + ("above the segments' scatter" if status == Status.POOR_FIT
                        else "2x or more the segments' scatter"))
    if res.cond > 1e10:
        notes.append(f"near-degenerate parameters (condition number {res.cond:.2g}): see the correlations")
    lumps = np.asarray(s.data.lump_sd, float) if s.data is not None else np.zeros(1)
    if lumps.any():
        what = ("lumpy texture: the texture's power at each bin and its spread along the bin's line k . v = omega "
                f"fitted as random effects (sd {float(np.hypot(lumps[0], lumps[1])):.2f} in log power), as a "
                "texture of a few hundred persistent modes needs")
        notes.insert(0, what if status != Status.POOR_FIT else
                     f"poor fit, {what}; the spectra still scatter {res.redchi:.1f}x their noise (trend ratio "
                     f"{float(s.roughness):.1f}): the errors come from that scatter")
    elif status == Status.POOR_FIT and bool(s.lumpy):
        notes.insert(0, f"poor fit, lumpy texture: the spectra scatter {res.redchi:.1f}x their noise from bin to bin "
                        f"with no trend across frequency (trend ratio {float(s.roughness):.1f}), as a texture of a few "
                        "hundred persistent modes makes them; the values are the smooth texture model's, with errors "
                        "from that scatter")
    elif status == Status.POOR_FIT and np.isfinite(float(s.roughness)):
        notes.insert(0, f"poor fit: reduced chi-square {res.redchi:.1f}, trend ratio {float(s.roughness):.1f} across "
                        "frequency; the joint model does not describe these spectra (a line texture, another window, "
                        "or a wrong basin): check the plot before trusting the numbers")
    elif status == Status.POOR_FIT:
        notes.insert(0, f"poor fit: reduced chi-square {res.redchi:.1f}; the band is too narrow to test the misfit for "
                        f"a trend across frequency (no series of {ROUGHNESS_MIN_ROWS} bins), so a lumpy texture cannot "
                        "be told from a model that does not describe these spectra (a line texture, another window, or "
                        "a wrong basin): check the plot before trusting the numbers")
    n_leak = int(s.located.n_leak)
    if n_leak:
        res.warnings.append(f"{n_leak} coherent bins dropped as spectral leakage between texture lines")
    res.message = "; ".join(notes)
    return res


def texture_sections(s: Summary) -> tuple:
    """The pipeline's Eq. 18/19 cross-sections (``core.texture_sections``) on each pair's fitted bins."""
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
