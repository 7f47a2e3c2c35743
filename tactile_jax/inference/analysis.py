"""The whole analysis of one record as one pure, fixed-shape program: ``analyse``.

Every model choice a record needs is made inside the program, as data. The
program runs a fixed schedule of solves (``STAGES``), each a
Levenberg-Marquardt solve (``solve.levenberg_marquardt``) of the joint model
under either contact window, started from where the earlier solves ended. A
solve the record does not need is switched off (no iteration runs) and every
choice is a ``jnp.where`` on the solves' statistics:

====  ==========================================================================
G0    the Gaussian window's starts, each explored (``core``'s step 4), a start
      far behind an earlier one's end left early (``SCOUT_GIVE_UP``): the
      scouting of the Hertz disk's starts; with the window given as Gaussian,
      the Gaussian fit itself
H1    the Hertz disk from the one of G0's ends of lowest Hertz cost (of those within
      ``SCOUT_GIVE_UP`` of the best Gaussian end, their radii scaled to the same
      second moment, and the best end as it is)
GW1   the Gaussian window refitted from H1 (its radius scaled to the same second
      moment), or from G0's best end where that fits better: the window choice
      compares the two by chi-square. H1 (against
      G0's scouting), GW1 and GW2 (against the Hertz fit they start from) stop
      once they could no longer win the choice (``GIVE_UP_FACTOR``); the
      window margin is then the one where the loser stopped
HX    the Hertz disk's own starts (each pair fitted with the disk's curve),
      where the chosen fit and H1 are poor or unsettled: a large disk at a
      slow slip bends the ratio beyond what the Gaussian window follows
GW2   the Gaussian window refitted from HX, where HX improved on H1
GF    the Gaussian window's own starts, where it was chosen but its refit
      did not settle
T2    the texture's lobe freed to its second harmonic (detection)
T4    all four harmonics, where the lobe is decisive (its shape)
DA    the minor speed held at 0 (slip along an axis)
WN    the contact radius held negligible (is the window needed?)
TL    the kept fit refitted with the texture's power at each bin a random effect
      (``residuals``), where that fit is poor and its misfit has no trend
      across frequency (``core``'s lumpy texture): a texture of few persistent
      modes
====  ==========================================================================

The windows, texture models and slip directions are chosen, or averaged
where the data barely tell them apart, by the rules of ``_compare_windows``,
``_texture_fit`` and ``_direction_fit``; the choices, margins and weights are
arrays of the ``Analysis``, which ``inference.describe`` turns into words.
Under ``jax.jit`` on one record a solve switched off costs nothing;
under ``jax.vmap`` every record runs the schedule side by side, and a chunk
iterates until its slowest record stops. The solves share one loop body (a
``lax.scan`` over the stages), so the program compiles the joint model and its
Jacobian once for each window.

A refit (``Choices.refit``: profiles, ``model="auto"``) runs the same program
from a given ``Start`` with every choice held: G0 goes on from the start under
the given window, the other stages are off.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._numerics import any_in_batch
from .core import (HERTZ_PER_GAUSS, ITERATIONS, N_STARTS, OWN_STARTS, STOP_TOL, DECREMENT_TOL, Errors, Located,
                   Record, Settings, Start, Summary, errors, fit_status, no_start, prepare, settled_physics,
                   statistics, step_bounds, summary_at)
from .data import N_DATA_ROWS, N_LUMP, N_LUMP_SD, JointData
from .forward import ANISO, INDEX, ModelSpectra, lump_basis
from .residuals import lump_scale, residuals_and_model
from .solve import levenberg_marquardt

__all__ = ["Choices", "Analysis", "Stages", "analyse", "summary_of", "STAGES", "WINDOWS", "TEXTURES", "DIRECTIONS",
           "WINDOW_DECISIVE", "DIRECTIONAL_EXPLAINS", "DETECTING", "TEXTURE_AVERAGED", "DIRECTION_TESTED",
           "AXIS_FLOOR", "A_NEGLIGIBLE", "DIRECTION_KEEP", "DIRECTION_GIVE_UP", "GIVE_UP_FACTOR", "GIVE_UP_AFTER",
           "SCOUT_GIVE_UP", "SCOUT_AFTER", "WINDOW_TEST_REL_ERR", "DELTA_95", "EXPLORED_GAIN", "N_FINAL"]

STAGES = ("G0", "H1", "GW1", "HX", "GW2", "GF", "T2", "T4", "DA", "WN", "TL")
G0, H1, GW1, HX, GW2, GF, T2, T4, DA, WN, TL = range(len(STAGES))
#: the windows, texture models and slip directions, in the order of their codes in ``Analysis``
WINDOWS = ("gaussian", "hertz")
TEXTURES = ("isotropic", "directional")
DIRECTIONS = ("oblique", "along x", "along y")

#: a window margin (chi-square in units of the correlated-bin scale) at least this large decides between the windows
WINDOW_DECISIVE = 6.0
#: a poor isotropic fit is explained by a directional lobe when that brings its reduced chi-square this low
DIRECTIONAL_EXPLAINS = 1.5
#: angular coefficients (``forward.ANISO``) that detect a directional lobe: its second harmonic
DETECTING = 2
#: below this AIC margin the texture models are averaged by Akaike weight (the loser's weight above 0.7 %)
TEXTURE_AVERAGED = 10.0
#: a minor speed below this fraction of the major one is tested against 0
DIRECTION_TESTED = 0.3
#: a minor speed is held at 0 where holding it raises chi-square by at most this many of its error scale
#: (Akaike's criterion: one parameter is worth 2)
DIRECTION_KEEP = 2.0
#: DA (the minor speed held) gives up, where the direction is chosen, once its |r|^2 less the Gauss-Newton
#: decrement still to go is this many times the direction test's threshold (``DIRECTION_KEEP`` x the minor speed's
#: error scale) above where it could still win, tested from ``GIVE_UP_AFTER`` final iterations on
DIRECTION_GIVE_UP = 3.0
#: a speed held at 0 is held at this fraction of the other (the parameter is log|v|): its effect on the
#: spectra, quadratic in it, is 1e-6 of the major speed's
AXIS_FLOOR = 1e-3
#: contact radius (m) standing for "no window": its offset 3 (d2^2 - d1^2) / (2 a^2) is 1e-4 at the paper's depths
A_NEGLIGIBLE = 0.1
#: a window's solve (H1, GW1, GW2) gives up, where the window is chosen, once its chi-square less the
#: Gauss-Newton decrement still to go is above this many times the other window's chi-square plus the decisive
#: margin: it could no longer win the window. With 2 (or 1.5) in place of 3, the 200 scenes of
#: ``benchmarks/windows.py`` (default fit) and 128 oblique records of ``benchmarks/throughput.py``'s pool give the
#: same rows to the last digit; on the pool H1's slowest record takes 22 iterations against 36, and a vmapped
#: block of 128, which runs each stage until its slowest record stops, 97 against 111
GIVE_UP_FACTOR = 2.0
#: ... tested from this many final iterations on. On 12 Hertz and 12 Gaussian scenes of ``benchmarks/windows.py``,
#: testing from the 18th instead gives the same window choices and statuses and values within 0.011 of their
#: errors, and runs H1 on the Gaussian contacts and GW1 on the Hertz ones 24 and up to 19 iterations against
#: 12 and 7
GIVE_UP_AFTER = 6
#: a start being explored is left once its cost is this many times the lowest cost an earlier start ended at,
#: tested from its SCOUT_AFTER-th evaluation on (1: the start itself). On 22 records (16 oblique Gaussian
#: contacts of ``benchmarks/throughput.py``'s pool, 6 of both windows), no start so left would have ended best
#: after all its iterations, with factors 5-1000 tested from the 1st-5th evaluation on; G0 scouts those 16 in 18
#: iterations on average, where running every start in full takes 36
SCOUT_GIVE_UP = 10.0
SCOUT_AFTER = 1
#: the window's need is tested where a is measured to worse than this relative error
WINDOW_TEST_REL_ERR = 0.05
#: chi2 rise (in units of a's variance scale) below which a -> infinity is not rejected: one-sided 95 %
DELTA_95 = 2.71
#: chi-square the Hertz disk's own starts must gain over H1 to replace it
EXPLORED_GAIN = 0.1
#: iterations of a solve from a given point: ``core``'s final ones and three more solves' worth where a fit
#: has not settled; a solve ends once the decrement still to go is below ``core.STOP_TOL``, or after
#: ``core.ITERATIONS[2]`` below ``core.DECREMENT_TOL`` (converged)
N_FINAL = 4 * ITERATIONS[2]

_N_FIRST, _N_START, _ = ITERATIONS
_I_V = np.array([INDEX["log_vx"], INDEX["log_vy"]])
_I_A = INDEX["log_a"]
_I_VVA = np.array([INDEX["log_vx"], INDEX["log_vy"], INDEX["log_a"]])
_I_ANISO = np.array([INDEX[name] for name in ANISO])


class Choices(NamedTuple):
    """What the user fixed, as data (one program for every choice).

    window, texture: 0 to choose per record, else 1 + the index into ``WINDOWS`` / ``TEXTURES``;
    direction: 0 to choose, else 1 + the index into ``DIRECTIONS``; test_window: test whether the data
    need the contact window (``WN``); refit: go on from the given ``Start`` with every choice held (the
    window given by ``window``, the texture and direction by the start's free mask); direction_keep: the
    rise of chi-square, in units of the minor speed's error scale, up to which a minor speed is held at 0
    (``DIRECTION_KEEP``: Akaike's criterion; a caller whose error scale has few degrees of freedom asks for
    more: ``track.tracker``)."""

    window: int = 0
    texture: int = 0
    direction: int = 0
    test_window: bool = True
    refit: bool = False
    direction_keep: float = DIRECTION_KEEP


class Stages(NamedTuple):
    """Where each stage (``STAGES``) ended: theta, free (K, P); chi2, redchi, n_data (K,); status (K,) of
    the solution (``core.STATUS``); active (K,): whether the stage ran; hertz (K,): its window; errors:
    its ``core.Errors`` (zeros where not computed: a stage off, or G0's scouting); r, jac, model: the
    residuals (K, R), their Jacobian (K, R, P) and the model's spectra at its solution; iterations (K,):
    the evaluations of the residuals and their Jacobian it took; lumps (K, ``N_LUMP_SD``): the sds of the texture
    random effects it fitted with (``JointData.lump_sd``; their rows follow from the Jacobian it started from)."""

    theta: jax.Array
    free: jax.Array
    chi2: jax.Array
    redchi: jax.Array
    n_data: jax.Array
    status: jax.Array
    active: jax.Array
    hertz: jax.Array
    errors: Errors
    r: jax.Array
    jac: jax.Array
    model: ModelSpectra
    iterations: jax.Array
    lumps: jax.Array


class Analysis(NamedTuple):
    """What ``analyse`` returns (arrays; a leading batch axis under ``vmap``).

    summary: the kept fit (``core.Summary``; its ``data`` the Gaussian window's, ``data_h`` the Hertz
    disk's). window: index into ``WINDOWS``; window_margin: chi-square margin in units of the
    correlated-bin scale (positive favours the Hertz disk; nan where not compared; where the losing
    window's solve gave up, its chi-square where it stopped); window_weight: the
    kept window's Akaike weight (1 where decisive); window_other, window_other_sd (3,): the other
    window's log vx, log vy, log a and their errors (where averaged); explored: the Hertz disk's own
    starts replaced the first Hertz fit; explored_chi2 (2,): the first fit's and theirs; fresh: the
    Gaussian window's own starts replaced its refit. texture: index into ``TEXTURES``; texture_margin
    (AIC, the loser's minus the winner's), texture_weight, texture_other, texture_other_sd as for the
    window; texture_note: 0 none, 1 the lobe did not fit, 2 the lobe does not describe the spectra, 3 a
    decisive lobe, 4 averaged; texture_lobe (4,): the lobe's coefficients (the directional fit's);
    texture_redchi (2,): the isotropic and directional reduced chi-squares. direction: index into
    ``DIRECTIONS``; direction_margin (AIC in the minor speed's error scale; nan where not tested);
    direction_forced; oblique: the fit with both speeds free where one is held (theta, free, scales
    (P,) each, chi2; else the kept fit's). window_needed; window_rise: chi2's rise with a held negligible;
    window_threshold. lumps: (``N_LUMP_SD``,) the sds of the texture's random effects at each bin
    (``JointData.lump_sd``) of the kept fit (TL's, or those a refit was given), else zeros. stages: ``Stages``.
    """

    summary: Summary
    data_h: JointData
    window: jax.Array
    window_margin: jax.Array
    window_weight: jax.Array
    window_other: jax.Array
    window_other_sd: jax.Array
    explored: jax.Array
    explored_chi2: jax.Array
    fresh: jax.Array
    texture: jax.Array
    texture_margin: jax.Array
    texture_weight: jax.Array
    texture_other: jax.Array
    texture_other_sd: jax.Array
    texture_note: jax.Array
    texture_lobe: jax.Array
    texture_redchi: jax.Array
    direction: jax.Array
    direction_margin: jax.Array
    direction_forced: jax.Array
    oblique_theta: jax.Array
    oblique_free: jax.Array
    oblique_scales: jax.Array
    oblique_chi2: jax.Array
    window_needed: jax.Array
    window_rise: jax.Array
    window_threshold: jax.Array
    lumps: jax.Array
    stages: Stages


class _Plan(NamedTuple):
    starts: jax.Array
    free: jax.Array
    n_start: jax.Array
    n_explore: jax.Array
    n_final: jax.Array
    skip: jax.Array
    hertz: jax.Array
    active: jax.Array
    give_up: jax.Array = np.inf         # |r|^2 above which the solve ends early (``levenberg_marquardt``)
    lumps: jax.Array = np.zeros(N_LUMP_SD)      # the texture random effects (``JointData.lump_sd``, ``lump_rows``)
    lump_rows: jax.Array = np.zeros((N_DATA_ROWS, N_LUMP))


def _either(theta, args):
    """The joint residuals and model under the window ``args[3]`` says (traced; ``args[2]`` None: the Gaussian
    window's alone), with the texture random effects' sds and rows ``args[4:6]``, and ``args[6]`` (optional)
    whether the Jacobian's columns of vx, vy and a are wanted (the solver's ``jac_use``). Each window is
    computed only where some record wants it: on one record, one window;
    under ``vmap``, a chunk whose records all want one window (every stage but the texture and direction
    refits) computes that one alone, instead of both for every record."""
    data_g, data_h, coef, use_hertz, lumps, rows, *wanted = args
    data_g, data_h = (d._replace(lump_sd=lumps, lump_rows=rows) for d in (data_g, data_h))
    if coef is None:
        return residuals_and_model(theta, (data_g, None))
    # (the module's function itself, not a lambda: jax keeps its shapes for these inputs, and the trace of the
    # program asks for them once instead of at every trace of this function)
    shape = jax.eval_shape(residuals_and_model, theta, (data_g, None))
    blank = lambda t: jax.tree.map(lambda x: jnp.zeros(x.shape, x.dtype), shape)     # noqa: E731
    hz = jax.lax.cond(any_in_batch(use_hertz), lambda t: residuals_and_model(t, (data_h, coef, *wanted)), blank, theta)
    gs = jax.lax.cond(any_in_batch(~use_hertz), lambda t: residuals_and_model(t, (data_g, None)), blank, theta)
    return jax.tree.map(lambda h, g: jnp.where(use_hertz, h, g), hz, gs)


def _akaike_weight(margin):
    """The Akaike weight of the one of two models ahead by ``margin`` (AIC or chi-square units)."""
    return 1.0 / (1.0 + jnp.exp(-0.5 * margin))


def _compared(st: Stages, k):
    """Whether stage ``k`` ran and gave values to compare (ok, not converged or poor)."""
    s = st.status[k]
    return st.active[k] & ((s == 0) | (s == 2) | (s == 3))


def _poor(st: Stages, k):
    s = st.status[k]
    return st.active[k] & ((s == 2) | (s == 3))


class _Window(NamedTuple):
    kept: jax.Array
    other: jax.Array
    margin: jax.Array
    weight: jax.Array


def _compare_windows(st: Stages, h, g, bin_factor) -> _Window:
    """The contact window of one record: the Hertz fit (stage ``h``) against the Gaussian refit from it (``g``).

    Both models have the same parameters, so the criterion is the chi-square difference in units of the
    correlated-bin scale (the bin factor times the better fit's reduced chi-square, at least 1, as the noise
    scale of an F test is the better model's): positive favours Hertz. Below ``WINDOW_DECISIVE`` the data
    cannot tell the windows apart: the fit kept is the Hertz one (a fingertip's contact is a Hertz disk)
    unless only the Gaussian window describes the spectra (reduced chi-square at most ``POOR_FIT_REDCHI``),
    and vx, vy and a are averaged over both by their Akaike weights, exp(-margin / 2) relative. Returns
    the kept stage, the other (-1 where decisive), the margin (nan where not compared) and the kept
    window's weight."""
    chi_h, chi_g = st.chi2[h], st.chi2[g]
    rc_h, rc_g = st.redchi[h], st.redchi[g]
    valid = _compared(st, h) & st.active[g] & jnp.isfinite(chi_g)
    scale = jnp.maximum(bin_factor, 1.0) * jnp.maximum(jnp.minimum(rc_h, rc_g), 1.0)
    margin = (chi_g - chi_h) / scale
    hertz, gauss = margin >= WINDOW_DECISIVE, margin <= -WINDOW_DECISIVE
    close = valid & ~hertz & ~gauss
    keep_gauss = (rc_h > 2.0) & (rc_g <= 2.0)          # only the Gaussian window describes the spectra
    kept = jnp.where(valid & (gauss | close & keep_gauss), g, h)
    w_hertz = _akaike_weight(margin)
    return _Window(kept, jnp.where(close, jnp.where(keep_gauss, h, g), -1), jnp.where(valid, margin, jnp.nan),
                   jnp.where(close, jnp.where(keep_gauss, 1.0 - w_hertz, w_hertz), 1.0))


def _hertz_fit(st: Stages):
    """H1, or HX where the disk's own starts found a lower chi-square (by more than rounding)."""
    better = st.active[HX] & (st.chi2[HX] < st.chi2[H1] - jnp.maximum(EXPLORED_GAIN, 1e-9 * jnp.abs(st.chi2[H1])))
    return jnp.where(better, HX, H1), better


def _first_window(st: Stages, bin_factor) -> _Window:
    return _compare_windows(st, H1, GW1, bin_factor)


class _WindowFit(NamedTuple):
    index: jax.Array
    hertz: jax.Array
    choice: _Window
    explored: jax.Array
    fresh: jax.Array


def _window_fit(st: Stages, choices: Choices, bin_factor) -> _WindowFit:
    """The fit of the chosen (or given) window after G0-GF."""
    h, explored = _hertz_fit(st)
    gw = jnp.where(explored, GW2, GW1)
    choice = _compare_windows(st, h, gw, bin_factor)
    gauss_chosen = choice.kept == gw
    fresh = st.active[GF] & ((st.status[GF] != 2) | (st.chi2[GF] < st.chi2[gw]))
    chosen = jnp.where(gauss_chosen & fresh, GF, choice.kept)
    window = jnp.asarray(choices.window)
    # a refit goes on in G0 under the given window (every other stage is off)
    index = jnp.where((window == 1) | jnp.asarray(choices.refit), G0, jnp.where(window == 2, h, chosen))
    none = _Window(index, jnp.asarray(-1), jnp.asarray(jnp.nan), jnp.asarray(1.0))
    choice = jax.tree.map(lambda a, b: jnp.where(window == 0, a, b), choice, none)
    return _WindowFit(index, st.hertz[index], choice, explored & (window != 1), fresh & (window == 0))


class _TextureFit(NamedTuple):
    index: jax.Array
    directional: jax.Array
    other: jax.Array
    margin: jax.Array
    weight: jax.Array
    note: jax.Array


def _texture_fit(st: Stages, w, bin_factor) -> _TextureFit:
    """The texture model of one record: the isotropic fit (stage ``w``) against the directional one.

    The lobe is detected with its second harmonic (``DETECTING`` coefficients freed from the isotropic
    optimum: T2) and, where that is decisive, estimated with all four (T4, from T2's optimum): the fourth
    harmonic is second order in the anisotropy, so a lobe too weak to detect decisively has none worth
    fitting, while a decisive lobe's shape moves the minor speed. The lobe is kept where it lowers Akaike's
    criterion with the correlated-bin correction (chi2 / (b c) + 2 k; the quasi-likelihood scale c is the
    directional fit's reduced chi-square, so that a misfit it does not remove is not read as evidence),
    and only if it describes the spectra (reduced chi-square at most ``DIRECTIONAL_EXPLAINS``): a lumpy
    spectrum of few discrete modes is not a directional texture. Below a margin of ``TEXTURE_AVERAGED``
    vx, vy and a are averaged over the isotropic and second-harmonic fits by their Akaike weights."""
    chi_w, chi_d = st.chi2[w], st.chi2[T2]
    n_data = st.n_data[w]
    k_iso, k_dir = jnp.sum(st.free[w]), jnp.sum(st.free[T2])
    c = jnp.maximum(chi_d / jnp.maximum(n_data - k_dir, 1.0), 1.0)
    b = jnp.maximum(bin_factor, 1.0)
    ic_iso, ic_dir = chi_w / (b * c) + 2.0 * k_iso, chi_d / (b * c) + 2.0 * k_dir
    ran = st.active[T2]
    finite = jnp.isfinite(chi_d)
    explains = st.redchi[T2] <= DIRECTIONAL_EXPLAINS
    valid = ran & finite & explains
    ahead = ic_dir < ic_iso
    margin = jnp.abs(ic_iso - ic_dir)
    decisive = margin >= TEXTURE_AVERAGED
    shaped = st.active[T4] & jnp.isfinite(st.chi2[T4]) & (st.chi2[T4] <= chi_d + 1e-6 * n_data)
    index = jnp.where(valid & ahead, jnp.where(shaped, T4, T2), w)
    close = valid & ~decisive
    poor = (st.redchi[w] > 2.0) & (st.redchi[T2] < st.redchi[w])
    note = jnp.where(ran & ~finite, 1, jnp.where(ran & finite & ~explains & poor, 2,
                     jnp.where(valid & decisive & ahead, 3, jnp.where(close, 4, 0))))
    directional = jnp.any(st.free[index][_I_ANISO])
    return _TextureFit(index, directional, jnp.where(close, jnp.where(ahead, w, T2), -1),
                       jnp.where(valid, margin, jnp.nan), jnp.where(close, _akaike_weight(margin), 1.0), note)


def _minor(st: Stages, t, choices: Choices):
    """(minor speed's index into (vx, vy), whether DA tests it) for the fit of stage ``t``."""
    theta, free = st.theta[t], st.free[t]
    mode = jnp.asarray(choices.direction)
    minor = jnp.where(mode == 0, jnp.argmin(theta[_I_V]), jnp.where(mode == 2, 1, 0))
    small = theta[_I_V][minor] - theta[_I_V][1 - minor] < np.log(DIRECTION_TESTED)
    testable = (mode != 1) & _compared(st, t) & free[_I_V].all() & ~jnp.asarray(choices.refit)
    return minor, testable & ((mode != 0) | small)


def _direction_fit(st: Stages, t, choices: Choices, scales_t):
    """The slip direction of one record: both speeds free (stage ``t``) or the minor one held at 0 (DA).

    Tested where both speeds are free and the minor one is below ``DIRECTION_TESTED`` of the major (or a
    direction is given): DA holds it at ``AXIS_FLOOR`` of the major, from ``t``'s optimum. Akaike's
    criterion in units of the minor speed's own error scale (its variance ratio ``scales_t``, the unit of
    its profile intervals): the axis model is kept where holding the speed raises chi-square by at most
    ``choices.direction_keep`` of that scale (2 by default, i.e. where it is within 1.4 sigma of 0 and a
    fitted value would be noise). A given direction is held whatever the data say. Returns the kept stage,
    the margin (the loser's AIC minus the winner's; nan where not tested or given) and whether the direction
    was given."""
    minor, _ = _minor(st, t, choices)
    forced = jnp.asarray(choices.direction) >= 2
    scale = jnp.maximum(scales_t[_I_V][minor], 1e-12)
    margin = jnp.asarray(choices.direction_keep) - (st.chi2[DA] - st.chi2[t]) / scale
    ok = _compared(st, DA) & jnp.isfinite(st.chi2[DA])
    take = st.active[DA] & (forced | ok & (margin >= 0.0))
    return (jnp.where(take, DA, t), jnp.where(st.active[DA] & ~forced & ok, jnp.abs(margin), jnp.nan),
            forced & st.active[DA])


def _window_needed(tested, chi2_held, chi2, scale_a):
    """Whether the data reject a negligible window (a held at ``A_NEGLIGIBLE``, WN): a likelihood-ratio test,
    run where a is loosely measured. Where holding a raises chi2 by less than ``DELTA_95`` x a's variance
    scale, the data cannot tell the window from none at 95 %, and a fitted radius would be a number fitted
    into noise: a is then reported as a lower bound. Returns (needed, the rise, the threshold)."""
    rise = chi2_held - chi2
    threshold = DELTA_95 * scale_a
    return ~jnp.asarray(tested, bool) | ~jnp.isfinite(chi2_held) | (rise >= threshold), rise, threshold


def analyse(record: Record, settings: Settings, choices: Choices = Choices(), start: Start | None = None
            ) -> Analysis:
    """The analysis of one record (see the module). Pure jnp, fixed shapes: jit and vmap freely.

    settings: ``core.Settings``; with the Hertz table's coefficients in ``hertz`` both windows are in the
    program, with None the Gaussian window's alone (``Choices.window`` is then 1); choices: ``Choices``;
    start: where a refit goes on from (``Choices.refit``)."""
    start = no_start() if start is None else start
    coef = settings.hertz
    if coef is None:            # a program of the Gaussian window alone
        choices = choices._replace(window=1)
    refit = jnp.asarray(choices.refit)
    prep_g, prep_h, hertz_starts = prepare(record, settings, both_windows=True)
    data_g, data_h = prep_g.data, prep_h.data
    b = prep_g.band
    i0 = b.i0
    bin_factor = record.seg.bin_factor
    p = prep_g.starts.shape[-1]
    dtype = prep_g.starts.dtype
    n_bins = jnp.sum(data_g.mask_s11[0]) + jnp.sum(data_g.mask_s11[1] | data_g.mask_xy[0])
    window = jnp.asarray(choices.window)
    texture = jnp.asarray(choices.texture)

    def errors_at(st: Stages, k) -> Errors:
        return jax.tree.map(lambda x: x[k], st.errors)

    def off(hertz=False):       # no iteration at all
        return _Plan(prep_g.starts, prep_g.free, jnp.asarray(1), jnp.asarray(1), jnp.asarray(-1), jnp.asarray(True),
                     jnp.asarray(hertz), jnp.asarray(False))

    def from_point(theta, free, hertz, active, give_up=np.inf, lumps=np.zeros(N_LUMP_SD),
                   lump_rows=np.zeros((N_DATA_ROWS, N_LUMP))):
        """A solve from one point, or a stage switched off."""
        plan = _Plan(jnp.broadcast_to(theta, prep_g.starts.shape), free, jnp.asarray(1), jnp.asarray(1),
                     jnp.asarray(N_FINAL), jnp.asarray(True), jnp.asarray(hertz), jnp.asarray(active),
                     jnp.asarray(give_up), jnp.asarray(lumps), jnp.asarray(lump_rows))
        return jax.tree.map(lambda a, o: jnp.where(active, a, o), plan, off())

    def own_starts(prep, n_explore, hertz, active, n_final=N_FINAL):
        plan = _Plan(prep.starts, prep.free, jnp.asarray(_N_START), jnp.asarray(n_explore), jnp.asarray(n_final),
                     jnp.asarray(False), jnp.asarray(hertz), jnp.asarray(active))
        return jax.tree.map(lambda a, o: jnp.where(active, a, o), plan, off())

    def plan_g0(st, ends):
        # a refit (a profile point, a model of ``fit``'s extras) goes on for ``core``'s final iterations, no more
        given = _Plan(start.theta.astype(dtype), start.free, jnp.asarray(1), jnp.asarray(1),
                      jnp.asarray(ITERATIONS[2]), jnp.asarray(True), window == 2, jnp.asarray(True), jnp.asarray(np.inf),
                      jnp.asarray(start.lumps), jnp.asarray(start.lump_rows))
        gauss = own_starts(prep_g, OWN_STARTS["gaussian"], False, True)
        scout = own_starts(prep_g, N_STARTS, False, True, n_final=0)
        plan = jax.tree.map(lambda a, b: jnp.where(window == 1, a, b), gauss, scout)
        return jax.tree.map(lambda a, b: jnp.where(refit, a, b), given, plan)

    def give_up_against(st, k):
        """Where the window is chosen, a solve that only competes with stage ``k``'s fit (which reached its
        chi-square, and whose optimum is lower still) need go on only as long as it could still win."""
        bound = GIVE_UP_FACTOR * (jnp.sum(jnp.square(st.r[k])) + WINDOW_DECISIVE * jnp.maximum(bin_factor, 1.0)
                                  * jnp.maximum(st.redchi[k], 1.0))
        return jnp.where((window == 0) & jnp.isfinite(bound), bound, jnp.inf)

    def plan_h1(st, ends):
        # G0's ends in the order of their Gaussian cost, those within SCOUT_GIVE_UP of the best evaluated
        thetas, costs = ends
        order = jnp.argsort(costs)
        near = jnp.maximum(jnp.sum(costs <= SCOUT_GIVE_UP * jnp.min(costs)), 1)
        thetas = thetas[order]
        scaled = thetas.at[:, _I_A].add(np.log(HERTZ_PER_GAUSS))
        # and the best end with its radius as it is: a Gaussian fit of a Hertz contact can read the disk's radius
        # itself, and a wrong scaling costs H1 iterations or its basin. On the 100 Hertz scenes of
        # benchmarks/windows.py: H1 27.5 iterations on average against 32.8, and a slow oblique slip under a
        # 2.1 mm disk found (ok, a 2.03 mm) where the scaled starts ended poor at a 3.9 mm. It takes the slot after
        # the near ends, or the last one's where all are near
        slot = jnp.minimum(near, thetas.shape[0] - 1)
        thetas = scaled.at[slot].set(thetas[0])
        active = ~refit & (window != 1)
        plan = _Plan(thetas, prep_h.free, jnp.asarray(1), slot + 1, jnp.asarray(N_FINAL),
                     jnp.asarray(False), jnp.asarray(True), active, give_up_against(st, G0))
        return jax.tree.map(lambda a, o: jnp.where(active, a, o), plan, off())

    def gauss_from(st, k, active):
        theta = st.theta[k].at[_I_A].add(-np.log(HERTZ_PER_GAUSS))
        return from_point(theta, st.free[k], False, active & ~refit & (window == 0) & _compared(st, k),
                          give_up_against(st, k))

    def plan_gw1(st, ends):
        # from H1's solution or from G0's best Gaussian end, whichever fits better (each evaluated once)
        plan = gauss_from(st, H1, True)
        two = plan._replace(starts=plan.starts.at[1].set(st.theta[G0]), n_explore=jnp.asarray(2),
                            skip=jnp.asarray(False))
        return jax.tree.map(lambda a, o: jnp.where(plan.active, a, o), two, plan)

    def plan_hx(st, ends):
        first = _first_window(st, bin_factor)
        wanted = jnp.where(window == 0, _poor(st, first.kept), window == 2) & _poor(st, H1) & ~refit
        # run where some record of a chunk wants them (a record that does not has the stage off: its starts
        # are not used)
        starts = jax.lax.cond(any_in_batch(wanted), hertz_starts, lambda: prep_h.starts)
        return own_starts(prep_h._replace(starts=starts), OWN_STARTS["hertz"], True, wanted)

    def plan_gw2(st, ends):
        return gauss_from(st, HX, _hertz_fit(st)[1])

    def plan_gf(st, ends):
        h, explored = _hertz_fit(st)
        gw = jnp.where(explored, GW2, GW1)
        choice = _compare_windows(st, h, gw, bin_factor)
        wanted = (window == 0) & (choice.kept == gw) & (st.status[gw] == 2) & ~refit
        return own_starts(prep_g, OWN_STARTS["gaussian"], False, wanted)

    def plan_t2(st, ends):
        w = _window_fit(st, choices, bin_factor)
        free = st.free[w.index].at[_I_ANISO[:DETECTING]].set(True)
        return from_point(st.theta[w.index], free, w.hertz, (texture == 0) & _compared(st, w.index) & ~refit)

    def plan_t4(st, ends):
        w = _window_fit(st, choices, bin_factor)
        t = _texture_fit(st, w.index, bin_factor)
        wanted = (t.index == T2) & (t.note == 3)
        return from_point(st.theta[T2], st.free[T2].at[_I_ANISO].set(True), w.hertz, wanted)

    def texture_index(st):
        w = _window_fit(st, choices, bin_factor)
        return _texture_fit(st, w.index, bin_factor).index, w.hertz

    def plan_da(st, ends):
        t, hertz = texture_index(st)
        minor, wanted = _minor(st, t, choices)
        theta, free = st.theta[t], st.free[t]
        i, major = _I_V[0] + minor, _I_V[0] + 1 - minor      # vx, vy are adjacent in the parameter vector
        held = theta.at[i].set(theta[major] + np.log(AXIS_FLOOR))
        # where the direction is chosen, DA need only go on while it could still win the test of
        # ``_direction_fit``: |r|^2 (the priors included, the held speed's moved by holding it) no higher than
        # t's plus DIRECTION_GIVE_UP times the test's threshold
        centre = jnp.where(hertz, data_h.prior_center[i], data_g.prior_center[i])
        weight = jnp.where(hertz, data_h.prior_inv_sd[i], data_g.prior_inv_sd[i])
        prior_rise = jnp.square((held[i] - centre) * weight) - jnp.square((theta[i] - centre) * weight)
        scale = jnp.maximum(errors_at(st, t).scales[_I_V][minor], 1e-12)
        bound = (jnp.sum(jnp.square(st.r[t])) + prior_rise
                 + DIRECTION_GIVE_UP * jnp.asarray(choices.direction_keep) * scale)
        give_up = jnp.where((jnp.asarray(choices.direction) == 0) & jnp.isfinite(bound), bound, jnp.inf)
        return from_point(held, free.at[i].set(False), hertz, wanted, give_up)

    def direction_index(st):
        t, hertz = texture_index(st)
        return _direction_fit(st, t, choices, errors_at(st, t).scales)[0], hertz

    def plan_wn(st, ends):
        d, hertz = direction_index(st)
        sd_a = errors_at(st, d).sd[_I_A]
        wanted = (jnp.asarray(choices.test_window) & _compared(st, d) & st.free[d][_I_A]
                  & (sd_a >= WINDOW_TEST_REL_ERR) & ~refit)
        return from_point(st.theta[d].at[_I_A].set(np.log(A_NEGLIGIBLE)), st.free[d].at[_I_A].set(False), hertz,
                          wanted)

    basis = jnp.asarray(lump_basis(p), dtype)

    def effect_rows(st, d):
        """The data rows' derivatives by the texture's random effects, from the Jacobian where stage ``d`` ended
        (``forward.lump_basis``): held there by TL's refit from d."""
        return -st.jac[d][:N_DATA_ROWS] @ basis

    def plan_tl(st, ends):
        d, hertz = direction_index(st)
        wanted = errors_at(st, d).lumpy & _compared(st, d) & ~refit
        rows = effect_rows(st, d)
        sd = lump_scale(st.r[d][:N_DATA_ROWS], rows, data_g)
        return from_point(st.theta[d], st.free[d], hertz, wanted & jnp.any(sd > 0), lumps=sd, lump_rows=rows)

    def typed(planner):         # every branch of the switch returns the same types
        def run(st, ends):
            plan = planner(st, ends)
            return _Plan(plan.starts.astype(dtype), plan.free.astype(bool), *(jnp.asarray(x, jnp.int32) for x in
                         (plan.n_start, plan.n_explore, plan.n_final)),
                         *(jnp.asarray(x, bool) for x in (plan.skip, plan.hertz, plan.active)),
                         jnp.asarray(plan.give_up, dtype), jnp.broadcast_to(jnp.asarray(plan.lumps, dtype), (N_LUMP_SD,)),
                         jnp.broadcast_to(jnp.asarray(plan.lump_rows, dtype), (N_DATA_ROWS, N_LUMP)))
        return run

    planners = [typed(f) for f in (plan_g0, plan_h1, plan_gw1, plan_hx, plan_gw2, plan_gf, plan_t2, plan_t4, plan_da,
                                   plan_wn, plan_tl)]
    assert len(planners) == len(STAGES)

    def stage(carry, k):
        st, ends = carry
        plan = jax.lax.switch(k, planners, st, ends)
        theta, r, jac, model, last, last_cost, n_iter = levenberg_marquardt(
            _either, plan.starts, (data_g, data_h, coef, plan.hertz, plan.lumps, plan.lump_rows), plan.free, prep_g.first, n_start=plan.n_start,
            n_first=_N_FIRST, n_final=plan.n_final, n_explore=plan.n_explore, skip_starts=plan.skip, ends=True,
            stop_tol=STOP_TOL, count=True, soft_after=ITERATIONS[2], soft_tol=DECREMENT_TOL, give_up_chi2=plan.give_up,
            give_up_after=GIVE_UP_AFTER, jac_use=lambda args, used: args + (used,), scout_give_up=SCOUT_GIVE_UP,
            scout_after=SCOUT_AFTER, end_costs=True, max_step=step_bounds(p))
        lumped_data = data_g._replace(lump_sd=plan.lumps, lump_rows=plan.lump_rows)
        _, chi2, n_data, _, redchi, _, decrement, step_sigma = statistics(
            theta, r, jac, plan.free, lumped_data)
        finite = jnp.all(jnp.isfinite(theta)) & jnp.isfinite(chi2)
        converged = finite & ((decrement < DECREMENT_TOL) | settled_physics(step_sigma, plan.free))
        status = jnp.where(plan.active, fit_status(n_bins, finite, converged, redchi), 4)
        chi2 = jnp.where(plan.active & jnp.isfinite(chi2), chi2, jnp.inf)
        # the errors where the stage ended a solve (not G0's scouting), computed once for every later choice
        solved = plan.active & (plan.n_final > 0)
        e = jax.lax.cond(any_in_batch(solved), lambda: jax.tree.map(
            lambda x, o: jnp.where(solved, x, o), errors(record, lumped_data, plan.free, i0, theta, r, jac),
            blank),
            lambda: blank)
        new = (theta, plan.free, chi2, redchi, n_data.astype(dtype), status, plan.active, plan.hertz, e, r, jac, model,
               n_iter, plan.lumps)
        st = jax.tree.map(lambda whole, x: whole.at[k].set(x), st, Stages(*new))
        ends = jax.tree.map(lambda new, old: jnp.where(k == G0, new, old), (last, last_cost), ends)
        return (st, ends), None

    n = len(STAGES)
    args0 = (data_g, data_h, coef, jnp.asarray(False), jnp.zeros(N_LUMP_SD, dtype), jnp.zeros((N_DATA_ROWS, N_LUMP), dtype))
    r_shape, model_shape = jax.eval_shape(_either, prep_g.starts[0], args0)
    zeros = lambda x: jnp.zeros(x.shape, x.dtype)           # noqa: E731
    blank = jax.tree.map(zeros, jax.eval_shape(lambda: errors(record, data_g, prep_g.free, i0, prep_g.starts[0],
                                                              jnp.zeros(r_shape.shape, dtype),
                                                              jnp.zeros(r_shape.shape + (p,), dtype))))
    stacked = lambda tree: jax.tree.map(lambda x: jnp.zeros((n,) + x.shape, x.dtype), tree)    # noqa: E731
    init = Stages(jnp.zeros((n, p), dtype), jnp.zeros((n, p), bool), jnp.full(n, jnp.inf, dtype),
                  jnp.full(n, jnp.inf, dtype), jnp.zeros(n, dtype), jnp.full(n, 4, jnp.int32), jnp.zeros(n, bool),
                  jnp.zeros(n, bool), stacked(blank), jnp.zeros((n,) + r_shape.shape, dtype),
                  jnp.zeros((n,) + r_shape.shape + (p,), dtype), stacked(model_shape), jnp.zeros(n, jnp.int32),
                  jnp.zeros((n, N_LUMP_SD), dtype))
    (st, _), _ = jax.lax.scan(stage, (init, (prep_g.starts, jnp.full(prep_g.starts.shape[0], jnp.inf, dtype))),
                              jnp.arange(n))

    # the choices, from where the stages ended
    w = _window_fit(st, choices, bin_factor)
    t = _texture_fit(st, w.index, bin_factor)
    t_index = jnp.where(texture == 0, t.index, w.index)
    others = jnp.stack([w.choice.other, jnp.where(texture == 0, t.other, -1)])
    e_t = errors_at(st, t_index)
    d, d_margin, d_forced = _direction_fit(st, t_index, choices, e_t.scales)
    # a lumpy texture's refit (TL) replaces the fit it started from where it ran to a solution
    lumped = st.active[TL] & ((st.status[TL] == 0) | (st.status[TL] == 3))
    kept = jnp.where(lumped, TL, d)
    theta, free, e = st.theta[kept], st.free[kept], errors_at(st, kept)          # the kept fit
    e = e._replace(lumpy=e.lumpy | lumped)
    jac, model = st.jac[kept], jax.tree.map(lambda x: x[kept], st.model)
    # the random effects the kept fit has: TL's, from d's Jacobian; a refit's, given in its start
    lumps = st.lumps[kept]
    rows = jnp.where(lumped, effect_rows(st, d), jnp.where(refit, jnp.asarray(start.lump_rows, dtype), 0.0))
    data_g, data_h = (x._replace(lump_sd=lumps, lump_rows=rows) for x in (data_g, data_h))
    summary = summary_at(theta, free, e, Located(i0, b.n_leak, b.k0, b.speed0), model, jac, data_g)
    e_d = errors_at(st, d)
    needed, rise, threshold = _window_needed(st.active[WN], st.chi2[WN], e_d.chi2, e_d.scales[_I_A])
    other_sd = st.errors.sd[jnp.maximum(others, 0)][:, _I_VVA]
    nan3 = jnp.full(3, jnp.nan, dtype)
    return Analysis(
        summary=summary, data_h=data_h, window=w.hertz.astype(jnp.int32), window_margin=w.choice.margin,
        window_weight=w.choice.weight,
        window_other=jnp.where(others[0] >= 0, st.theta[jnp.maximum(others[0], 0)][_I_VVA], nan3),
        window_other_sd=other_sd[0], explored=w.explored, explored_chi2=jnp.stack([st.chi2[H1], st.chi2[HX]]),
        fresh=w.fresh, texture=jnp.where(texture == 0, t.directional, texture == 2).astype(jnp.int32),
        texture_margin=jnp.where(texture == 0, t.margin, jnp.nan),
        texture_weight=jnp.where(texture == 0, t.weight, 1.0),
        texture_other=jnp.where(others[1] >= 0, st.theta[jnp.maximum(others[1], 0)][_I_VVA], nan3),
        texture_other_sd=other_sd[1], texture_note=jnp.where(texture == 0, t.note, 0),
        texture_lobe=jnp.where(st.active[T4] & (t.index == T4), st.theta[T4], st.theta[T2])[_I_ANISO],
        texture_redchi=jnp.stack([st.redchi[w.index], st.redchi[T2]]),
        direction=jnp.where(~free[_I_V[0]] & free[_I_V[1]], 2, jnp.where(free[_I_V[0]] & ~free[_I_V[1]], 1, 0)),
        direction_margin=d_margin, direction_forced=d_forced,
        oblique_theta=st.theta[t_index], oblique_free=st.free[t_index], oblique_scales=e_t.scales, oblique_chi2=st.chi2[t_index],
        window_needed=needed, window_rise=rise, window_threshold=threshold, lumps=lumps, stages=st)


def summary_of(a: Analysis) -> Summary:
    """The kept fit's ``Summary`` with the data of its window (one record's ``Analysis``)."""
    return a.summary._replace(data=a.data_h) if int(a.window) == 1 else a.summary
