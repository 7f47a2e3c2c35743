"""Posterior sampling with emcee around a least-squares fit, with emcee's diagnostics, saved with ArviZ.

``run_emcee`` explores the free parameters of a :class:`~tactile_jax.problem.FitProblem`
with emcee's affine-invariant ensemble (stretch move). The log-probability is
``-0.5 * sum(r**2) / scale`` with a flat prior on the free parameters inside
``[lower, upper]`` in the internal (fitting) parametrisation (residuals taken at
the point pulled toward the fit by ``problem.stretch``, where given), evaluated for the
whole ensemble at once by one jit-compiled, vmapped JAX function. Sampler
trouble comes back as data (``PosteriorResult.warnings``), never as an
exception. ``to_inference_data`` converts a result to ArviZ and ``save_posterior``
writes it with ArviZ's netCDF-4 writer (both need the ``mcmc`` extra: arviz);
``load_posterior`` and ``read_attrs`` read a file back with h5py alone.
How to read the file: docs/posterior.md.
"""

from __future__ import annotations

import datetime
import json
import math
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache, partial
from pathlib import Path
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..io.atomic import atomic_write
from .._cores import usable_cores
from .._optional import need
from ..inference.problem import FitProblem

__all__ = ["PosteriorResult", "make_log_prob", "run_emcee", "to_inference_data", "save_posterior",
           "load_posterior", "read_attrs"]

TAU_FACTOR = 50                   # the chain must be this many autocorrelation times long
#: what the sampler's log-probability can run in. float32 takes about a third of float64's time on a CPU (XLA
#: vectorises float32 exp and log, which the joint model is mostly made of; docs/posterior.md gives the figures).
#: What it costs in accuracy is measured on every run, against float64 (``run_emcee``).
PRECISIONS = ("float32", "float64")
CHECK_DRAWS = 256
#: the largest sd over the checked draws of (float64 - float32) log-probability for a float32 run. A
#: target reweighted by exp(eps) moves a posterior mean by at most about sd(eps) posterior sds, here below
#: the Monte Carlo error of a mean, sd / sqrt(ESS), for an ESS up to 400; beyond it the chain runs in float64
PRECISION_TOL = 0.05
ACCEPTANCE_RANGE = (0.15, 0.8)    # healthy mean acceptance fraction of the stretch move
_SUMMARY_QUANTILES = {"median": 50.0, "q16": 16.0, "q84": 84.0, "q2.5": 2.5, "q97.5": 97.5}
_CHAIN_NOTE = ("emcee walker; the walkers of one ensemble are not independent chains (each move uses the "
               "others' positions): r_hat across them is not a convergence test, read tau and ess")
_DRAW_NOTE = "kept step of each walker (after burn-in and thinning)"


class PosteriorResult(NamedTuple):
    """Outcome of ``run_emcee``: kept draws (after burn-in and thinning) and sampler diagnostics.

    names: names of the sampled physical quantities from ``problem.to_physical`` (e.g. ``"vx"``):
        those that vary over the draws; quantities of fixed parameters alone are in ``fixed``.
    samples: name -> (n_walkers, n_draws) physical draws (units of ``to_physical``:
        m/s, m, ...); chain = walker.
    theta: (n_walkers, n_draws, n_free) draws of the internal free parameters.
    free_names: (n_free,) internal names of the free parameters.
    log_prob: (n_walkers, n_draws) log-probability of each draw.
    acceptance_fraction: mean over walkers of emcee's acceptance fraction (whole run).
    tau: (n_free,) integrated autocorrelation time, in steps, from the kept chain
        (emcee ``get_autocorr_time(discard=n_burn, thin=thin, quiet=True)``); NaN if not estimable.
    ess: effective sample size ``n_walkers * (n_steps - n_burn) / max(tau)``, capped at
        the number of kept draws; NaN when tau is not estimable.
    n_steps: steps run per walker (burn-in included). n_burn: steps discarded. thin: kept every ``thin``-th.
    warnings: human messages about the run (too short a chain, acceptance, stuck walkers); empty when healthy.
    walker_acceptance: (n_walkers,) acceptance fraction of each walker over the whole run.
    fixed: name -> value of the physical quantities that depend on fixed parameters only
        (one value for every draw, e.g. a gain ratio held at 1), in the units of ``to_physical``.
    precision: what the kept chain's log-probability was computed in ("float32" or "float64").
    lp_error: sd of the float64 log-probability less the float32 one, over up to ``CHECK_DRAWS`` kept
        draws of a float32 run, or over the fit and the Laplace draws that chose float64
        (NaN where float64 was asked for).
    """

    names: tuple[str, ...]
    samples: dict[str, np.ndarray]
    theta: np.ndarray
    free_names: tuple[str, ...]
    log_prob: np.ndarray
    acceptance_fraction: float
    tau: np.ndarray
    ess: float
    n_steps: int
    n_burn: int
    thin: int
    warnings: tuple[str, ...]
    walker_acceptance: np.ndarray
    fixed: dict[str, float]
    precision: str = "float64"
    lp_error: float = math.nan

    @property
    def max_tau(self) -> float:
        """Largest integrated autocorrelation time over the free parameters (steps; NaN if unknown)."""
        tau = np.asarray(self.tau, float)
        return float(np.max(tau)) if tau.size and np.all(np.isfinite(tau)) else math.nan

    def summary(self) -> dict[str, dict]:
        """Per sampled quantity: ``mean``, ``sd`` (ddof=1), ``median``, ``q16``, ``q84``, ``q2.5``, ``q97.5``
        in the quantity's own units (m/s, m, ...), and emcee's diagnostics of its chain: ``tau``
        (integrated autocorrelation time, steps; NaN if not estimable) and ``ess``
        (``n_walkers * (n_steps - n_burn) / tau``, capped at the number of draws)."""
        out = {}
        for name in self.names:
            draws = np.asarray(self.samples[name], float)
            x = draws.ravel()
            row = {"mean": float(np.mean(x)), "sd": float(np.std(x, ddof=1)) if x.size > 1 else math.nan}
            qs = np.percentile(x, list(_SUMMARY_QUANTILES.values()))
            row.update({k: float(q) for k, q in zip(_SUMMARY_QUANTILES, qs)})
            tau = _quantity_tau(draws, self.thin)
            row["tau"] = tau
            row["ess"] = _ess(draws.shape[0], self.n_steps - self.n_burn, x.size, tau)
            out[name] = row
        return out


def _quantity_tau(draws, thin) -> float:
    """emcee's integrated autocorrelation time (steps) of one (n_walkers, n_draws) chain; NaN if not estimable."""
    import emcee

    try:
        # tol=0: the 50-tau rule is applied (and reported) by run_emcee itself
        tau = float(emcee.autocorr.integrated_time(np.asarray(draws, float).T[:, :, None], tol=0, quiet=True)[0])
    except Exception:  # noqa: BLE001 - a chain too short for any estimate
        return math.nan
    return thin * tau if math.isfinite(tau) and tau > 0 else math.nan


def _ess(n_walkers, n_kept_steps, n_draws, tau) -> float:
    """``n_walkers * n_kept_steps / tau`` capped at ``n_draws``; NaN when tau is NaN."""
    return float(min(n_walkers * n_kept_steps / tau, n_draws)) if math.isfinite(tau) else math.nan


# ---------------------------------------------------------------- log-probability

@partial(jax.jit, static_argnames=("residuals", "sequential"))
def _log_prob_batch(theta_free, residuals, args, theta0, idx, lower, upper, scale, stretch, sequential=False):
    """(n_walkers, n_free) free parameters -> (n_walkers,) log-probabilities (-inf outside the bounds); the
    walkers side by side (vmap), or one after another in the same program (``sequential``: lax.map)."""
    centre = theta0[idx]

    def one(tf):
        r = residuals(theta0.at[idx].set(centre + (tf - centre) / stretch), args)
        lp = -0.5 * jnp.sum(jnp.square(r)) / scale
        inside = jnp.all((tf >= lower) & (tf <= upper))
        return jnp.where(inside & jnp.isfinite(lp), lp, -jnp.inf)

    return jax.lax.map(one, theta_free) if sequential else jax.vmap(one)(theta_free)


def _free_index(problem: FitProblem) -> np.ndarray:
    free = np.asarray(problem.free, bool)
    if free.shape != np.shape(problem.theta):
        raise ValueError(f"problem.free has shape {free.shape}, theta has {np.shape(problem.theta)}")
    return np.flatnonzero(free)


@lru_cache(maxsize=None)
def _pool(workers: int) -> ThreadPoolExecutor:
    return ThreadPoolExecutor(workers, thread_name_prefix="tactile_jax-walkers")


def make_log_prob(problem: FitProblem, block: int = 16, workers: int = 1) -> Callable:
    """Log-probability of an ensemble of free-parameter vectors for ``problem``.

    Returns ``log_prob(theta_free)``: (n_walkers, n_free) numpy or jax array of the
    free internal parameters (units of ``problem.names``) -> (n_walkers,) numpy
    float64 ``-0.5 * sum(r**2) / problem.scale`` (``r`` at ``theta + (t - theta) / stretch``
    when ``problem.stretch`` is given), or ``-inf`` outside
    ``[lower, upper]`` (inclusive; a flat prior in the internal parametrisation)
    or where the residuals are not finite. One jit-compiled function of ``block``
    walkers (side by side in float32, one after another in float64), shared between problems with the same residual function and shapes: any
    number of walkers is evaluated in blocks of that size (the last one padded), so the
    starting ball, the initial ensemble and each half-ensemble step of the stretch move
    share one compilation (a compile of the joint model's log-probability costs more than
    a few hundred of its evaluations). workers: threads that evaluate the blocks of one call side by side (the
    walkers of a block go one after another, in operations too small for XLA to spread over the cores).
    """
    if block < 1:
        raise ValueError(f"block must be >= 1, got {block}")
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    idx = _free_index(problem)
    theta0 = jnp.asarray(problem.theta)
    dtype = theta0.dtype
    lower = jnp.asarray(np.asarray(problem.lower, float)[idx], dtype)
    upper = jnp.asarray(np.asarray(problem.upper, float)[idx], dtype)
    scale = jnp.asarray(float(problem.scale), dtype)
    stretch = np.ones(idx.size) if problem.stretch is None else np.asarray(problem.stretch, float)[idx]
    if not np.all(np.isfinite(stretch) & (stretch > 0)):
        raise ValueError(f"problem.stretch must be finite and > 0 on the free parameters, got {stretch}")
    stretch = jnp.asarray(stretch, dtype)
    idx_j = jnp.asarray(idx)
    # on a CPU XLA vectorises float32 exp and log across the walkers, while in float64 the walker axis only adds
    # memory traffic (the Hertz table's slices gathered per walker): 16 walkers of a Gaussian-window fit take
    # 5.2 ms side by side against 6.4 one after another in float32, 17.1 against 11.5 ms in float64, and of a
    # Hertz fit in float64 68 against 19 ms
    sequential = dtype != jnp.float32
    residuals = problem.residuals
    # on the device once: numpy leaves would be copied there at every call (a Hertz fit's: 14 ms a call of 16 walkers)
    args = jax.device_put(problem.args if problem.sampling_args is None else problem.sampling_args())

    def log_prob(theta_free):
        tf = np.asarray(theta_free, np.float64)
        squeeze = tf.ndim == 1
        tf = np.atleast_2d(tf)
        n = tf.shape[0]
        padded = np.concatenate([tf, np.broadcast_to(tf[:1], (-n % block, tf.shape[1]))])
        blocks = [padded[i:i + block] for i in range(0, padded.shape[0], block)]
        run = (map if workers == 1 or len(blocks) == 1 else _pool(workers).map)(one_block, blocks)
        lp = np.concatenate(list(run))[:n]
        return lp[0] if squeeze else lp

    def one_block(b):
        return np.asarray(_log_prob_batch(jnp.asarray(b, dtype), residuals, args, theta0, idx_j, lower, upper, scale,
                                          stretch, sequential), np.float64)

    return log_prob


def _in_precision(problem: FitProblem, precision: str) -> FitProblem:
    """``problem`` with its arguments' floating arrays and theta in ``precision`` (complex ones to match)."""
    real = jnp.dtype(precision)
    cplx = jnp.result_type(real, jnp.complex64)

    def cast(x):
        if isinstance(x, (jax.Array, np.ndarray)) and jnp.issubdtype(x.dtype, jnp.inexact):
            return jnp.asarray(x, cplx if jnp.issubdtype(x.dtype, jnp.complexfloating) else real)
        return x

    sampling = None if problem.sampling_args is None else (lambda: jax.tree.map(cast, problem.sampling_args()))
    return problem._replace(args=jax.tree.map(cast, problem.args), sampling_args=sampling,
                            theta=np.asarray(problem.theta, real))


# ---------------------------------------------------------------- sampling

def _initial_ball(problem: FitProblem, idx, n_walkers, rng, log_prob):
    """Walkers in a Gaussian ball of 0.1 Laplace sd around the fit, inside the bounds, with finite log-prob."""
    theta = np.asarray(problem.theta, float)[idx]
    lo = np.asarray(problem.lower, float)[idx]
    hi = np.asarray(problem.upper, float)[idx]
    with np.errstate(invalid="ignore"):
        sd = np.sqrt(np.diag(np.asarray(problem.cov, float))[idx])
    bad = ~np.isfinite(sd) | (sd <= 0)
    sd = np.where(bad, 1e-4 * np.abs(theta) + 1e-6, sd)
    spread = 0.1 * sd
    if not log_prob(theta[None]).item() > -np.inf:
        raise ValueError("the log-probability at the least-squares fit is -inf "
                         "(fit outside its bounds, or non-finite residuals); refit before sampling")

    def draw(n, s):
        p = theta + s * rng.standard_normal((n, theta.size))
        p = np.where(p < lo, 2 * lo - p, p)              # reflect into the box, keeping walkers distinct
        p = np.where(p > hi, 2 * hi - p, p)
        return np.clip(p, lo, hi)

    p0 = draw(n_walkers, spread)
    for _ in range(20):                                   # shrink towards the fit where a walker landed on -inf
        lp = log_prob(p0)
        out = ~(lp > -np.inf)
        if not out.any():
            return p0
        spread = spread / 4
        p0[out] = draw(int(out.sum()), spread)
    raise ValueError("could not place the walkers where the log-probability is finite")


def _autocorr_time(sampler, burn, thin, n_free):
    try:
        # tol=0: the 50-tau rule is applied (and reported) by run_emcee itself
        tau = np.asarray(sampler.get_autocorr_time(discard=burn, thin=thin, quiet=True, tol=0), float)
    except Exception:  # noqa: BLE001 - a chain too short for any estimate
        tau = np.full(n_free, np.nan)
    return np.where(np.isfinite(tau) & (tau > 0), tau, np.nan)


def _diagnose(n_walkers, n_steps, tau, acc, walker_acc, log_prob, n_free):
    msgs = []
    if not np.all(np.isfinite(tau)):
        msgs.append(f"autocorrelation time not estimable (n_steps = {n_steps}); run a longer chain")
    elif n_steps < TAU_FACTOR * tau.max():
        msgs.append(f"chain shorter than {TAU_FACTOR} autocorrelation times "
                    f"(n_steps = {n_steps}, max tau = {tau.max():.1f})")
    lo, hi = ACCEPTANCE_RANGE
    if not lo <= acc <= hi:
        msgs.append(f"acceptance fraction {acc:.2f} outside [{lo}, {hi}]")
    med_acc = np.median(walker_acc)
    walker_lp = np.mean(np.where(np.isfinite(log_prob), log_prob, -1e300), axis=1)
    drop = 10.0 + n_free
    stuck = (walker_acc < 0.1 * med_acc) | (walker_lp < np.median(walker_lp) - drop)
    if stuck.any():
        msgs.append(f"{int(stuck.sum())} of {n_walkers} walkers stuck (acceptance < 10% of the median "
                    f"{med_acc:.2f}, or mean log-prob more than {drop:.0f} below the median walker's)")
    return tuple(msgs)


def run_emcee(problem: FitProblem, *, n_walkers: int = 32, n_steps: int = 2000, burn: int | None = None,
              thin: int = 1, seed: int = 0, progress: bool = False, precision: str = "float32") -> PosteriorResult:
    """Sample the posterior of ``problem``'s free parameters with emcee around its least-squares fit.

    n_walkers: ensemble size; must be at least ``2 * n_free`` (ValueError otherwise:
        the stretch move needs it, and silently changing the shape of the result is worse).
    n_steps: steps per walker, burn-in included. burn: steps discarded (default
        ``n_steps // 4``). thin: keep every ``thin``-th step after burn-in.
    seed: ``np.random.default_rng(seed)`` draws the starting ball and the seed of
        emcee's internal (legacy ``RandomState``) generator, so the same seed gives
        identical chains. progress: emcee's tqdm progress bar.

    Physical quantities that do not vary over the draws (functions of fixed parameters
    alone) go to ``PosteriorResult.fixed``, not ``samples``.
    precision: what the log-probability is sampled in (``PRECISIONS``). "float32" runs the residuals
        in float32 (``problem.args`` cast) where their log-probability keeps within ``PRECISION_TOL``
        of float64's (sd; ``PosteriorResult.lp_error``): at the fit and ``n_walkers`` draws of
        the Laplace approximation before the run, and at ``CHECK_DRAWS`` kept draws after it; where it does not,
        the chain is sampled (again) in float64 with the same seed. A problem whose ``precision`` is
        "float64" (the joint model under the Hertz disk) is sampled in float64 whatever is asked.
    Walkers start in a Gaussian ball of 0.1 Laplace sd (``problem.cov``; ``1e-4 |theta| + 1e-6``
    where that sd is 0 or not finite) around ``problem.theta``, kept inside the bounds. Warnings
    (as data): ``n_steps < 50 * max(tau)``, mean acceptance outside [0.15, 0.8], stuck walkers.
    Raises ValueError for invalid sizes or a fit whose own log-probability is -inf.
    """
    idx = _free_index(problem)
    n_free = idx.size
    if n_free == 0:
        raise ValueError("problem has no free parameters to sample")
    if n_walkers < 2 * n_free:
        raise ValueError(f"n_walkers = {n_walkers} is fewer than 2 * n_free = {2 * n_free}; "
                         f"use n_walkers >= {2 * n_free}")
    burn = n_steps // 4 if burn is None else int(burn)
    if n_steps < 2 or not 0 <= burn < n_steps:
        raise ValueError(f"need n_steps >= 2 and 0 <= burn < n_steps (n_steps = {n_steps}, burn = {burn})")
    if thin < 1:
        raise ValueError(f"thin must be >= 1, got {thin}")
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}")
    if problem.precision not in PRECISIONS:
        raise ValueError(f"problem.precision must be one of {PRECISIONS}, got {problem.precision!r}")
    precision = max(precision, problem.precision, key=PRECISIONS.index)
    # the stretch move's half ensemble, spread over the cores: on a 2-core CPU two blocks of 8 walkers on two
    # threads take 60 % of the time of one block of 16 (a Hertz fit's, float64)
    workers = max(1, min(len(usable_cores()), -(-n_walkers // 2)))
    block = -(-n_walkers // (2 * workers))
    high = make_log_prob(problem, block=block, workers=workers)
    lp_error = math.nan
    if precision == "float32":
        low = make_log_prob(_in_precision(problem, "float32"), block=block, workers=workers)
        # first at the fit and draws of the Laplace approximation, so that a model float32 cannot carry costs no run
        checks = np.vstack([np.asarray(problem.theta, float)[idx][None], _laplace_draws(problem, idx, n_walkers, seed)])
        lp_error = _lp_error(checks, None, low, high)
        if lp_error <= PRECISION_TOL:
            post = _sample(problem, low, idx, n_walkers, n_steps, burn, thin, seed, progress)
            theta = post.theta.reshape(-1, idx.size)
            pick = np.unique(np.linspace(0, theta.shape[0] - 1, min(CHECK_DRAWS, theta.shape[0])).astype(int))
            lp_error = _lp_error(theta[pick], post.log_prob.ravel()[pick], low, high)
            if lp_error <= PRECISION_TOL:
                return post._replace(precision="float32", lp_error=lp_error)
    post = _sample(problem, high, idx, n_walkers, n_steps, burn, thin, seed, progress)
    return post._replace(precision="float64", lp_error=lp_error)


def _laplace_draws(problem: FitProblem, idx, n, seed) -> np.ndarray:
    """n draws of the free parameters from the fit's Laplace approximation, clipped to the bounds."""
    theta = np.asarray(problem.theta, float)[idx]
    cov = np.asarray(problem.cov, float)[np.ix_(idx, idx)]
    cov = np.where(np.isfinite(cov), cov, 0.0)
    w, v = np.linalg.eigh(0.5 * (cov + cov.T))
    z = np.random.default_rng(seed).standard_normal((n, idx.size))
    draws = theta + (z * np.sqrt(np.clip(w, 0.0, None))) @ v.T
    return np.clip(draws, np.asarray(problem.lower, float)[idx], np.asarray(problem.upper, float)[idx])


def _lp_error(theta, low_lp, low, high) -> float:
    """sd over the draws ``theta`` (n, n_free) of the float64 log-probability ``high`` less the float32 one
    (``low_lp`` where the run computed it, else ``low``); inf where one is finite and the other not."""
    low_lp = low(theta) if low_lp is None else low_lp
    high_lp = high(theta)
    if np.any(np.isfinite(low_lp) != np.isfinite(high_lp)):
        return math.inf
    eps = (high_lp - low_lp)[np.isfinite(low_lp)]
    return float(np.std(eps)) if eps.size > 1 else 0.0


def _sample(problem, log_prob, idx, n_walkers, n_steps, burn, thin, seed, progress) -> PosteriorResult:
    # emcee (with scipy.stats) is imported where it samples: 0.8 s of every command's start otherwise
    import emcee

    n_free = idx.size
    rng = np.random.default_rng(seed)
    p0 = _initial_ball(problem, idx, n_walkers, rng, log_prob)
    emcee_state = np.random.RandomState(int(rng.integers(2**32))).get_state()
    sampler = emcee.EnsembleSampler(n_walkers, n_free, log_prob, vectorize=True)
    sampler.run_mcmc(emcee.State(p0, random_state=emcee_state), n_steps, progress=progress)

    chain = np.swapaxes(sampler.get_chain(discard=burn, thin=thin), 0, 1)       # (walker, draw, free)
    lp = np.swapaxes(sampler.get_log_prob(discard=burn, thin=thin), 0, 1)
    walker_acc = np.asarray(sampler.acceptance_fraction, float)
    acc = float(np.mean(walker_acc))
    tau = _autocorr_time(sampler, burn, thin, n_free)
    n_draws = chain.shape[1]
    ess = _ess(n_walkers, n_steps - burn, n_walkers * n_draws, float(tau.max()) if np.all(np.isfinite(tau)) else math.nan)

    full = np.broadcast_to(np.asarray(problem.theta, float), chain.shape[:2] + (np.size(problem.theta),)).copy()
    full[..., idx] = chain
    phys = problem.to_physical(full)
    samples, fixed = {}, {}
    for k, v in phys.items():
        v = np.broadcast_to(np.asarray(v, float), chain.shape[:2])
        if np.all(v == v.flat[0]):                        # a function of fixed parameters only
            fixed[str(k)] = float(v.flat[0])
        else:
            samples[str(k)] = v.copy()
    free_names = tuple(str(problem.names[i]) for i in idx)
    return PosteriorResult(
        names=tuple(samples), samples=samples, theta=chain, free_names=free_names, log_prob=lp,
        acceptance_fraction=acc, tau=tau, ess=ess, n_steps=int(n_steps), n_burn=burn, thin=int(thin),
        warnings=_diagnose(n_walkers, n_steps, tau, acc, walker_acc, lp, n_free),
        walker_acceptance=walker_acc, fixed=fixed)


# ---------------------------------------------------------------- ArviZ InferenceData and files

def _json_float(x):
    x = float(x)
    return x if math.isfinite(x) else None                # JSON has no NaN: null


def _provenance_attrs() -> dict[str, Any]:
    import emcee

    return {
        "created_by": "tactile_jax",
        "created_at": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "inference_library": "emcee",
        "inference_library_version": emcee.__version__,
    }


def _run_attrs(result: PosteriorResult) -> dict[str, Any]:
    """Run attributes: provenance, emcee's diagnostics and settings; lists and dicts as JSON strings."""
    return {
        **_provenance_attrs(),
        "comment": "chain = emcee walker (not independent chains: r_hat across walkers is not a convergence "
                   "test); diagnostics: tau (steps), ess, acceptance_fraction, warnings",
        "tau": json.dumps([_json_float(t) for t in np.asarray(result.tau).ravel()]),
        "ess": json.dumps(_json_float(result.ess)),
        "acceptance_fraction": float(result.acceptance_fraction),
        "warnings": json.dumps(list(result.warnings)),
        "free_names": json.dumps(list(result.free_names)),
        "fixed": json.dumps({k: _json_float(v) for k, v in result.fixed.items()}),
        "n_walkers": int(np.shape(result.log_prob)[0]),
        "n_steps": int(result.n_steps),
        "n_burn": int(result.n_burn),
        "thin": int(result.thin),
        "precision": str(result.precision),
        "lp_error": json.dumps(_json_float(result.lp_error)),
    }


def _user_attr(value):
    if isinstance(value, (str, int, float, np.integer, np.floating)) and not isinstance(value, bool):
        return value
    return json.dumps(value, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))


def _diagnostics(tau, ess) -> dict[str, float]:
    return {"tau": float(tau), "ess": float(ess)}


def to_inference_data(result: PosteriorResult, *, observed: dict | None = None, attrs: dict | None = None):
    """ArviZ ``InferenceData`` (arviz < 1) or ``xarray.DataTree`` (arviz >= 1) of ``result``.

    Groups: ``posterior`` (the sampled physical quantities, dims (chain, draw), chain =
    walker; each with attributes ``tau`` (steps) and ``ess`` from ``result.summary()``),
    ``unconstrained_posterior`` (internal free parameters, with ``tau`` and ``ess``),
    ``sample_stats`` (``lp`` (chain, draw); ``acceptance_rate`` (chain,) per walker over
    the whole run) and, given ``observed`` (name -> array), ``observed_data``. Attributes
    of the whole and of ``posterior``: provenance, ``comment`` (how to read it), ``tau``,
    ``ess``, ``warnings``, ``free_names``, ``fixed`` (JSON strings), ``acceptance_fraction``,
    run settings and the user's ``attrs`` (non-scalars as JSON). Needs the ``mcmc`` extra
    (``MissingExtra`` naming it otherwise).
    """
    az = need("arviz", "mcmc", "to_inference_data")
    import xarray as xr

    n_walkers, n_draws = result.log_prob.shape
    coords = {"chain": ("chain", np.arange(n_walkers, dtype=np.int64), {"long_name": _CHAIN_NOTE}),
              "draw": ("draw", np.arange(n_draws, dtype=np.int64), {"long_name": _DRAW_NOTE})}
    cd = ("chain", "draw")
    run_attrs = {**_run_attrs(result), **{k: _user_attr(v) for k, v in (attrs or {}).items()}}
    summary = result.summary()
    n_kept = result.n_steps - result.n_burn
    posterior = {k: (cd, np.asarray(v, float), _diagnostics(summary[k]["tau"], summary[k]["ess"]))
                 for k, v in result.samples.items()}
    unconstrained = {k: (cd, result.theta[..., i],
                         _diagnostics(result.tau[i], _ess(n_walkers, n_kept, n_walkers * n_draws, result.tau[i])))
                     for i, k in enumerate(result.free_names)}
    stats = {"lp": (cd, np.asarray(result.log_prob, float)),
             "acceptance_rate": (("chain",), np.asarray(result.walker_acceptance, float))}
    provenance = {k: run_attrs[k] for k in _provenance_attrs()}
    groups = {
        "posterior": xr.Dataset(posterior, coords=coords, attrs=run_attrs),
        "unconstrained_posterior": xr.Dataset(unconstrained, coords=coords, attrs=provenance),
        "sample_stats": xr.Dataset(stats, coords=coords, attrs=provenance),
    }
    if observed:
        groups["observed_data"] = xr.Dataset(
            {k: ([f"{k}_dim_{i}" for i in range(np.ndim(v))], np.asarray(v)) for k, v in observed.items()},
            attrs=provenance)
    if hasattr(az, "InferenceData"):                      # arviz < 1.0
        return az.InferenceData(attrs=run_attrs, **groups)
    tree = xr.DataTree.from_dict(groups)                  # arviz >= 1.0 works on DataTree
    tree.attrs.update(run_attrs)
    return tree


def save_posterior(path, result: PosteriorResult, *, attrs: dict | None = None) -> Path:
    """Write ``result`` to ``path`` (.h5 or .nc, netCDF-4) with ArviZ: ``to_inference_data(...).to_netcdf``.

    The layout and attributes are those of ``to_inference_data`` (groups ``posterior``,
    ``unconstrained_posterior``, ``sample_stats``; physical quantities in the units of
    ``to_physical``: m/s, m, ...; quantities of fixed parameters alone are not sampled
    and are listed in the ``fixed`` attribute). ``az.from_netcdf`` or ``load_posterior``
    read it back.

    Reading the diagnostics: ``chain`` holds emcee's walkers so that ArviZ can read the
    file, but the walkers of one ensemble are not independent chains (each move of a
    walker is drawn from the positions of the others) and they start in a small ball
    around the fit, so ArviZ's r_hat across them (``az.summary``) is not a convergence
    test, and its ESS is not emcee's. The diagnostics to read are emcee's: ``tau``
    (integrated autocorrelation time, steps, per free parameter in the attributes and
    per quantity on each variable), ``ess`` (``n_walkers * (n_steps - n_burn) / tau``),
    ``acceptance_fraction`` and ``warnings``; a run is long enough when
    ``n_steps >= 50 * tau`` (otherwise ``warnings`` says so, and tau itself is
    underestimated).

    Atomic, with the permissions of a plain new file (``_atomic.atomic_write``); the
    folder must exist. Needs the ``mcmc`` extra (arviz).
    """
    idata = to_inference_data(result, attrs=attrs)
    return atomic_write(path, idata.to_netcdf)


def load_posterior(path) -> dict[str, dict[str, np.ndarray]]:
    """Read a ``save_posterior`` file: group -> variable -> array (dimensions ``chain``/``draw`` left out).

    Needs h5py alone (no arviz)."""
    import h5py

    out: dict[str, dict[str, np.ndarray]] = {}
    with h5py.File(path, "r") as h5:
        for gname, grp in h5.items():
            if not isinstance(grp, h5py.Group):
                continue
            out[gname] = {k: ds[()] for k, ds in grp.items()
                          if isinstance(ds, h5py.Dataset) and not ds.is_scale}
    return out


def read_attrs(path) -> dict[str, Any]:
    """Run attributes of a ``save_posterior`` file, JSON strings (``tau``, ``ess``, ``warnings``, ``fixed``, ...)
    decoded; netCDF's own (``_NCProperties``, ...) left out. Needs h5py alone."""
    import h5py

    out: dict[str, Any] = {}
    with h5py.File(path, "r") as h5:
        for k, v in h5.attrs.items():
            if k.startswith("_"):
                continue
            v = v.decode() if isinstance(v, bytes) else v
            if isinstance(v, str):
                try:
                    v = json.loads(v)
                except ValueError:
                    pass
            elif isinstance(v, (np.generic, np.ndarray)):
                v = v.item() if np.size(v) == 1 else v.tolist()     # netCDF stores a number as a 1-array
            out[k] = v
    return out
