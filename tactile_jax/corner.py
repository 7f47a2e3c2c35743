"""A small, self-contained corner plot of posterior draws (matplotlib Agg; no ``corner`` package)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from .plotting import provenance  # also selects the Agg backend

__all__ = ["corner_plot"]

_MAX_SCATTER = 4000                     # points drawn per 2-D panel (an even subsample of the draws)
_LEVELS = (0.3935, 0.8647)              # mass inside the 1- and 2-sigma contours of a 2-D Gaussian


def _range(x):
    lo, hi = np.percentile(x, [0.5, 99.5])
    if not hi > lo:                      # a constant quantity: give it a visible width
        pad = 1e-6 * abs(lo) + 1e-12
        return lo - pad, hi + pad
    pad = 0.05 * (hi - lo)
    return lo - pad, hi + pad


def _contour_levels(h):
    """Density thresholds enclosing the ``_LEVELS`` fractions of a 2-D histogram's mass."""
    flat = np.sort(h.ravel())[::-1]
    cum = np.cumsum(flat)
    if cum[-1] <= 0:
        return []
    cum /= cum[-1]
    levels = [flat[min(np.searchsorted(cum, q), flat.size - 1)] for q in _LEVELS]
    levels = sorted(set(float(v) for v in levels if v > 0))
    return levels


def corner_plot(samples: dict[str, np.ndarray], path, *, names=None, truths: dict | None = None,
                labels: dict | None = None, title: str = "") -> Path:
    """Corner plot of posterior draws, written to ``path`` (format from the suffix, e.g. PNG).

    samples: name -> draws of any shape (flattened; e.g. (n_walkers, n_draws)), in the
        quantity's own units (m/s, m, ...). names: which quantities and their order
        (default: all). truths: name -> true value, drawn as lines. labels: name -> axis
        label (default: the name). title: figure title. Diagonal: 1-D histograms with the
        16/50/84 % quantiles dashed; below it: draws scattered with the 39 % / 86 % (1 and
        2 sigma in 2-D) contours of their 2-D histogram. A footer names the package versions.
    """
    names = list(samples) if names is None else list(names)
    if not names:
        raise ValueError("corner_plot needs at least one quantity")
    truths = truths or {}
    labels = labels or {}
    data = {n: np.asarray(samples[n], float).ravel() for n in names}
    data = {n: x[np.isfinite(x)] for n, x in data.items()}
    ranges = {n: _range(x) if x.size else (0.0, 1.0) for n, x in data.items()}
    fixed = {n: x.size > 0 and np.ptp(x) == 0 for n, x in data.items()}    # e.g. a parameter held fixed
    k = len(names)
    size = 2.2 * k + 0.8
    fig = Figure(figsize=(size, size + 0.3))
    axes = fig.subplots(k, k, squeeze=False)
    n_draws = min(x.size for x in data.values())
    step = max(1, n_draws // _MAX_SCATTER)
    for i, yi in enumerate(names):
        for j, xj in enumerate(names):
            ax = axes[i, j]
            if j > i:
                ax.set_visible(False)
                continue
            x = data[xj]
            if i == j and fixed[xj]:
                ax.axvline(x[0], color="k", lw=1.5)
                ax.set_title(f"{labels.get(xj, xj)} = {x[0]:.4g} (fixed)", fontsize=8)
                ax.set_yticks([])
            elif i == j:
                ax.hist(x, bins=40, range=ranges[xj], histtype="step", color="k", density=True)
                if x.size:
                    q16, q50, q84 = np.percentile(x, [16, 50, 84])
                    for q in (q16, q50, q84):
                        ax.axvline(q, color="C0", ls="--" if q != q50 else "-", lw=1)
                    ax.set_title(f"{labels.get(xj, xj)} = {q50:.4g}$^{{+{q84 - q50:.2g}}}_{{-{q50 - q16:.2g}}}$",
                                 fontsize=8)
                ax.set_yticks([])
            else:
                y = data[yi]
                m = min(x.size, y.size)
                ax.plot(x[:m:step], y[:m:step], ".", ms=1.5, color="0.5", alpha=0.3, rasterized=True)
                if m > 50 and not (fixed[xj] or fixed[yi]):
                    h, ex, ey = np.histogram2d(x[:m], y[:m], bins=30, range=[ranges[xj], ranges[yi]])
                    levels = _contour_levels(h)
                    if levels:
                        cx, cy = 0.5 * (ex[1:] + ex[:-1]), 0.5 * (ey[1:] + ey[:-1])
                        ax.contour(cx, cy, h.T, levels=levels, colors="k", linewidths=0.8)
                ax.set_ylim(ranges[yi])
                if yi in truths:
                    ax.axhline(truths[yi], color="C3", lw=1)
                    ax.plot([truths.get(xj, np.nan)], [truths[yi]], "s", color="C3", ms=3)
            if xj in truths:
                ax.axvline(truths[xj], color="C3", lw=1)
            ax.set_xlim(ranges[xj])
            if fixed[xj]:
                ax.set_xticks([data[xj][0]])
            if fixed[yi] and i != j:
                ax.set_yticks([data[yi][0]])
            ax.tick_params(labelsize=7)
            ax.ticklabel_format(useOffset=False)
            if i == k - 1:
                ax.set_xlabel(labels.get(xj, xj), fontsize=9)
            else:
                ax.set_xticklabels([])
            if j == 0 and i > 0:
                ax.set_ylabel(labels.get(yi, yi), fontsize=9)
            elif j > 0 and i != j:
                ax.set_yticklabels([])
    if title:
        fig.suptitle(title, fontsize=10)
    fig.text(0.01, 0.005, provenance(), fontsize=5, color="0.4", ha="left", va="bottom")
    fig.subplots_adjust(left=0.12, right=0.97, bottom=0.1, top=0.93 if title else 0.95, wspace=0.08, hspace=0.08)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path
