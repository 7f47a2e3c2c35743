"""Figures (matplotlib, Agg backend): the edge of the package, imported only by the CLI and examples.

matplotlib is the ``plot`` extra: it is imported by the functions that draw, which raise
``MissingExtra`` naming ``pip install "tactile_jax[plot]"`` without it.
"""

from __future__ import annotations

import platform
from pathlib import Path

import numpy as np

from .._optional import need

__all__ = ["plot_ratio_figure", "provenance", "pyplot", "save_figure"]


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend; ``MissingExtra`` naming the ``plot`` extra without matplotlib."""
    matplotlib = need("matplotlib", "plot", "plotting")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def provenance() -> str:
    """One line naming the machine and package versions, for figure footers."""
    import jax

    from .. import __version__

    return (f"tactile_jax {__version__}, jax {jax.__version__}, numpy {np.__version__}; "
            f"{platform.machine()} {platform.system()}, {platform.python_implementation()} {platform.python_version()}")


def save_figure(fig, path, *, dpi: int = 120) -> Path:
    """Stamp ``provenance()`` in the footer, write ``fig`` to ``path`` (folders made) and close it."""
    fig.text(0.01, 0.005, provenance(), fontsize=6, color="0.4")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    pyplot().close(fig)
    return path


def plot_ratio_figure(path, *, freq, psd_shallow, psd_deep, omega, log_ratio, log_ratio_err, band,
                      line=None, line_label="fitted line (Eq. 6)", curves=None, title=""):
    """Fig. 5-style figure: (a) the two probes' amplitude spectra, (b) log|P2/P1| against omega.

    freq (Hz), psd_* (units^2/Hz, shown as amplitude sqrt(psd)), omega (rad/s),
    log_ratio and its one-sigma error, band (bool: bins used), ``line`` =
    (intercept, slope in s) of a fitted straight line, ``curves`` = {"om":
    omega grid, label: log R on that grid, ...} of model curves.
    """
    plt = pyplot()
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    ax1.semilogy(freq[1:], np.sqrt(psd_shallow[1:]), lw=1, label="shallow $P_{x1}$")
    ax1.semilogy(freq[1:], np.sqrt(psd_deep[1:]), lw=1, label="deep $P_{x2}$")
    ax1.set_xlabel("frequency (Hz)")
    ax1.set_ylabel("amplitude spectrum (units/$\\sqrt{Hz}$)")
    ax1.set_title("(a) probe spectra")
    sel = np.asarray(band, bool)
    hi = omega[sel].max() * 1.1 if sel.any() else omega.max()
    ax1.set_xlim(0, min(freq[-1], 4 * hi / (2 * np.pi)))
    ax1.legend()
    shown = omega <= hi
    ax2.plot(omega[~sel & shown], log_ratio[~sel & shown], ".", color="0.75", ms=3, label="bins not used")
    ax2.errorbar(omega[sel], log_ratio[sel], yerr=log_ratio_err[sel], fmt=".", ms=3, lw=0.6,
                 label="$\\log|P_{x2}/P_{x1}|$ (band used)")
    om = np.linspace(0, hi, 200)
    if line is not None:
        ax2.plot(om, line[0] + line[1] * om, "r-", lw=1.2, label=line_label)
    curves = dict(curves or {})
    grid = curves.pop("om", om)
    for (label, values), style in zip(curves.items(), ["g-", "k--", "m:", "c-."]):
        ax2.plot(grid, values, style, lw=1.3, label=label)
    lo = np.nanmin(log_ratio[sel]) if sel.any() else -10
    ax2.set_ylim(lo - 1.0, 1.0)
    ax2.set_xlim(0, hi)
    ax2.set_xlabel("$\\omega$ (rad/s)")
    ax2.set_ylabel("$\\log|P_{x2}/P_{x1}|$")
    ax2.set_title("(b) amplitude ratio")
    ax2.legend(fontsize=8)
    fig.suptitle(title)
    fig.text(0.01, 0.01, provenance(), fontsize=6, color="0.4")
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


__all__ += ["plot_fit", "plot_posterior_corner"]

_PAIR_LABELS = (("x", "$\\log|P_{x2}/P_{x1}|$"), ("y", "$\\log|P_{y2}/P_{y1}|$"))


def _result_stem(result) -> str:
    """``<file stem>_<index>`` naming a result's figures (``result`` when it has no file)."""
    import re

    stem = Path(str(result.file)).stem if getattr(result, "file", None) else "result"
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", stem) or "result"
    return f"{stem}_{int(getattr(result, 'index', 0) or 0)}"


def _fit_title(result) -> str:
    def part(name, value, err, scale, unit):
        if value is None or not np.isfinite(value):
            return f"{name} n/d"
        if err is None or not np.isfinite(err):
            return f"{name} = {scale * value:.4g} {unit}"
        from .report import value_and_error_text

        v_txt, e_txt = value_and_error_text(scale * value, scale * err)
        return f"{name} = {v_txt} $\\pm$ {e_txt} {unit}"

    bits = [part("$|v_x|$", result.vx, result.vx_err, 100, "cm/s"), part("$|v_y|$", result.vy, result.vy_err, 100, "cm/s")]
    if result.a is not None:
        bits.append(part("$a$", result.a, result.a_err, 1e3, "mm"))
    elif getattr(result, "a_lower", None):
        bits.append(f"$a$ > {1e3 * result.a_lower:.3g} mm (95 %)")
    if result.redchi is not None:
        bits.append(f"$\\chi^2_\\nu$ = {result.redchi:.3g}")
    src = Path(str(result.file)).name if result.file else "fit"
    return f"{src} [{result.index}]: " + ", ".join(bits)


def _ratio_limits(lr, err, measured, model, shown):
    """y-limits of a log-ratio panel: the measurements with their errors, else the model (clipped)."""
    if measured.any():
        lo = float(np.nanmin((lr - err)[measured]))
        top = float(np.nanmax((lr + err)[measured]))
        near = shown & np.isfinite(model) & (model > lo - 3.0)      # the model near the data, not its far tail
        if near.any():
            lo, top = min(lo, float(model[near].min())), max(top, float(model[near].max()))
    else:
        vals = model[shown & np.isfinite(model)]
        vals = np.clip(vals, -30.0, 5.0)
        lo, top = (float(vals.min()), float(vals.max())) if vals.size else (-5.0, 0.5)
    if top - lo < 1.0:                                               # at least one e-fold of context
        mid = 0.5 * (top + lo)
        lo, top = mid - 0.5, mid + 0.5
    pad = 0.1 * (top - lo)
    return lo - pad, top + pad


def plot_fit(result, out_dir) -> list[Path]:
    """Fig. 7-style figure of a joint fit: measured and fitted log|P2/P1| of the x and y pairs.

    result: a ``inference.result.FitResult``. out_dir: folder for ``fit_<file stem>_<index>.png``.
    Each panel: the measured log amplitude ratio against omega (rad/s) with its
    one-sigma error bars in the bins the fit used; other bins carrying a measured
    value in grey; the fitted model curve with its +/- 1 sigma band (Laplace
    covariance, ``fit.model_curves``). Returns the written paths: [] when the fit has
    no joint-model curves (ratio-only input, or a fit that did not run).
    """
    from ..inference.result import model_curves

    curves = model_curves(result)
    if curves is None:
        return []
    omega = np.asarray(curves["omega"], float)
    used = np.asarray(curves["mask"], bool).any(axis=0)
    # the model is an extrapolation beyond the bins used: show up to 1.5 times the highest one
    hi = 1.5 * omega[used].max() if used.any() else (omega.max() if omega.size else 1.0)
    hi = float(min(hi, omega.max() * 1.02)) if omega.size else 1.0
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.4))
    for p, (ax, (axis, ylabel)) in enumerate(zip(axes, _PAIR_LABELS)):
        lr = np.asarray(curves["log_ratio"][p], float)
        err = np.asarray(curves["log_ratio_err"][p], float)
        mask = np.asarray(curves["mask"][p], bool)
        model = np.asarray(curves["model"][p], float)
        sd = np.asarray(curves["model_sd"][p], float)
        filler = (lr == 0.0) & (err == 1.0)                  # bins the fit filled in, not measurements
        other = ~mask & ~filler & np.isfinite(lr)
        if other.any():
            ax.plot(omega[other], lr[other], ".", color="0.7", ms=4, label="bins not used")
        if mask.any():
            ax.errorbar(omega[mask], lr[mask], yerr=err[mask], fmt="o", ms=3, lw=0.8, color="C0",
                        label="measured (bins used)")
        ok = np.isfinite(model)
        ax.plot(omega[ok], model[ok], "-", color="C3", lw=1.4, label="joint model fit")
        band = ok & np.isfinite(sd)
        ax.fill_between(omega[band], (model - sd)[band], (model + sd)[band], color="C3", alpha=0.25, lw=0,
                        label="model $\\pm 1\\sigma$")
        ax.set_xlabel("$\\omega$ (rad/s)")
        ax.set_ylabel(ylabel)
        n = int(mask.sum())
        ax.set_title(f"({'ab'[p]}) {axis} pair: {n} ratio bin{'s' if n != 1 else ''} fitted", fontsize=10)
        ax.set_xlim(0, hi)
        ax.set_ylim(*_ratio_limits(lr, err, mask | other, model, omega <= hi))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(_fit_title(result), fontsize=10)
    # every speed comes from all four probes' spectra at once, not from one pair's ratio
    fig.text(0.99, 0.01, f"vx, vy and a are fitted to {int(result.n_residuals or 0)} residuals of all four probes' "
             f"spectra ({int(result.n_bins)} bins); each panel shows one pair's log ratio",
             fontsize=7, color="0.3", ha="right")
    fig.text(0.01, 0.01, provenance(), fontsize=6, color="0.4")
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"fit_{_result_stem(result)}.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return [path]


def plot_posterior_corner(result, out_dir, *, truth: dict | None = None) -> list[Path]:
    """Corner plot (ArviZ ``plot_pair``) of the posterior of |vx|, |vy| (cm/s) and a (mm): ``corner_<file stem>_<index>.png``.

    result: a ``inference.result.FitResult`` with ``posterior`` set (``posterior.run_emcee``); the sampled
    ones of vx, vy and a are drawn (fixed ones are not sampled). Panels: 2-D KDE contours of
    each pair below the diagonal, 1-D KDE marginals on it. truth: a simulator's truth dict
    (``vx``, ``vy``, ``a`` in SI units), drawn as reference points (and lines on the
    marginals). Needs the ``plot`` and ``mcmc`` extras. Returns the written paths ([] when
    the result has no posterior or fewer than two of the quantities were sampled).
    """
    post = getattr(result, "posterior", None)
    if post is None:
        return []
    scales = {"vx": (100.0, "$|v_x|$ (cm/s)"), "vy": (100.0, "$|v_y|$ (cm/s)"), "a": (1e3, "$a$ (mm)")}
    names = [n for n in scales if n in post.samples]
    if len(names) < 2:
        return []
    pyplot()                                              # the Agg backend before ArviZ draws
    az = need("arviz", "mcmc", "the corner plot")
    samples = {n: scales[n][0] * np.asarray(post.samples[n], float) for n in names}
    truths = {}
    for n in names:
        v = (truth or {}).get(n)
        if v is not None and np.isfinite(v):
            truths[n] = scales[n][0] * (abs(float(v)) if n in ("vx", "vy") else float(v))
    axes = az.plot_pair(samples, kind="kde", marginals=True, figsize=(3 * len(names), 3 * len(names)), textsize=10,
                        labeller=az.labels.MapLabeller(var_name_map={n: scales[n][1] for n in names}),
                        reference_values=truths if len(truths) == len(names) else None,
                        backend="matplotlib", show=False)
    axes = np.atleast_2d(axes)
    for i, n in enumerate(names):
        if n in truths:
            axes[i, i].axvline(truths[n], color="C2", lw=1)
    fig = axes[0, 0].figure
    src = Path(str(result.file)).name if result.file else "fit"
    fig.suptitle(f"{src} [{result.index}]: emcee posterior ({post.n_steps} steps, burn-in {post.n_burn})",
                 fontsize=10)
    fig.subplots_adjust(left=0.11, right=0.97, bottom=0.09, top=0.93, wspace=0.25, hspace=0.25)
    path = Path(out_dir) / f"corner_{_result_stem(result)}.png"
    save_figure(fig, path)
    return [path]
