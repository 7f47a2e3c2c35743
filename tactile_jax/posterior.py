"""Posterior sampling with emcee around a least-squares fit, with diagnostics and ArviZ-layout files.

``run_emcee`` explores the free parameters of a :class:`~tactile_jax.problem.FitProblem`
with emcee's affine-invariant ensemble (stretch move). The log-probability is
``-0.5 * sum(r**2) / scale`` with a flat prior on the free parameters inside
``[lower, upper]`` in the internal (fitting) parametrisation (residuals taken at
the point pulled toward the fit by ``problem.stretch``, where given), evaluated for the
whole ensemble at once by one jit-compiled, vmapped JAX function. Sampler
trouble comes back as data (``PosteriorResult.warnings``), never as an
exception. ``to_inference_data`` converts a result to ArviZ (optional
dependency); ``save_posterior`` writes the same InferenceData layout to HDF5 /
netCDF-4 with h5py alone, and ``load_posterior`` reads it back.
"""

from __future__ import annotations

import datetime
import json
import math
import os
import tempfile
from functools import partial
from pathlib import Path
from typing import Any, Callable, NamedTuple

import emcee
import jax
import jax.numpy as jnp
import numpy as np

from .problem import FitProblem

__all__ = ["PosteriorResult", "make_log_prob", "run_emcee", "to_inference_data", "save_posterior",
           "load_posterior", "read_attrs"]

TAU_FACTOR = 50                   # the chain must be this many autocorrelation times long
ACCEPTANCE_RANGE = (0.15, 0.8)    # healthy mean acceptance fraction of the stretch move
_SUMMARY_QUANTILES = {"median": 50.0, "q16": 16.0, "q84": 84.0, "q2.5": 2.5, "q97.5": 97.5}


class PosteriorResult(NamedTuple):
    """Outcome of ``run_emcee``: kept draws (after burn-in and thinning) and sampler diagnostics.

    names: physical quantity names from ``problem.to_physical`` (e.g. ``"vx"``).
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

    @property
    def max_tau(self) -> float:
        """Largest integrated autocorrelation time over the free parameters (steps; NaN if unknown)."""
        tau = np.asarray(self.tau, float)
        return float(np.max(tau)) if tau.size and np.all(np.isfinite(tau)) else math.nan

    def summary(self) -> dict[str, dict]:
        """Per physical name: ``mean``, ``sd`` (ddof=1), ``median``, ``q16``, ``q84``, ``q2.5``, ``q97.5``.

        Values are in the quantity's own units (m/s, m, ...)."""
        out = {}
        for name in self.names:
            x = np.asarray(self.samples[name], float).ravel()
            row = {"mean": float(np.mean(x)), "sd": float(np.std(x, ddof=1)) if x.size > 1 else math.nan}
            qs = np.percentile(x, list(_SUMMARY_QUANTILES.values()))
            row.update({k: float(q) for k, q in zip(_SUMMARY_QUANTILES, qs)})
            out[name] = row
        return out


# ---------------------------------------------------------------- log-probability

@partial(jax.jit, static_argnames=("residuals",))
def _log_prob_batch(theta_free, residuals, args, theta0, idx, lower, upper, scale, stretch):
    """(n_walkers, n_free) free parameters -> (n_walkers,) log-probabilities (-inf outside the bounds)."""
    centre = theta0[idx]

    def one(tf):
        r = residuals(theta0.at[idx].set(centre + (tf - centre) / stretch), args)
        lp = -0.5 * jnp.sum(jnp.square(r)) / scale
        inside = jnp.all((tf >= lower) & (tf <= upper))
        return jnp.where(inside & jnp.isfinite(lp), lp, -jnp.inf)

    return jax.vmap(one)(theta_free)


def _free_index(problem: FitProblem) -> np.ndarray:
    free = np.asarray(problem.free, bool)
    if free.shape != np.shape(problem.theta):
        raise ValueError(f"problem.free has shape {free.shape}, theta has {np.shape(problem.theta)}")
    return np.flatnonzero(free)


def make_log_prob(problem: FitProblem) -> Callable:
    """Log-probability of an ensemble of free-parameter vectors for ``problem``.

    Returns ``log_prob(theta_free)``: (n_walkers, n_free) numpy or jax array of the
    free internal parameters (units of ``problem.names``) -> (n_walkers,) numpy
    float64 ``-0.5 * sum(r**2) / problem.scale`` (``r`` at ``theta + (t - theta) / stretch``
    when ``problem.stretch`` is given), or ``-inf`` outside
    ``[lower, upper]`` (inclusive; a flat prior in the internal parametrisation)
    or where the residuals are not finite. One jit-compiled vmapped function,
    shared between problems with the same residual function and shapes.
    """
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
    residuals, args = problem.residuals, problem.args

    def log_prob(theta_free):
        tf = jnp.asarray(theta_free, dtype)
        squeeze = tf.ndim == 1
        lp = _log_prob_batch(jnp.atleast_2d(tf), residuals, args, theta0, idx_j, lower, upper, scale, stretch)
        lp = np.asarray(lp, np.float64)
        return lp[0] if squeeze else lp

    return log_prob


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
              thin: int = 1, seed: int = 0, progress: bool = False) -> PosteriorResult:
    """Sample the posterior of ``problem``'s free parameters with emcee around its least-squares fit.

    n_walkers: ensemble size; must be at least ``2 * n_free`` (ValueError otherwise:
        the stretch move needs it, and silently changing the shape of the result is worse).
    n_steps: steps per walker, burn-in included. burn: steps discarded (default
        ``n_steps // 4``). thin: keep every ``thin``-th step after burn-in.
    seed: ``np.random.default_rng(seed)`` draws the starting ball and the seed of
        emcee's internal (legacy ``RandomState``) generator, so the same seed gives
        identical chains. progress: emcee's tqdm progress bar.

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

    log_prob = make_log_prob(problem)
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
    ess = (float(min(n_walkers * (n_steps - burn) / tau.max(), n_walkers * n_draws))
           if np.all(np.isfinite(tau)) else math.nan)

    full = np.broadcast_to(np.asarray(problem.theta, float), chain.shape[:2] + (np.size(problem.theta),)).copy()
    full[..., idx] = chain
    phys = problem.to_physical(full)
    samples = {str(k): np.broadcast_to(np.asarray(v, float), chain.shape[:2]).copy() for k, v in phys.items()}
    free_names = tuple(str(problem.names[i]) for i in idx)
    return PosteriorResult(
        names=tuple(samples), samples=samples, theta=chain, free_names=free_names, log_prob=lp,
        acceptance_fraction=acc, tau=tau, ess=ess, n_steps=int(n_steps), n_burn=burn, thin=int(thin),
        warnings=_diagnose(n_walkers, n_steps, tau, acc, walker_acc, lp, n_free),
        walker_acceptance=walker_acc)


# ---------------------------------------------------------------- ArviZ InferenceData

def _json_float(x):
    x = float(x)
    return x if math.isfinite(x) else None                # JSON has no NaN: null


def _run_attrs(result: PosteriorResult) -> dict[str, Any]:
    """Root attributes: scalars as such, lists and diagnostics as JSON strings."""
    return {
        "created_by": "tactile_jax",
        "created_at": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "inference_library": "emcee",
        "inference_library_version": emcee.__version__,
        "tau": json.dumps([_json_float(t) for t in np.asarray(result.tau).ravel()]),
        "ess": json.dumps(_json_float(result.ess)),
        "warnings": json.dumps(list(result.warnings)),
        "free_names": json.dumps(list(result.free_names)),
        "acceptance_fraction": float(result.acceptance_fraction),
        "n_steps": int(result.n_steps),
        "n_burn": int(result.n_burn),
        "thin": int(result.thin),
    }


def _user_attr(value):
    if isinstance(value, (str, bool, int, float, np.integer, np.floating, np.bool_)):
        return value
    return json.dumps(value, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))


def to_inference_data(result: PosteriorResult, *, observed: dict | None = None, attrs: dict | None = None):
    """ArviZ ``InferenceData`` (arviz < 1) or ``xarray.DataTree`` (arviz >= 1) of ``result``.

    Groups: ``posterior`` (physical quantities, dims (chain, draw), chain = walker),
    ``unconstrained_posterior`` (internal free parameters), ``sample_stats`` (``lp``
    (chain, draw); ``acceptance_rate`` (chain,) per walker over the whole run) and,
    given ``observed`` (name -> array), ``observed_data``. Attributes: ``tau``,
    ``ess``, ``warnings`` (JSON strings), run settings and ``attrs``.
    Requires arviz (ImportError naming ``pip install arviz`` otherwise).
    """
    try:
        import arviz as az
        import xarray as xr
    except ImportError as err:
        raise ImportError("to_inference_data needs arviz: pip install arviz "
                          "(or use save_posterior, which needs only h5py)") from err
    n_walkers, n_draws = result.log_prob.shape
    coords = {"chain": np.arange(n_walkers), "draw": np.arange(n_draws)}
    run_attrs = {**_run_attrs(result), **{k: _user_attr(v) for k, v in (attrs or {}).items()}}
    groups = {
        "posterior": xr.Dataset({k: (("chain", "draw"), np.asarray(v)) for k, v in result.samples.items()},
                                coords=coords, attrs=run_attrs),
        "unconstrained_posterior": xr.Dataset(
            {k: (("chain", "draw"), result.theta[..., i]) for i, k in enumerate(result.free_names)},
            coords=coords, attrs=run_attrs),
        "sample_stats": xr.Dataset({"lp": (("chain", "draw"), result.log_prob),
                                    "acceptance_rate": (("chain",), np.asarray(result.walker_acceptance))},
                                   coords=coords, attrs=run_attrs),
    }
    if observed:
        groups["observed_data"] = xr.Dataset(
            {k: ([f"{k}_dim_{i}" for i in range(np.ndim(v))], np.asarray(v)) for k, v in observed.items()},
            attrs=run_attrs)
    if hasattr(az, "InferenceData"):                      # arviz < 1.0
        return az.InferenceData(**groups)
    tree = xr.DataTree.from_dict(groups)                  # arviz >= 1.0 works on DataTree
    tree.attrs.update(run_attrs)
    return tree


# ---------------------------------------------------------------- HDF5 / netCDF-4 files

def _write_group(h5, name, variables: dict[str, np.ndarray], dims: dict[str, tuple[str, ...]],
                 coords: dict[str, np.ndarray], attrs: dict):
    """One netCDF-4 group: coordinate variables as dimension scales, data variables attached to them."""
    grp = h5.create_group(name, track_order=True)
    for dim, values in coords.items():
        ds = grp.create_dataset(dim, data=np.asarray(values))
        ds.make_scale(dim)
    for var, data in variables.items():
        ds = grp.create_dataset(var, data=np.asarray(data))
        for axis, dim in enumerate(dims[var]):
            ds.dims[axis].attach_scale(grp[dim])
    for k, v in attrs.items():
        grp.attrs[k] = v
    return grp


def save_posterior(path, result: PosteriorResult, *, attrs: dict | None = None) -> Path:
    """Write ``result`` to ``path`` (.h5 or .nc) in the ArviZ InferenceData netCDF-4 layout, with h5py only.

    Groups ``posterior`` (one (chain, draw) dataset per physical quantity, units of
    ``to_physical``), ``unconstrained_posterior`` (internal free parameters) and
    ``sample_stats`` (``lp`` (chain, draw); ``acceptance_rate`` (chain,)), each with
    ``chain`` and ``draw`` dimension scales so xarray / ArviZ ``from_netcdf`` read it.
    Root attributes: ``created_by="tactile_jax"``, ``tau``, ``ess``, ``warnings``
    (JSON strings), run settings and the user's ``attrs`` (non-scalars as JSON).
    Atomic: a temporary file in the same folder is renamed over ``path``.
    """
    import h5py

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    n_walkers, n_draws = result.log_prob.shape
    coords = {"chain": np.arange(n_walkers, dtype=np.int64), "draw": np.arange(n_draws, dtype=np.int64)}
    cd = ("chain", "draw")
    root_attrs = {**_run_attrs(result), **{k: _user_attr(v) for k, v in (attrs or {}).items()}}
    group_attrs = {k: root_attrs[k] for k in ("created_at", "created_by", "inference_library",
                                              "inference_library_version")}
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        with h5py.File(tmp, "w", track_order=True) as h5:
            samples = {k: np.asarray(v, float) for k, v in result.samples.items()}
            _write_group(h5, "posterior", samples, dict.fromkeys(samples, cd), coords, group_attrs)
            theta = {k: result.theta[..., i] for i, k in enumerate(result.free_names)}
            _write_group(h5, "unconstrained_posterior", theta, dict.fromkeys(theta, cd), coords, group_attrs)
            stats = {"lp": np.asarray(result.log_prob, float),
                     "acceptance_rate": np.asarray(result.walker_acceptance, float)}
            _write_group(h5, "sample_stats", stats, {"lp": cd, "acceptance_rate": ("chain",)},
                         coords, group_attrs)
            for k, v in root_attrs.items():
                h5.attrs[k] = v
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def load_posterior(path) -> dict[str, dict[str, np.ndarray]]:
    """Read a ``save_posterior`` file: group -> variable -> array (dimension scales ``chain``/``draw`` left out)."""
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
    """Root attributes of a ``save_posterior`` file, JSON strings (``tau``, ``ess``, ``warnings``, ...) decoded."""
    import h5py

    out: dict[str, Any] = {}
    with h5py.File(path, "r") as h5:
        for k, v in h5.attrs.items():
            v = v.decode() if isinstance(v, bytes) else v
            if isinstance(v, str):
                try:
                    v = json.loads(v)
                except ValueError:
                    pass
            elif isinstance(v, np.generic):
                v = v.item()
            out[k] = v
    return out
