"""Joint estimation of slip velocity, contact radius, gains and texture spectrum, with error bars.

``fit_recording`` (probe signals) and ``fit_spectra`` (recorded spectra) run
the same pipeline: spectra -> usable band (coherent bins that are not mere
leakage) -> closed-form and single-pair starting values -> the joint 2-D model
of ``joint_model`` fitted by Levenberg-Marquardt (``lsq``) -> Laplace errors,
bounds for what the data cannot determine, texture cross-sections (Eq. 18-19).
Nothing here raises on a fit that fails: the result's ``status`` and
``message`` say why (bad input still raises ``TactileInputError`` in
``fit_recording``/``fit_spectra``; ``fit_file`` turns it into a status).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.special

from ._numerics import tiny
from . import cross_pair, jackknife
from . import joint_model as jm
from . import model_select
from .closed_form import dominant_wavenumber, slope_speed
from .errors import TactileInputError
from .lsq import DOGLEG, STEP_TOL, LsqResult, least_squares
from .pair_fit import Leakage, centroid_shift, fit_pair, kernel_log_weights, noise_err_from_slope
from .problem import FitProblem
from .r_curve import log_g
from .recording import Recording, validate_recording
from .sensor import PAPER_SENSOR
from .prewhiten import filter_gain, filter_response
from .spectra import (CrossSpectra, amplitude_ratio, conditioned_psd, estimate_spectra, neighbour_log_ratio_err,
                      usable_band, whitened_psd)

__all__ = ["FitOptions", "FitResult", "TextureSection", "fit_recording", "fit_cross_spectra", "fit_spectra", "model_curves",
           "RESULT_FIELDS"]

#: the data contract's result fields, in order (DESIGN.md); more follow in ``FitResult.to_record``
RESULT_FIELDS = ("file", "index", "vx", "vx_err", "vy", "vy_err", "a", "a_err", "contact_depth",
                 "contact_depth_err", "gain_ratio", "gain_ratio_err", "k0x", "k0y", "model", "window",
                 "converged", "status", "message")

_log_g = jax.jit(log_g)
_A_BOUNDS = (1e-5, 0.1)
_POOR_FIT_REDCHI = 4.0          # above: status "poor_fit" (good fits of simulated scenes stay below 3)
_GRID_MARGIN = 6.0               # bins of model grid beyond the fitted bins (>= any kernel's reach)
_V_BOUNDS = (1e-6, 10.0)         # m/s
#: LM tolerances (optimistix rtol = atol): stage 1 only makes a start, profile refits only need chi2 to
#: well below the bound's threshold. Against 1e-8 everywhere, on 12 coverage scenes: the same values
#: and errors to 3e-4 sigma, 1.6x less time (benchmarks/README.md, "Profile")
_TOL = {"stage1": 1e-3, "full": 1e-6, "profile": 1e-4}
#: a speed component below this fraction of the other gets a profile-likelihood interval (``FitResult.vx_lo``)
MINOR_PROFILE = 0.3


@dataclasses.dataclass(frozen=True)
class FitOptions:
    """How to fit a scene (SI units). Defaults suit the paper's sensor at 1 kHz.

    method, prewhiten, nperseg: spectral estimator (``spectra.estimate_spectra``).
    velocity: known (|vx|, |vy|) in m/s (the arm's command, paper section 4.3): held fixed.
    gain_ratio: known deep/shallow gain ratios (gx, gy) or one for both; None: the
        file's ``gain_ratio`` if any, else 1. ``fit_gain``: fit them instead.
    noise_floor: fit a white noise floor on the shallow probes.
    n_knots: knots of the isotropic log texture spectrum; smoothness: the prior sd of
        its second differences between knots (smaller: smoother).
    min_snr, max_err, fmin, fmax: usable-band selection (``spectra.usable_band``; Hz).
    band_neighbours: judge each bin by its 2 n neighbours' coherence, not its own, both for the
        band (``spectra.usable_band(neighbours=...)``: no selection bias at the band edge) and for
        the ratio's errors (``spectra.neighbour_log_ratio_err``: no weighting bias; with the bin's
        own, |v| came out +0.8 +/- 0.3 % high at 1.2 cm/s, 50 dB; benchmarks/README.md, "Session 10").
    profile_minor: give a speed component below ``MINOR_PROFILE`` of the other a
        profile-likelihood interval (``FitResult.vx_lo`` ...; adds 2-5 s to such a fit).
    min_band_bins: the joint fit's Welch segment is lengthened until the faster pair's
        band holds this many usable bins (``resolution_segment``); 0: the slope rule alone.
        8 changed 8 of the 100 coverage scenes (slow slips and large contacts, 11-20 bins
        -> 28-66, errors 2-5x smaller) and rescued short slow recordings (8 s, 1.5 cm/s:
        6 bins and poor_fit -> 18 bins, |v| within 0.2 %); 12 also moved scenes that had
        ~20 bins, with no gain (benchmarks/README.md, "Session 7").
    leakage_db: a bin whose shallow PSD lies this far below the highest within
        +/- 3 bins holds only spectral leakage (of a line texture) and is dropped.
    window_term: model each bin's realised window average (``joint_model.ModelData.centroid_shift``,
        from Welch spectra's ``centroid``) and weight the ratio by its errors of noise alone
        (``pair_fit.noise_err_from_slope``): one more solve from the window-average fit. Off by
        default: on issue 3's 40 scenes at 50 dB it changed nothing beyond noise (both speeds within
        2 % of |v| in 33 against 34, a within 5 % in 38 and 38; benchmarks/README.md, "Session 9"),
        where the pair fit gains 2-5x at 45-60 dB.
    conditioned: fit each pair's conditioned deep PSD S22.1 = S22 - |S12|^2 / S11 too
        (``joint_model.ModelData.log_c22``): the deep power the shallow probe does not explain,
        which 2-D slip through a small contact sets. On issue 3's 40 scenes at 50 dB it halved
        the minor speed's and a's scatter at 4-8 cm/s (rms 0.66 -> 0.33 % of |v|, 0.92 -> 0.45 %)
        and vy's at 1-2 cm/s (4.1 -> 2.3 %); benchmarks/README.md, "Session 10". False: the
        ratio and the shallow PSD alone (the same compiled model, S22.1 masked out).
    cross_pairs: fit the y pair conditioned on the x pair (``cross_pair``), which brings in the
        cross-pair spectra: None (default) 2 where the spectra have the x-y cross-spectra (a
        recording's) and 0 where not (spectra files), 0 off (each pair's spectra as if the pairs
        were independent), 1 y1 given (x1, x2) in place of y1's PSD, 2 also y2 given (x1, x2, y1) in
        place of the y pair's ratio and S22.1 (1 or 2 on spectra without ``xy``: off, with a warning).
        The batch (``batch_fit``) does not build the chain. On 500 coverage scenes the chain brought
        both speeds within 2 % of |v| in 391 of 425 small contacts (without: 364), with 2-sigma
        coverage 96.2 / 95.4 / 95.6 % for vx / vy / a (without: 95.2 / 94.8 / 94.6). Its vx 1-sigma
        intervals are too wide: they cover 74.6 % (without: 68.4 %), mostly where x is the major
        component. Its first fit compiles for about twice as long (65 s against 29 s). README,
        "Session 17: 500 scenes".
    solver: "optimistix" (Levenberg-Marquardt) or "jaxopt" (for comparison).
    window: "gaussian" (the joint model's window).
    model: the scene model (``model_select.MODELS``): None (default: slip and contact
        window, plus gains / noise floor as ``fit_gain`` / ``noise_floor`` say), "slip"
        (window negligible), "window", "window+gain", "window+noise", "window+gain+noise"
        (these set the two flags), "hertz" (each pair with the Hertz curve) or "auto"
        (chosen per recording by BIC; the choice and margin are in the result).
    """

    method: str = "welch"
    prewhiten: int | None = 8
    nperseg: int | None = None
    velocity: tuple[float, float] | None = None
    gain_ratio: Any = None
    fit_gain: bool = False
    noise_floor: bool = False
    n_knots: int = 12
    smoothness: float = 1.0
    min_snr: float = 1.0
    max_err: float = 0.5
    band_neighbours: int = 3
    profile_minor: bool = True
    min_band_bins: int = 8
    fmin: float | None = None
    fmax: float | None = None
    leakage_db: float = 20.0
    window_term: bool = False
    conditioned: bool = True
    cross_pairs: int | None = None
    solver: str = "optimistix"
    window: str = "gaussian"
    model: str | None = None


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
    solver reported success, or a full Gauss-Newton step would move every physical parameter by
    less than ``lsq.STEP_TOL`` sigma, or 256 more Dogleg steps moved each by less than that
    (a warning then says that texture knots were still moving).
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


# --------------------------------------------------------------------------- bands


def leakage_only(psd, half_width: int = 3, drop_db: float = 20.0):
    """Bins whose PSD is ``drop_db`` below the highest within +/- ``half_width`` bins: (..., M) bool.

    Between the lines of a periodic texture the bins hold only the spectral
    window's leakage from the lines: coherent, but their ratio is the lines'.
    jnp, so that the batch's compiled spectral stage uses it too.
    """
    p = jnp.asarray(psd)
    m = p.shape[-1]
    pad = jnp.pad(p, [(0, 0)] * (p.ndim - 1) + [(half_width, half_width)], mode="edge")
    local_max = pad[..., 0:m]
    for k in range(1, 2 * half_width + 1):
        local_max = jnp.maximum(local_max, pad[..., k:k + m])
    return p < local_max * 10.0 ** (-drop_db / 10.0)


def _bucket(n: int) -> int:
    """Round a bin count up to a power of two (at least 32): few shapes, few compilations."""
    return max(32, 1 << (max(n, 1) - 1).bit_length())


# --------------------------------------------------------------------------- the pipeline


def fit_recording(rec: Recording, options: FitOptions = FitOptions(), *, record: int = 0) -> FitResult:
    """Fit one record of a recording. Raises ``TactileInputError`` for bad input."""
    validate_recording(rec)
    one = rec.record(record)
    src = rec.source or "<recording>"
    signals = np.asarray(one.signals)
    precision = "float64" if jax.config.jax_enable_x64 else "float32"
    if precision == "float64":
        signals = signals.astype(np.float64)
    kw = {"nperseg": options.nperseg} if (options.nperseg and options.method == "welch") else {}
    try:
        spec = estimate_spectra(signals, one.fs, method=options.method, prewhiten=options.prewhiten, **kw)
        if options.method == "welch" and not options.nperseg:
            finer = _resolution_nperseg(spec, one.depths, signals.shape[-1], options,
                                        min_band_bins=options.min_band_bins)
            if finer:
                spec = estimate_spectra(signals, one.fs, method="welch", prewhiten=options.prewhiten, nperseg=finer)
        # the same estimator with each segment (taper) left out in turn: the jackknife of the errors
        loo_kw = {**kw, "nperseg": 2 * (spec.omega.size - 1)} if options.method == "welch" else kw
        loo = (estimate_spectra(signals, one.fs, method=options.method, prewhiten=options.prewhiten,
                                leave_one_out=True, **loo_kw) if spec.n_segments >= _MIN_JACKKNIFE else None)
    except TactileInputError as err:
        raise err.with_source(src) from None
    options = _options_from_file(options, one)
    res = fit_cross_spectra(spec, one.depths, options, curvature_radius=one.curvature_radius, leave_one_out=loo)
    res.file, res.index, res.truth, res.precision = rec.source, record, dict(one.truth), precision
    return res


#: the log ratio may change by at most this much across one bin (resolution of slow slips)
_MAX_LOG_STEP_PER_BIN = 0.15
#: a pair fit (3-parameter curve on the band alone) wants at least this many usable bins in the
#: faster pair's band: longer segments (more, narrower bins). benchmarks/README.md, "Speed vs error"
MIN_PAIR_BAND_BINS = 24
#: the longest segment leaves at least this many half-overlapping segments to average
_MIN_SEGMENTS = 6
#: fewest segments (tapers) for jackknife error bars; below, the Laplace errors x bin_factor
_MIN_JACKKNIFE = 5
#: the parameters with their own error scale (theta[:3]); every later one has the pooled scale
OWN_SCALE_PARAMS = ("vx", "vy", "a")


def _resolution_nperseg(spec, depths, n_samples: int, options: FitOptions, *, min_band_bins: int = 0) -> int | None:
    """A longer Welch segment when the band is poorly resolved (slow slips), else None.

    ``resolution_segment`` at the faster pair's Eq. 6 speed (and usable-bin count
    when ``min_band_bins``: pair fits pass ``MIN_PAIR_BAND_BINS``; the joint fit a
    floor, ``FitOptions.min_band_bins``, as halving its averages to reach 24 bins cost
    it more than the bins gained, while a band of 5-10 bins cannot fix the direction).
    """
    ratio = amplitude_ratio(spec)
    band = np.asarray(usable_band(ratio, min_snr=options.min_snr, max_err=options.max_err,
                                  neighbours=options.band_neighbours))
    counts = band.sum(axis=-1)
    speeds, ok = np.full(2, np.nan), np.zeros(2, bool)
    for p in range(2):
        if counts[p] >= 3:
            f = slope_speed(ratio.omega, ratio.log_ratio[p], ratio.log_ratio_err[p], band[p], *depths)
            ok[p] = bool(f.ok)
            speeds[p] = float(f.speed)
    nperseg = 2 * (np.asarray(spec.omega).size - 1)
    fs = float(spec.omega[1] - spec.omega[0]) * nperseg / (2 * math.pi)
    # no pair with a slope (a slow slip at low SNR, a band of a few Hz: speed_vs_error's 10 dB, 1.5 cm/s
    # recording has 3 + 1 bins at 512, 9 + 6 at 2048): the widest band is stretched by its bin count alone
    want = int(resolution_wants(speeds[None], ok[None], np.array([fs]), np.asarray(depths, float)[None], n_samples,
                                nperseg, n_band=counts[None], min_band_bins=min_band_bins)[0])
    return want if want > nperseg else None


def resolution_segment(speed, fs, depths, n_samples: int, *, n_band=None, nperseg=None,
                       min_band_bins: int = MIN_PAIR_BAND_BINS):
    """Welch segment (samples) that resolves the log ratio's band; numpy, elementwise.

    Two rules, the longer wins, rounded up to a power of two and capped so that at
    least 6 half-overlapping segments remain (``2 N / 7``):

    - the ratio falls as exp(-(d2 - d1) omega / v) and a bin is 2 pi fs / nperseg
      wide: nperseg >= 2 pi fs (d2 - d1) / (0.15 v) keeps the fall below 0.15 per bin;
    - with ``n_band`` usable bins at the current ``nperseg``, the band is stretched
      to at least ``min_band_bins`` (the band's width in Hz stays put as bins narrow; 0:
      no such rule). The Eq. 6 speed overestimates |v| under a small contact (by
      30-165 %), so the first rule alone misses slow slips (benchmarks/README.md,
      "Speed vs error").

    speed in m/s, fs in Hz, depths (..., 2) in m.
    """
    depths = np.asarray(depths, float)
    eps = depths[..., 1] - depths[..., 0]
    want = 2 * np.pi * np.asarray(fs) * eps / (_MAX_LOG_STEP_PER_BIN * np.asarray(speed))
    if n_band is not None and nperseg is not None:
        stretch = min_band_bins / np.maximum(np.asarray(n_band, float), 1.0)
        want = np.maximum(want, np.asarray(nperseg) * np.where(stretch > 1.0, stretch, 0.0))
    cap = 1 << ((2 * int(n_samples) // (_MIN_SEGMENTS + 1)).bit_length() - 1)
    return np.minimum(2.0 ** np.ceil(np.log2(np.maximum(want, 1.0))), cap)


def resolution_wants(speed0, line_ok, fs, depths, n_samples: int, nperseg0: int, n_band=None,
                     min_band_bins: int = MIN_PAIR_BAND_BINS) -> np.ndarray:
    """(B,) the Welch segment each record wants (``resolution_segment``), 0 where it has nothing to go by.

    A record wants the segment that resolves its faster pair's band (at most 0.15 of log ratio per
    bin at its Eq. 6 speed, and at least ``min_band_bins`` usable bins given the ``n_band`` it has
    at ``nperseg0``), and at least ``nperseg0`` (the default). A record with no Eq. 6 speed on
    either pair but some usable bins (a slow slip at low SNR: a band 1-3 bins wide) wants its
    widest band stretched to ``min_band_bins`` by its bin count alone (``_resolution_nperseg``, the batch).
    speed0: (B, 2) m/s, line_ok: (B, 2) bool, fs: (B,) Hz, depths: (B, 2) m, n_band: (B, 2) or None.
    """
    v = np.where(line_ok, speed0, np.nan)
    have = np.isfinite(v).any(axis=-1)
    fast = np.argmax(np.where(np.isfinite(v), v, -np.inf), axis=-1)[:, None]
    v_fast = np.take_along_axis(v, fast, axis=-1)[:, 0]
    count = None
    if n_band is not None and min_band_bins:
        n_band = np.asarray(n_band)
        count = np.where(have, np.take_along_axis(n_band, fast, axis=-1)[:, 0], n_band.max(axis=-1))
        have |= count > 0                       # no slope: the bin count alone (speed inf)
        v_fast = np.where(np.isfinite(v_fast), v_fast, np.inf)
        count = count[have]
    wants = np.zeros(v.shape[0], int)
    if have.any():
        wants[have] = np.maximum(resolution_segment(v_fast[have], np.asarray(fs)[have], np.asarray(depths)[have],
                                                    n_samples, n_band=count, nperseg=nperseg0,
                                                    min_band_bins=min_band_bins), nperseg0)
    return wants


def _options_from_file(options: FitOptions, rec) -> FitOptions:
    if options.velocity is None and rec.velocity is not None:
        options = dataclasses.replace(options, velocity=tuple(abs(float(v)) for v in rec.velocity))
    if options.gain_ratio is None and rec.gain_ratio is not None:
        options = dataclasses.replace(options, gain_ratio=rec.gain_ratio)
    return options


def fit_spectra(data, options: FitOptions = FitOptions()) -> FitResult:
    """Fit recorded spectra (``io.SpectraData``): PSD/CSD through the joint model, ratios alone per pair."""
    options = _options_from_file(options, data)
    omega = np.asarray(data.omega, float)
    if data.psd is not None and data.csd is not None:
        m = omega.size
        d_omega = np.diff(omega)
        if m < 8 or not np.allclose(d_omega, d_omega[0], rtol=1e-6):
            raise TactileInputError("fitting PSD/CSD needs at least 8 uniformly spaced omega bins",
                                    source=data.source, code="bad_shape")
        k = float(data.n_segments) if data.n_segments else 1.0
        if not data.n_segments:
            options_msg = "n_segments not given: errors assume 1 segment (very conservative)"
        else:
            options_msg = ""
        estimator = {"kernel": _file_kernel(data)}
        if data.bin_factor is not None:
            estimator["bin_factor"] = float(data.bin_factor)
        if data.whitening is not None:
            estimator.update(whitening=jnp.asarray(data.whitening), fs=jnp.asarray(float(data.fs)))
        spec = CrossSpectra(jnp.asarray(omega / (2 * np.pi)), jnp.asarray(omega), jnp.asarray(data.psd, float),
                            jnp.asarray(data.csd, complex), int(round(k)), k, "given", **estimator)
        res = fit_cross_spectra(spec, data.depths, options, curvature_radius=data.curvature_radius)
        if options_msg:
            res.warnings.append(options_msg)
        res.file = data.source
        return res
    return _fit_ratio_only(data, options)


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


def fit_cross_spectra(spec: CrossSpectra, depths, options: FitOptions = FitOptions(), *,
                      curvature_radius=None, leave_one_out: CrossSpectra | None = None) -> FitResult:
    """Fit the joint model to estimated spectra. Never raises for a fit that fails: see ``status``.

    leave_one_out: the same estimator's delete-one-segment spectra
    (``estimate_spectra(..., leave_one_out=True)``): the error bars are then
    scaled by their jackknife; without, by the spectra's ``bin_factor``.
    """
    try:
        options = model_select.options_for(options)
        if options.model == "hertz":            # the joint model is Gaussian only: each pair alone
            return model_select.fit_hertz(spec, depths, options, curvature_radius)
        return _fit_cross_spectra(spec, depths, options, curvature_radius, leave_one_out)
    except TactileInputError:
        raise
    except Exception as err:  # a bug or a numerical corner must not sink a batch: report it as data
        return FitResult(window=options.window, solver=options.solver, status="failed",
                         message=f"the fit failed: {type(err).__name__}: {' '.join(str(err).split())}")


def _fit_cross_spectra(spec, depths, options, curvature_radius, leave_one_out=None) -> FitResult:
    d1, d2 = (float(v) for v in depths)
    res = FitResult(window=options.window, solver=options.solver)
    if options.window != "gaussian":
        res.status = "unsupported"
        res.message = f"the joint model has the Gaussian window only; window {options.window!r} is not fitted"
        return res
    if options.cross_pairs not in (None, 0, 1, 2):
        res.status = "unsupported"
        res.message = f"cross_pairs must be None (the chain where it can be built), 0, 1 or 2, not {options.cross_pairs!r}"
        return res
    ratio = amplitude_ratio(spec)
    band = np.asarray(usable_band(ratio, min_snr=options.min_snr, max_err=options.max_err,
                                  fmin=options.fmin, fmax=options.fmax, neighbours=options.band_neighbours))
    psd = np.asarray(spec.psd)
    shallow = psd[[0, 2]]
    leak = np.asarray(leakage_only(shallow, drop_db=options.leakage_db))
    n_leak = int((band & leak).sum())
    band = band & ~leak
    omega = np.asarray(spec.omega)
    if band.sum() < 6:
        res.status = "no_band"
        res.message = (f"only {int(band.sum())} usable bins (coherent, deep probe above noise, not leakage): "
                       "too few to fit; check the gains, the SNR or the band limits")
        return res
    used = np.flatnonzero(band.any(axis=0))
    i0 = int(used[0])                                       # never DC: usable_band needs omega > 0
    length = _bucket(int(used[-1]) - i0 + 1)
    idx = np.arange(i0, i0 + length)
    valid = idx < omega.size
    idx = np.where(valid, idx, omega.size - 1)
    d_omega = float(omega[1] - omega[0])
    # bins (extrapolated past the end if needed); spectra files may start above DC
    om = float(omega[i0]) + d_omega * np.arange(length)
    offsets, weights = (np.asarray(v, float) for v in spec.kernel)
    # a fixed grid margin (bins) so every kernel gives the same shapes: one compilation
    half = max(float(np.max(np.abs(offsets))), _GRID_MARGIN)
    grid = np.arange(om[0] - half * d_omega, om[-1] + (half + 0.25) * d_omega, 0.5 * d_omega)
    kernel = np.zeros((length, grid.size))
    for o, w in zip(offsets, weights):
        pos = np.rint(((om + o * d_omega) - grid[0]) / (0.5 * d_omega)).astype(int)
        kernel[np.arange(length), pos] += w
    # errors (hence weights) from the neighbours' coherence: the bin's own would weight up the bins whose
    # ratio came out high (``spectra.neighbour_log_ratio_err``)
    ratio_np = (np.asarray(ratio.log_ratio), np.asarray(neighbour_log_ratio_err(ratio, options.band_neighbours)))
    mask_h = band[:, idx] & valid
    log_s11 = np.log(np.clip(shallow[:, idx], 1e-300, None))
    lr = np.where(mask_h, ratio_np[0][:, idx], 0.0)
    lr_err = np.where(mask_h, ratio_np[1][:, idx], 1.0)

    # ---- starting values: each pair alone (closed form, then exact R curve). The flat window here:
    # with the spectrum-weighted one (``fit_pair(spectrum=)``) an 8 s, 30 dB, 1.5 cm/s slip along x
    # started the joint fit into a wrong basin of LOWER chi-square (vx 0.66 cm/s, vy 1.9 +/- 0.5 cm/s
    # for a truth of 0, status ok) where these starts end in poor_fit: kept until that is understood
    gains = _gains(options)
    starts = []
    for p in range(2):
        sel = band[p]
        if sel.sum() >= 5:
            f = fit_pair(omega, ratio_np[0][p], ratio_np[1][p], sel, d1, d2, gain_ratio=gains[p],
                         kernel=spec.kernel)
            starts.append(f if (f.converged and np.isfinite(f.speed)) else None)
        else:
            starts.append(None)
    if options.velocity is not None:
        v0 = [max(abs(float(v)), 0.0) for v in options.velocity]
    else:
        v0 = [s.speed if s is not None else np.nan for s in starts]
        known = [v for v in v0 if np.isfinite(v)]
        fallback = 0.05 * max(known) if known else 0.02
        v0 = [v if np.isfinite(v) else fallback for v in v0]
    a_fits = [s for s in starts if s is not None and np.isfinite(s.a) and s.a_err > 0]
    a0 = min(a_fits, key=lambda s: s.a_err / s.a).a if a_fits else 2e-3
    a0 = float(np.clip(a0, 2 * _A_BOUNDS[0], 0.5 * _A_BOUNDS[1]))
    v_scale = max(max(v0), 1e-4)
    v_fixed_floor = 1e-3 * v_scale                          # a known zero component, in log space
    log_v0 = [np.log(max(v, v_fixed_floor if options.velocity is not None else 1e-3 * v_scale)) for v in v0]

    # ---- texture knots and their start from the shallow spectrum of the faster pair that has a band
    with_band = [p for p in range(2) if band[p].sum() >= 1]
    main = max(with_band, key=lambda p: v0[p])
    k_lo = 0.5 * om[0] / max(v0)
    k_hi = 25.0 / (2.0 * d1)
    knots = np.geomspace(k_lo, max(k_hi, 4 * k_lo), options.n_knots)
    sel = band[main]
    k_obs = omega[sel] / v0[main]
    g1 = np.asarray(_log_g(k_obs, d1, a0))
    phi_obs = np.log(np.clip(shallow[main][sel], 1e-300, None)) + np.log(v0[main]) - 2 * g1 - np.log(np.sqrt(3 * np.pi) / a0)
    log_phi0 = np.interp(np.log(knots), np.log(k_obs), phi_obs)
    noise0 = float(np.log(np.median(shallow[:, -omega.size // 4:]) + 1e-300))

    theta0 = np.concatenate([[log_v0[0], log_v0[1], np.log(a0), np.log(gains[0]), np.log(gains[1]), 0.0,
                              noise0 if options.noise_floor else -700.0], log_phi0])
    names = jm.param_names(options.n_knots)
    free = np.ones(theta0.size, bool)
    if options.velocity is not None:
        free[[0, 1]] = False
    if not options.fit_gain:
        free[[3, 4]] = False
    if not options.noise_floor:
        free[6] = False
    if not band[1].any():
        free[5] = False                                     # nothing measures the y pair's level
    # every residual is weighted as if bins were independent; their correlation (bin_factor) scales
    # the covariance in ``_fill``, so that the reduced chi-square of a good fit stays near 1
    s11_weight = np.sqrt(spec.dof)
    # weak priors: a factor e^3 on speeds and radius around the single-pair starts, e^2 on fitted gains
    prior_inv_sd = np.zeros(theta0.size)
    prior_inv_sd[[0, 1, 2]] = 1.0 / 3.0
    prior_inv_sd[[3, 4]] = 0.5
    prior_inv_sd = np.where(free, prior_inv_sd, 0.0)
    if spec.whitening is not None:
        fs = jnp.asarray(spec.fs)
        white_grid = np.log(np.asarray(filter_gain(spec.whitening, jnp.asarray(np.abs(grid)), fs)))
        white_bin = np.log(np.asarray(filter_gain(spec.whitening, jnp.asarray(om), fs)))
    else:
        white_grid, white_bin = np.zeros((2, grid.size)), np.zeros((2, length))
    data = jm.ModelData(jnp.asarray(om), jnp.asarray(log_s11), jnp.asarray(lr), jnp.asarray(lr_err),
                        jnp.asarray(mask_h), jnp.asarray(mask_h), jnp.asarray(s11_weight),
                        jnp.asarray(np.abs(grid)), jnp.asarray(kernel), jnp.asarray(np.log(knots)),
                        jnp.asarray([d1, d2]), jnp.asarray(theta0), jnp.asarray(prior_inv_sd), jnp.asarray(1.0 / options.smoothness),
                        jnp.asarray(white_grid), jnp.asarray(white_bin),
                        *(jnp.asarray(v) for v in jm.banded_kernel(kernel)))
    # the window term's slots are always there, with a zero shift until the term is fitted: one compiled
    # model for every stage and for ``window_term`` on or off
    data = data._replace(edge_index=jnp.asarray(_edge_index(om, grid)), centroid_shift=jnp.zeros((2, length)))
    # the conditioned deep PSD's slots are always there too (masked out unless ``options.conditioned``)
    c22 = np.asarray(conditioned_psd(spec))[:, idx]
    data = data._replace(**conditioned_fields(jnp.asarray(c22), jnp.asarray(om), jnp.asarray(spec.psd), spec.omega,
                                              spec.dof, jnp.asarray(mask_h & valid), use=options.conditioned,
                                              noise_floor=options.noise_floor))
    start_data = data                       # the starts run on the model without the chain (below)
    blocks = 2 if options.cross_pairs is None else options.cross_pairs       # None: the chain where it can be built
    if blocks and spec.xy is not None and band[0].any() and band[1].any():
        data = data._replace(**chain_fields(spec, idx, jnp.asarray(om), data, blocks, grid))
        res.cross_pairs = int(min(blocks, 2))
    elif options.cross_pairs and spec.xy is None:
        res.warnings.append("cross_pairs: these spectra have no x-y cross-spectra; the pairs are fitted as if "
                            "independent")
    term = _window_term(spec, idx, valid) if options.window_term else None
    n_prior = jm.n_prior_residuals(theta0.size)
    # Several starts for the speeds: the single-pair fits mistake a pair that hears only window
    # leakage (slip across it) for a fast slip along it, so also try each axis as the major one.
    starts_v = [tuple(log_v0[:2])]
    if options.velocity is None:
        power = [float(np.sum(shallow[p][band[p]])) for p in range(2)]
        for major in (int(np.argmax(power)), int(np.argmin(power))):
            v_major = v0[major] if np.isfinite(v0[major]) else max(v0)
            cand = [np.log(v_major), np.log(v_major)]
            cand[1 - major] = np.log(0.15 * v_major)
            if all(np.max(np.abs(np.subtract(cand, c))) > 0.3 for c in starts_v):
                starts_v.append(tuple(cand))
    # With the chain the starts are screened on the model without it, whose LM steps cost a quarter as
    # much (0.012 s against 0.052 s, session 14), and the best is refined with it: the chain adds information, it does not move the basin
    # (session 13, coverage scene 4, 1.2 deg off x: the three starts and the refinement 43 s -> 18 s, the
    # same chi2 344.8)
    chained = data is not start_data
    fit = None
    for log_vs in starts_v:
        th0 = theta0.copy()
        th0[:2] = log_vs
        # stage 1: texture spectrum and y level with the physics held at the starting values
        stage1 = free.copy()
        stage1[:5] = False
        stage1[6] = False
        fit1 = least_squares(jm.residuals, jnp.asarray(th0), start_data, jnp.asarray(stage1), solver="optimistix",
                             max_steps=256, n_prior=n_prior, rtol=_TOL["stage1"], atol=_TOL["stage1"])
        theta1 = np.where(np.isfinite(np.asarray(fit1.theta)), np.asarray(fit1.theta), th0)
        tol = _TOL["profile" if chained else "full"]
        trial = least_squares(jm.residuals, jnp.asarray(theta1), start_data, jnp.asarray(free), solver=options.solver,
                              max_steps=256, n_prior=n_prior, rtol=tol, atol=tol)
        if fit is None or (np.isfinite(float(trial.chi2)) and float(trial.chi2) < float(fit.chi2)):
            fit = trial
    if chained:
        theta1 = np.where(np.isfinite(np.asarray(fit.theta)), np.asarray(fit.theta), theta0)
        fit = least_squares(jm.residuals, jnp.asarray(theta1), data, jnp.asarray(free), solver=options.solver,
                            max_steps=256, n_prior=n_prior, rtol=_TOL["full"], atol=_TOL["full"])
    fit, settled = _rescue(res, fit, data, free, n_prior, options.solver)
    settled_theta = np.asarray(fit.theta) if settled else None
    if term is not None:
        fit, data = _refit_window_term(fit, free, data, term, lr_err, mask_h, n_prior, options.solver)
    fit, free = _select_model(res, fit, free, data, options, n_prior, spec.bin_factor, noise0)
    scale = _error_scale(res, fit, free, data, spec, leave_one_out, idx, term)
    window_weak = False
    if options.model is None:                   # the default model: is the window needed at all?
        needed, note = model_select.window_needed(fit, free, data, n_prior=n_prior, solver=options.solver,
                                                  scale=float(scale[2]))
        window_weak = not needed
        if note:
            res.warnings.append(note)
    res.n_bins = int(mask_h.sum())
    res.spectrum = {"omega": om, "log_ratio": np.where(valid, ratio_np[0][:, idx], np.nan),
                    "log_ratio_err": np.where(valid, ratio_np[1][:, idx], np.nan), "mask": mask_h}
    if n_leak:
        res.warnings.append(f"{n_leak} coherent bins dropped as spectral leakage between texture lines")
    settled = settled_theta is not None and np.array_equal(np.asarray(fit.theta), settled_theta)  # no refit since
    _fill(res, fit, names, free, data, options, d1, d2, curvature_radius, scale=scale, window_weak=window_weak,
          settled=settled)
    _model_note(res)
    res.data = data
    # dominant wavenumbers (Eq. 4 / 17) where a pair's shallow spectrum has a single dominant line
    for p, attr in ((0, "k0x"), (1, "k0y")):
        k0 = float(dominant_line(shallow[p], ratio_np[0][p], band[p], np.log(gains[p]), d1, d2))
        setattr(res, attr, k0 if np.isfinite(k0) else None)
    return res


class _WindowTerm(NamedTuple):
    """A recording's realised window term on the joint fit's bins (``_window_term``)."""

    shift: np.ndarray           # (2, L) centroid less the weights' own, bins (0 past the spectra)
    leakage: tuple              # per pair, ``pair_fit.Leakage`` on the L bins: centroid - shift is the weights'


def conditioned_fields(c22, om, psd, omega, dof: float, mask, *, use: bool, noise_floor: bool) -> dict:
    """``joint_model.ModelData``'s S22.1 fields (``FitOptions.conditioned``); jnp, for ``fit`` and the batch.

    c22: (2, L) ``spectra.conditioned_psd`` at the fit's bins om (L,), rad/s; psd: (4, M)
    the four PSDs at omega (M,); mask: (2, L) the ratio's bins. DC and the first
    bin above it are left out (the segments' mean removal reshapes the spectral window there, which
    the ratio cancels and S22.1 does not). The white-noise PSDs are the medians of S11
    and S22 above 3/4 of the top frequency; with ``noise_floor`` the model's fitted floor
    is the shallow one. use False: the slots with nothing in them (one compiled model).
    """
    d_omega = omega[1] - omega[0]
    tail = jnp.where(omega >= 0.75 * omega[-1], psd, jnp.nan)
    noise = jnp.log(jnp.nanmedian(tail, axis=-1) + tiny(psd)).reshape(2, 2)          # [[x1, x2], [y1, y2]]
    if noise_floor:
        noise = noise.at[:, 0].set(-700.0)
    k1 = max(float(dof) - 1.0, 1.0)
    mask = mask & (c22 > 0) & (om >= 1.5 * d_omega)[None, :] & bool(use) & (float(dof) > 2.0)
    return {"log_c22": jnp.where(mask, jnp.log(jnp.where(mask, c22, 1.0)), 0.0), "mask_c22": mask,
            "c22_weight": jnp.asarray(math.sqrt(k1)),
            # E log of the estimate less that of S11's, which the model's level absorbs: psi(K-1) - psi(K). For
            # complex-Wishart (K) spectra S22.1 ~ S22.1 chi^2_2(K-1) / 2K and S11 ~ S11 chi^2_2K / 2K. On white noise
            # (16 s, Welch, K 28.5) log S22.1 - log S11 came out -0.041 on average; this offset is -0.036, the
            # psi(K-1) - log(K-1) used until session 12 was -0.018 and left S22.1 2 % low against the model
            "c22_offset": jnp.asarray(float(scipy.special.digamma(k1) - scipy.special.digamma(k1 + 1.0))),
            "log_noise_c22": noise}


def chain_fields(spec: CrossSpectra, idx, om, data: jm.ModelData, blocks: int, grid) -> dict:
    """``joint_model.ModelData``'s chain fields (``cross_pair``) at the bins ``idx`` (L,) of ``data``, and its
    masks with the y pair's blocks the chain replaces taken out (``FitOptions.cross_pairs``: 1 or 2 blocks).

    Each block uses the bins of what it replaces (y1's PSD; the y ratio), except DC and the first
    bin (as ``conditioned_fields``).
    """
    est = cross_pair.chain_estimate(spec.psd, spec.csd, spec.xy, spec.dof)
    weight, offset = cross_pair.chain_offsets(spec.dof)
    d_omega = spec.omega[1] - spec.omega[0]
    low = (om >= 1.5 * d_omega)
    mask = jnp.stack([data.mask_s11[1], data.mask_h[1] & (blocks >= 2)]) & est.ok[:, idx] & low[None]
    fields = {"xy_beta1": est.beta1[idx], "xy_beta2": est.beta2[idx], "xy_w1": est.w1[idx], "xy_w2": est.w2[idx],
              "log_xy_c": jnp.where(mask, est.log_c[:, idx], 0.0), "mask_xy": mask,
              "xy_c_weight": jnp.asarray(weight), "xy_c_offset": jnp.asarray(offset),
              "mask_s11": data.mask_s11.at[1].set(data.mask_s11[1] & ~mask[0]),
              "mask_h": data.mask_h.at[1].set(data.mask_h[1] & ~mask[1])}
    if data.mask_c22 is not None:
        fields["mask_c22"] = data.mask_c22.at[1].set(data.mask_c22[1] & ~mask[1])
    if spec.whitening is not None:                    # the signed grid: A(-omega) = conj(A(omega))
        fs = jnp.asarray(spec.fs)
        rg, rb = (filter_response(spec.whitening, jnp.asarray(w), fs) for w in (grid, om))
        fields["xy_white_grid"] = jnp.conj(rg[0]) * rg[1]
        fields["xy_white_bin"] = jnp.conj(rb[0]) * rb[1]
    return fields


def _edge_index(om, grid) -> np.ndarray:
    """(2, L) indices of om -+ half a bin on the half-bin ``grid`` (``joint_model.ModelData.edge_index``)."""
    d_omega = float(om[1] - om[0])
    return np.stack([np.rint((om + h * d_omega - grid[0]) / (0.5 * d_omega)).astype(np.int32) for h in (-0.5, 0.5)])


def _window_term(spec: CrossSpectra, idx, valid) -> _WindowTerm | None:
    """The joint model's realised window term from Welch spectra's centroids; None without them."""
    if spec.centroid is None or spec.spread is None:
        return None
    omega = np.asarray(spec.omega)
    seen = np.asarray(whitened_psd(spec))[0::2]
    centroid, spread = np.asarray(spec.centroid, float), np.asarray(spec.spread, float)
    shift = np.zeros((2, idx.size))
    leakage = []
    for p in range(2):
        offsets, log_w = kernel_log_weights(omega, spec.kernel, seen[p])
        full = centroid_shift(offsets, log_w, centroid[p])
        shift[p] = np.where(valid, full[idx], 0.0)
        leakage.append(Leakage(centroid[p][idx], spread[p][idx], float(spec.dof)))
    return _WindowTerm(shift, tuple(leakage))


def _refit_window_term(fit, free, data: jm.ModelData, term: _WindowTerm, lr_err, mask_h, n_prior, solver):
    """The fit with the window term, weighted by the ratio's noise-alone errors at the window-average fit."""
    slope = np.asarray(jm.ratio_slope(fit.theta, data))
    err = np.stack([noise_err_from_slope(lr_err[p], slope[p], mask_h[p], term.leakage[p]) for p in range(2)])
    data = data._replace(h_err=jnp.asarray(np.where(mask_h, err, 1.0)), centroid_shift=jnp.asarray(term.shift))
    trial = least_squares(jm.residuals, fit.theta, data, jnp.asarray(free), solver=solver, max_steps=256,
                          n_prior=n_prior, rtol=_TOL["full"], atol=_TOL["full"])
    ok = bool(np.all(np.isfinite(np.asarray(trial.theta)))) and np.isfinite(float(trial.chi2))
    # the fallback's Jacobian is that of the data without the term: not the one returned with it
    return (trial, data) if ok else (fit._replace(jac=None), data)


def _error_scale(res, fit, free, data, spec, leave_one_out, idx, term=None) -> np.ndarray:
    """The variance scales (P,) of the fit's unit covariance (J^T J)^-1; records how they were found in ``res``.

    With delete-one spectra (``joint_jackknife``): vx, vy and a each take their own
    jackknife variance over their Laplace one, the other parameters that ratio
    pooled over the three; never below the reduced chi-square (a misfit the
    segments share). ``res.error_scale`` is the pooled one.
    Without (recorded spectra, or too few segments): max(redchi, 1) x the spectra's
    ``bin_factor``, which counts adjacent bins as correlated as white noise's
    (Hann: 1.94); the log ratio's errors correlate by -0.23..+0.25, and the errors
    come out 1.0-2.1x too wide (benchmarks/README.md, "Error calibration").
    """
    redchi = float(fit.redchi)
    fallback = max(redchi, 1.0) * max(float(spec.bin_factor), 1.0)
    res.error_scale, res.error_method = fallback, "laplace x max(redchi, 1) x bin_factor"
    if leave_one_out is None:
        return np.full(len(free), fallback)
    k = leave_one_out.n_segments
    shift_k = None
    if term is not None and leave_one_out.centroid is not None:
        expected = np.stack([lk.centroid for lk in term.leakage]) - term.shift      # the weights' own centroid
        shift_k = np.where(data.mask_h, np.asarray(leave_one_out.centroid)[:, :, idx] - expected, 0.0)
    c22_k = conditioned_psd(leave_one_out) if data.log_c22 is not None and bool(np.any(data.mask_c22)) else None
    chain_k = None
    if data.xy_beta1 is not None and leave_one_out.xy is not None:
        chain_k = cross_pair.chain_estimate(leave_one_out.psd, leave_one_out.csd, leave_one_out.xy, spec.dof)
    var, var_unit, pooled, scale = (np.asarray(v) for v in joint_jackknife(
        fit.theta, jnp.asarray(free), data, amplitude_ratio(leave_one_out).log_ratio, leave_one_out.psd[:, 0::2],
        idx, k / leave_one_out.dof, fit.redchi, shift_k, c22_k, chain_k, fit.jac))
    ratios = {name: float(var[i] / var_unit[i]) for i, name in enumerate(OWN_SCALE_PARAMS)
              if free[i] and var_unit[i] > 0}
    res.jackknife = {"n_segments": k, "overlap": k / leave_one_out.dof, "variance_ratio": ratios,
                     "pooled": float(pooled), "redchi": redchi, "fallback": fallback}
    if not np.all(np.isfinite(scale)):
        return np.full(len(free), fallback)
    res.error_scale = float(scale[len(OWN_SCALE_PARAMS)])        # the pooled one, floored at redchi
    res.error_method = f"laplace x jackknife ({k} segments; vx, vy, a each their own)"
    return scale


def joint_jackknife(theta, free, data: jm.ModelData, log_ratio_k, shallow_k, idx, overlap, redchi, shift_k=None,
                    c22_k=None, chain_k=None, jac=None):
    """The delete-one-segment jackknife of a joint fit (jnp; the batch's compiled stage calls it too).

    log_ratio_k, shallow_k: (K, 2, M) log amplitude ratios and shallow PSDs of the
    K delete-one spectra; idx: (L,) the bins of ``data``; overlap: n_segments / dof.
    shift_k: (K, 2, L) their ``data.centroid_shift`` when the model has the window term, else None.
    c22_k: (K, 2, M) their conditioned deep PSDs (``spectra.conditioned_psd``) when the fit uses them, else None.
    chain_k: their ``cross_pair.ChainEstimate`` (leading axis K) when the fit has the chain, else None (the
        weights stay those of the full record).
    jac: the residuals' Jacobian at (theta, data) when the fit has it (``LsqResult.jac``), else None.
    Returns the jackknife and unit Laplace variances (P,), (P,), their ratio pooled
    over the free vx, vy, a, and the variance scales of the error bars (P,): each
    free vx, vy, a its own ratio, every other parameter the pooled one, never below
    ``redchi`` (NaN when nothing is pooled).

    Why not one pooled scale for all: the Laplace variances miss by different
    factors for different parameters. Coverage scene 4 (1.2 deg off x) redrawn 30
    times: vx's unit Laplace error matched its scatter (variance ratio 1.05) and its
    own jackknife ratio was 1.06, while the pooled 1.68 (a's ratio is larger) made
    the interval too wide. On 700 coverage scenes vx's 1-sigma intervals hold 72.1 %
    with each its own ratio and 74.2 % pooled (74.0 -> 72.0 % on the 200 scenes the
    rule was not chosen on; README, "Error bars: coverage"). The cost: one ratio is
    noisier than three pooled, and a recording whose ratio for a came out in the
    lowest quarter covered a 48 % of the time.
    """
    fields = {"log_h": jnp.where(data.mask_h, log_ratio_k[:, :, idx], 0.0),
              "log_s11": jnp.where(data.mask_s11, jnp.log(jnp.clip(shallow_k[:, :, idx], tiny(shallow_k), None)), 0.0)}
    if shift_k is not None:          # the window term's centroids change with the segment left out too
        fields["centroid_shift"] = jnp.asarray(shift_k)
    if c22_k is not None:
        fields["log_c22"] = jnp.where(data.mask_c22, jnp.log(jnp.clip(c22_k[:, :, idx], tiny(c22_k), None)), 0.0)
    if chain_k is not None:
        ok = chain_k.ok[:, :, idx]
        fields.update(xy_beta1=chain_k.beta1[:, idx], xy_beta2=chain_k.beta2[:, idx],
                      log_xy_c=jnp.where(data.mask_xy & ok, chain_k.log_c[:, :, idx], data.log_xy_c))
    shifts, unit = jackknife.linear_shifts(jm.residuals, theta, data, fields, free, jac)
    var, var_unit = jnp.diag(jackknife.covariance(shifts, overlap=overlap)), jnp.diag(unit)
    pooled, scale = jackknife.own_scales(var, var_unit, free & (jnp.arange(free.shape[0]) < len(OWN_SCALE_PARAMS)), redchi)
    return var, var_unit, pooled, scale


def _select_model(res, fit, free, data, options, n_prior, bin_factor, noise0):
    """Apply ``options.model`` (forced or "auto", ``model_select``): the chosen fit and free mask."""
    sel = model_select.select(fit, free, data, options, n_prior=n_prior, bin_factor=bin_factor, noise0=noise0)
    res.model, res.model_margin = sel.name, sel.margin
    if sel.note:
        res.warnings.append(sel.note)
    return sel.fit, sel.free


def _model_note(res):
    """Put the model choice first in the message; flag error bars larger than their values."""
    choice = [w for w in res.warnings if w.startswith("model ") and "chosen by" in w]
    if choice:
        res.warnings.remove(choice[0])
        res.message = "; ".join(m for m in (choice[0], res.message) if m)
    model_select.annotate(res)


def dominant_line(psd, log_ratio, band, log_gain, d1, d2):
    """Eq. 4 / 17 at the spectral peak when one line carries most of the band's power: k0 (rad/m) or NaN.

    A line: at least half the band's power within +/- 2 bins of the peak, at least 3
    band bins, and a peak 10x above the bins 3 away (not the edge of a falling
    spectrum). jnp on one pair's (M,) arrays; the batch vmaps it.
    """
    m = psd.shape[-1]
    p = jnp.where(band, psd, 0.0)
    i = jnp.argmax(p)
    near = jnp.abs(jnp.arange(m) - i) <= 2
    line = jnp.sum(jnp.where(near, p, 0.0)) >= 0.5 * jnp.sum(p)
    lo, hi = psd[jnp.clip(i - 3, 0, m - 1)], psd[jnp.clip(i + 3, 0, m - 1)]
    ok = line & (jnp.sum(band) >= 3) & (i >= 3) & (i + 3 < m) & (psd[i] > 10 * lo) & (psd[i] > 10 * hi)
    return jnp.where(ok, dominant_wavenumber(1.0, jnp.exp(log_ratio[i] - log_gain), d1, d2), jnp.nan)


def _contact_depth(res: FitResult, curvature_radius):
    r = float(curvature_radius) if curvature_radius else PAPER_SENSOR.curvature_radius
    res.curvature_radius = r
    if res.a is not None:
        res.contact_depth = res.a ** 2 / r
        res.contact_depth_err = None if res.a_err is None else 2 * res.a * res.a_err / r
    if not curvature_radius:
        res.warnings.append(f"curvature_radius not given: contact depth assumes R = {1e3 * r:g} mm")


def physics_settled(fit: LsqResult, free):
    """Whether every free non-texture parameter's |``step_sigma``| is below ``lsq.STEP_TOL`` (all of it
    finite): a stop at ``max_steps`` that leaves the physics where it is. jnp (the batch vmaps it)."""
    step = jnp.abs(jnp.asarray(fit.step_sigma))
    physics = jnp.asarray(free, bool) & (jnp.arange(step.shape[-1]) < jm.N_FIXED_PARAMS)
    return jnp.all(jnp.isfinite(step)) & jnp.any(physics) & jnp.all(jnp.where(physics, step < STEP_TOL, True))


def _physics_steps(fit: LsqResult, free):
    """Largest |step_sigma| of the free non-texture and of the texture parameters (NaN without it)."""
    step = None if fit.step_sigma is None else np.abs(np.asarray(fit.step_sigma))
    if step is None or not np.all(np.isfinite(step)):
        return np.nan, np.nan, None
    texture = np.arange(step.size) >= jm.N_FIXED_PARAMS
    free = np.asarray(free, bool)
    physics = free & ~texture
    top = float(step[physics].max()) if physics.any() else np.nan
    return top, float(step[free & texture].max(initial=0.0)), step


def _settled_physics(res: FitResult, fit: LsqResult, names, free) -> bool:
    """Whether a fit stopped at ``max_steps`` has its physics settled while texture knots still move.

    Near an axis, with the minor speed a few sigma from 0, the high-k knots (which only the
    leakage-dominated pair constrains) can crawl along a curved valley for thousands of LM steps
    (session 18, coverage scene 4 redrawn: 13 of 30 draws stopped with a decrement of 3-5 chi2
    while a full Gauss-Newton step moved vx by 0.02 sigma and log_phi_11 by 2.1 sigma). Settled:
    every free non-texture parameter's remaining step is below ``lsq.STEP_TOL`` of its sd. Then the
    reported values and errors stand, and a warning names the knots that were still moving.
    """
    if fit.step_sigma is None or not bool(physics_settled(fit, free)):
        return False
    top, top_texture, step = _physics_steps(fit, free)
    moving = [n for n, s, f in zip(names, step, free) if f and s >= STEP_TOL]
    res.warnings.append(
        f"the solver stopped at its step limit with texture knots still moving ({', '.join(moving)}: up to "
        f"{top_texture:.1f} sigma); a full Gauss-Newton step moves the speeds, radius and gains by at most "
        f"{top:.2f} sigma, so their values and errors stand; the texture spectrum there may not")
    return True


def _rescue(res: FitResult, fit: LsqResult, data, free, n_prior, solver) -> tuple[LsqResult, bool]:
    """LM stopped at ``max_steps`` with a physical parameter still moving: go on with Dogleg from there.

    Returns the fit to keep and whether its physics is settled by that continuation.
    Session 18: on coverage scene 4 (1.2 deg off x) redrawn, 7 of 30 draws stopped so with the minor
    vy 0.15-0.7 sigma from the step's end; from LM's stopping point Dogleg converged in 48 steps
    (decrement 4e-8) where LM gained < 1.7 chi2 in 512. Costs one more compiled program (about 20 s with
    the chain), only in the processes that need it. Kept if it converged.
    Session 20: on coverage scene 708 (exactly along y, vx consistent with 0) Dogleg did not converge
    either: the low-k texture knots crawl down as vx does. Its 256 steps moved vx, vy and a by at most
    0.05 sd (of LM's covariance) and the knots by up to 0.65 sd; 2048 more LM steps left the physics
    unchanged to 1e-4. Where Dogleg moves every free non-texture parameter by less than ``STEP_TOL`` of
    its sd, that measured displacement settles the physics, as ``_settled_physics`` does from the
    linearised step: the stop with the lower chi-square is kept, with a warning.
    """
    if solver != "optimistix" or bool(fit.converged) or not _physics_steps(fit, free)[0] >= STEP_TOL:
        return fit, False
    trial = least_squares(jm.residuals, fit.theta, data, jnp.asarray(free), solver=DOGLEG, max_steps=256,
                          n_prior=n_prior, rtol=_TOL["full"], atol=_TOL["full"])
    theta, theta0 = np.asarray(trial.theta), np.asarray(fit.theta)
    if not (np.all(np.isfinite(theta)) and np.isfinite(float(trial.chi2))):
        return fit, False
    if bool(trial.converged):
        res.warnings.append(f"Levenberg-Marquardt stopped at its step limit in a curved valley; optimistix's "
                            f"Dogleg went on from there and converged in {int(trial.n_steps)} steps")
        return trial, False
    free = np.asarray(free, bool)
    with np.errstate(invalid="ignore", divide="ignore"):
        moved = np.abs(theta - theta0) / np.sqrt(np.diag(np.asarray(fit.cov)))
    physics = free & (np.arange(free.size) < jm.N_FIXED_PARAMS)
    if not (physics.any() and np.all(np.isfinite(moved[physics])) and moved[physics].max() < STEP_TOL):
        return fit, False
    texture = free & ~physics
    res.warnings.append(
        f"the solver stopped at its step limit with texture knots still moving (256 more Dogleg steps moved "
        f"them by up to {np.nanmax(moved[texture], initial=0.0):.2f} sigma and the speeds, radius and gains by at "
        f"most {moved[physics].max():.3f} sigma), so the latter's values and errors stand; the texture spectrum "
        "there may not")
    return (trial if float(trial.chi2) < float(fit.chi2) else fit), True


def _fill(res: FitResult, fit: LsqResult, names, free, data, options, d1, d2, curvature_radius, *, scale,
          window_weak=False, settled=False):
    theta = np.asarray(fit.theta)
    # lsq scaled the covariance by redchi; ``scale`` (``_error_scale``, one per parameter) replaces that factor
    redchi = float(fit.redchi)
    scale = np.asarray(scale, float)
    cov = np.asarray(fit.cov) * (np.sqrt(np.outer(scale, scale)) / redchi if redchi > 0 else 1.0)
    res.error_scales = {name: float(scale[i]) for i, name in enumerate(OWN_SCALE_PARAMS) if free[i]}
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    res.converged = bool(fit.converged)
    res.redchi, res.chi2 = float(fit.redchi), float(fit.chi2)
    res.cond = float(fit.cond)
    n_free = int(free.sum())
    res.n_params = n_free
    n = float(fit.n_data)
    res.aic = float(n * np.log(max(res.chi2, 1e-300) / max(n, 1)) + 2 * n_free)
    res.bic = float(n * np.log(max(res.chi2, 1e-300) / max(n, 1)) + np.log(max(n, 1)) * n_free)
    res.names = tuple(names)
    fidx = np.flatnonzero(free)
    sub = cov[np.ix_(fidx, fidx)]
    dsd = np.sqrt(np.clip(np.diag(sub), 1e-300, None))
    res.correlations = sub / np.outer(dsd, dsd)
    notes = []
    if not res.converged:
        res.converged = settled or _settled_physics(res, fit, names, free)
    if not res.converged:
        res.status = "not_converged"
        notes.append(f"the solver did not converge ({options.solver})")
    if not np.all(np.isfinite(theta)) or not np.isfinite(res.chi2):
        res.status = "failed"
        res.message = "the fit produced non-finite values"
        return
    vx, vy, a = np.exp(theta[:3])
    # speeds: fixed ones report their value with no error
    for i, (name, v) in enumerate((("vx", vx), ("vy", vy))):
        if not free[i]:
            known = options.velocity[i] if options.velocity is not None else v
            setattr(res, name, float(abs(known)))
            setattr(res, name + "_err", None)
            continue
        err = float(v * sd[i])
        setattr(res, name, float(v))
        setattr(res, name + "_err", err)
        if err > 0.5 * v or v < 1e-3 * max(vx, vy):          # 0 inside the 2-sigma interval: bound it
            upper = _profile_bound(fit, data, free, i, direction=+1, scale=scale[i])
            if upper is not None and upper > _V_BOUNDS[1]:
                upper = None
            setattr(res, name + "_upper", upper)
            notes.append(f"{name} is consistent with 0 at 2 sigma (95 % upper bound {_fmt_speed(upper)})" if upper
                         else f"{name} is not determined (consistent with 0)")
    minor = int(vy < vx)
    name = ("vx", "vy")[minor]
    if options.profile_minor and free[0] and free[1] and getattr(res, name + "_upper") is None \
            and min(vx, vy) < MINOR_PROFILE * max(vx, vy):
        (lo, hi), (lo2, hi2) = _profile_interval(fit, data, free, minor, sd[minor], scale=scale[minor])
        for suffix, value in (("_lo", lo), ("_hi", hi), ("_lo2", lo2), ("_hi2", hi2)):
            setattr(res, name + suffix, value)
        notes.append(f"{name} is a minor component (the spectra depend on it quadratically): "
                     f"profile-likelihood 1-sigma interval [{_fmt_speed(lo)}, {_fmt_speed(hi)}]")
        if lo2 == 0.0 and hi2 is not None:      # the profile's 2-sigma interval reaches 0: bound it too
            setattr(res, name + "_upper", hi2)
            notes.append(f"{name} is consistent with 0 at 2 sigma (95 % upper bound {_fmt_speed(hi2)})")
    # contact radius
    a_err = float(a * sd[2])
    if window_weak or a_err > 0.5 * a or a > 0.5 * _A_BOUNDS[1]:
        lower = _profile_bound(fit, data, free, 2, direction=-1, scale=scale[2])
        res.a, res.a_err, res.a_lower = None, None, lower
        notes.append("the contact window is too weak to measure a: "
                     f"a > {1e3 * lower:.3g} mm (95 % lower bound)" if lower else
                     "the contact window is too weak to measure a")
    else:
        res.a, res.a_err = float(a), a_err
    # gains
    for i, (name, name_err) in ((3, ("gain_ratio", "gain_ratio_err")), (4, ("gain_ratio_y", "gain_ratio_y_err"))):
        g = float(np.exp(theta[i]))
        setattr(res, name, g)
        setattr(res, name_err, float(g * sd[i]) if free[i] else None)
    _contact_depth(res, curvature_radius)
    if res.cond > 1e10:
        notes.append(f"near-degenerate parameters (condition number {res.cond:.2g}): see the correlations")
    if res.redchi > _POOR_FIT_REDCHI and res.status == "ok":
        res.status = "poor_fit"
        notes.insert(0, f"poor fit: reduced chi-square {res.redchi:.1f}; the joint model does not describe these "
                        "spectra (a line texture, another window, or a wrong basin): check the plot before "
                        "trusting the numbers")
    res.message = "; ".join(notes)
    # texture cross-sections along x and y (Eq. 18 / 19)
    try:
        res.texture_x, res.texture_y = _texture_sections(theta, cov, data)
    except Exception as err:  # pragma: no cover - reporting extra, never fatal
        res.warnings.append(f"texture cross-sections not computed: {err}")
    res.problem = FitProblem(
        residuals=jm.residuals, args=data, theta=theta, free=tuple(bool(f) for f in free), names=tuple(names),
        lower=_lower(len(theta)), upper=_upper(len(theta)), cov=cov, scale=res.error_scale,
        to_physical=_to_physical(curvature_radius), stretch=np.sqrt(scale / res.error_scale))


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


def _profile_walk(fit, data, free, i, direction, step, c_stop, *, limit=None, n_max=24, growth=1.5):
    """Step log-parameter i from the best fit (direction -1: down, +1: up), the other free parameters
    refitted (warm-started), until chi2 rises by ``c_stop`` or x passes ``limit``; the step grows by
    ``growth`` each time. Returns the finite points (x, chi2 - chi2_min), starting with (x_best, 0), and
    the last x tried.
    """
    free_others = np.asarray(free).copy()
    free_others[i] = False
    n_prior = jm.n_prior_residuals(len(free_others))
    chi0 = float(fit.chi2)
    theta = np.asarray(fit.theta).copy()
    x = float(theta[i])
    points = [(x, 0.0)]
    for _ in range(n_max):
        if limit is not None and direction * (x + direction * step - limit) > 0:
            break
        x = x + direction * step
        step *= growth
        theta[i] = x
        f = least_squares(jm.residuals, jnp.asarray(theta), data, jnp.asarray(free_others), solver="optimistix",
                          max_steps=256, n_prior=n_prior, rtol=_TOL["profile"], atol=_TOL["profile"])
        c = float(f.chi2)
        if not np.isfinite(c):
            continue
        points.append((x, c - chi0))
        theta = np.asarray(f.theta).copy()
        if c - chi0 >= c_stop:
            break
    return points, x


def _profile_bound(fit, data, free, i, *, direction, scale, delta=2.71, n_max=24):
    """One-sided 95 % profile-likelihood bound of parameter i (log space) from the best fit.

    Steps log-parameter i away from the fit (direction -1: down, +1: up) with
    the other free parameters refitted, until chi2 rises by ``delta * scale``;
    returns exp of the crossing (interpolated), or the last value tried.
    """
    points, x_last = _profile_walk(fit, data, free, i, direction, 0.1, delta * scale, n_max=n_max)
    if len(points) > 1 and points[-1][1] >= delta * scale:
        (x0, c0), (x1, c1) = points[-2], points[-1]
        frac = (delta * scale - c0) / max(c1 - c0, 1e-12)
        return float(np.exp(x0 + frac * (x1 - x0)))
    return float(np.exp(x_last)) if direction < 0 else None


def _profile_interval(fit, data, free, i, sd_log, *, scale, n_sigma=(1.0, 2.0)):
    """Profile-likelihood intervals of speed i (m/s), one (lo, hi) per ``n_sigma``.

    The crossing of chi2_min + n^2 scale is interpolated linearly in
    sqrt(chi2 - chi2_min), which is exact for a quadratic profile. A side that
    never reaches it gives 0 (below) or None (above).
    """
    v_major = float(np.max(np.asarray(fit.theta)[:2]))
    limits = {-1: v_major + np.log(1e-3), +1: v_major + np.log(2.0)}     # log m/s
    c_stop = max(n_sigma) ** 2 * scale
    step = 0.5 * max(float(sd_log), 0.02)
    sides = {d: _profile_walk(fit, data, free, i, d, step, c_stop, limit=limits[d], n_max=16)[0] for d in (-1, +1)}
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


def _log_phi_axis(th, data):
    """log Phi(k = omega / |v_p|) - model log S11_p(omega) for both pairs: (2, L)."""
    s11, _ = jm.log_spectra(th, data)
    v = jnp.exp(th[:2])
    k = data.omega[None, :] / v[:, None]
    lphi = jm.log_phi_at(jnp.log(k), data.log_k_knots, th[jm.N_FIXED_PARAMS:])
    return lphi - s11


@jax.jit
def _section_terms(theta, data):
    return _log_phi_axis(theta, data), jax.jacfwd(_log_phi_axis)(theta, data)


def _texture_sections(theta, cov, data):
    """Eq. 18/19: data/model ratio of the shallow PSD times the model Phi, on k = omega / |v_axis|."""
    base, jac = (np.asarray(t) for t in _section_terms(jnp.asarray(theta), data))        # (2, L), (2, L, P)
    var_theta = np.einsum("plk,km,plm->pl", jac, cov, jac)
    spec_var = 1.0 / float(data.s11_weight) ** 2
    sections = []
    v = np.exp(theta[:2])
    for p in range(2):
        m = np.asarray(data.mask_s11[p])
        k = np.asarray(data.omega)[m] / v[p]
        logp = base[p][m] + np.asarray(data.log_s11[p])[m]
        err = np.sqrt(np.clip(var_theta[p][m], 0, None) + spec_var)
        sections.append(TextureSection(k, np.exp(logp), err) if m.any() else None)
    return tuple(sections)


@jax.jit
def _ratio_terms(theta, data):
    def h(th):
        return jm.log_spectra(th, data)[1]
    return h(theta), jax.jacfwd(h)(theta)


def model_curves(result: FitResult) -> dict | None:
    """Measured and fitted log|P2/P1| of both pairs for plots (Fig. 7 style).

    Returns dict with ``omega`` (L,) rad/s; ``log_ratio``, ``log_ratio_err``,
    ``mask`` (2, L) measured; ``model`` (2, L) at the fit and ``model_sd``
    (2, L) its one-sigma band from the Laplace covariance; None when the fit
    has no joint-model data (ratio-only input or a failed fit).
    """
    if result.problem is None or result.data is None:
        return None
    data = result.data
    theta = np.asarray(result.problem.theta)
    model, jac = (np.asarray(t) for t in _ratio_terms(jnp.asarray(theta), data))
    var = np.einsum("plk,km,plm->pl", jac, np.asarray(result.problem.cov), jac)
    measured = result.spectrum or {"log_ratio": np.asarray(data.log_h), "log_ratio_err": np.asarray(data.h_err)}
    return {"omega": np.asarray(data.omega), "log_ratio": np.asarray(measured["log_ratio"]),
            "log_ratio_err": np.asarray(measured["log_ratio_err"]), "mask": np.asarray(data.mask_h),
            "model": model, "model_sd": np.sqrt(np.clip(var, 0, None))}
