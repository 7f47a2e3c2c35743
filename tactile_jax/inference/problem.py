"""A least-squares problem in the form that solvers and samplers share."""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import numpy as np

__all__ = ["FitProblem"]


class FitProblem(NamedTuple):
    """A fitted least-squares problem: what a sampler needs to explore around the fit.

    residuals: module-level function ``residuals(theta, args) -> (n,)`` of
        weighted residuals (zero where masked); the negative log-likelihood is
        ``0.5 * sum(r**2) / scale``.
    args: the data pytree passed to ``residuals``.
    theta: (P,) best-fit parameter vector in the internal (fitting)
        parametrisation, e.g. log speeds; fixed entries hold their values.
    free: (P,) which entries are fitted (a sampler explores only these).
    names: (P,) internal parameter names, e.g. ``"log_vx"``.
    lower, upper: (P,) bounds of the internal parameters (a flat prior on
        the free ones inside them).
    cov: (P, P) Laplace (Gauss-Newton) covariance of ``theta``.
    scale: likelihood temperature (the variance scale of the covariance,
        ``FitResult.error_scale``: jackknife or reduced chi-square x bin
        factor), so that sampler and Laplace widths agree.
    to_physical: function ``(theta (..., P)) -> dict[name, array (...)]`` of
        the reported physical quantities (m/s, m, ...); vectorised over
        leading axes with numpy.
    stretch: (P,) width factors about ``theta``, or None (all ones). The
        sampled density at ``t`` is ``exp(-0.5 * sum(r(theta + (t - theta) / stretch)**2) / scale)``:
        the tempered posterior mapped by ``t = theta + stretch * (u - theta)``,
        so its widths are ``stretch`` times the tempered ones and its
        correlations and shape are kept. ``fit`` sets ``sqrt(s_i / scale)``
        for vx, vy and a, which have their own jackknife scales ``s_i``
        (``FitResult.error_scales``), so that sampler and Laplace widths agree
        for them too.
    sampling_args: a function of no arguments giving what a sampler passes to ``residuals`` in place of
        ``args``, or None (``args``): the same residuals wherever the sampler's walkers go, and none (NaN) far
        beyond them, at a fraction of the cost (``fit`` cuts the Hertz table to the corner its walkers read,
        ``model.hertz.corner``; computed when a sampler asks, not at every fit).
    precision: the lowest precision a sampler may evaluate ``residuals`` in ("float32" or "float64"):
        "float64" where float32 is known not to carry the model, so that no float32 run is tried and thrown
        away (``posterior.run_emcee``).
    """

    residuals: Callable
    args: Any
    theta: np.ndarray
    free: tuple
    names: tuple
    lower: np.ndarray
    upper: np.ndarray
    cov: np.ndarray
    scale: float
    to_physical: Callable
    stretch: np.ndarray | None = None
    precision: str = "float32"
    sampling_args: Callable[[], Any] | None = None
