"""The figure of a tracked slip: vx, vy and a against time, with error bands and each update's status."""

from __future__ import annotations

import numpy as np

from .figures import pyplot, save_figure

__all__ = ["track_figure"]

_COLOURS = {"ok": "tab:green", "no_slip": "0.6", "slip_start": "tab:blue", "slip_stop": "tab:purple",
            "slip_change": "tab:cyan", "no_band": "0.3",
            "not_converged": "tab:orange", "poor_fit": "tab:red", "undetermined": "tab:olive"}


def _column(rows, name, scale):
    return np.array([np.nan if r.get(name) is None else scale * float(r[name]) for r in rows])


def track_figure(rows: list[dict], *, path=None, title: str = "", truth: list[dict] | None = None):
    """vx, vy (cm/s) and a (mm) of ``rows`` (``Tracker`` rows) against ``t``: the value with its one-sigma band,
    markers coloured by status, and a strip of the statuses. truth: pieces (dicts with start, end, vx, vy, a)
    drawn as steps. Writes ``path`` where given; returns the figure."""
    plt = pyplot()
    t = np.array([float(r["t"]) for r in rows])
    status = [r["status"] for r in rows]
    fig, axes = plt.subplots(4, 1, figsize=(8, 7.5), sharex=True, gridspec_kw={"height_ratios": [3, 3, 3, 0.6]})
    for ax, (name, scale, label) in zip(axes, (("vx", 100.0, "vx (cm/s)"), ("vy", 100.0, "vy (cm/s)"),
                                               ("a", 1e3, "a (mm)"))):
        v, e = _column(rows, name, scale), _column(rows, name + "_err", scale)
        band = np.where(np.isfinite(e), e, 0.0)
        ax.fill_between(t, v - band, v + band, color="tab:green", alpha=0.25, lw=0, label="one sigma")
        ax.plot(t, v, color="0.3", lw=0.8)
        for s in sorted(set(status)):
            pick = np.array([x == s for x in status])
            ax.scatter(t[pick], v[pick], s=8, color=_COLOURS.get(s, "k"), label=s, zorder=3)
        if truth:
            for piece in truth:
                value = piece.get(name)
                if value is not None:
                    ax.plot([piece["start"], piece["end"]], [scale * value] * 2, color="k", lw=1.2, ls="--")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    axes[0].legend(handles, labels, fontsize=7, ncol=4, loc="upper left")
    strip = axes[3]
    for s in sorted(set(status)):
        pick = np.array([x == s for x in status])
        strip.scatter(t[pick], np.zeros(pick.sum()), marker="|", s=200, color=_COLOURS.get(s, "k"))
    strip.set_yticks([])
    strip.set_ylabel("status", rotation=0, ha="right", va="center")
    strip.set_xlabel("time (s): the window's centre")
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path)
    return fig
