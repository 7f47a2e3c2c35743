"""Figures (matplotlib, Agg backend): the edge of the package, imported only by the CLI and examples."""

from __future__ import annotations

import platform
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

__all__ = ["plot_ratio_figure", "provenance"]


def provenance() -> str:
    """One line naming the machine and package versions, for figure footers."""
    import jax

    from . import __version__

    return (f"tactile_jax {__version__}, jax {jax.__version__}, numpy {np.__version__}; "
            f"{platform.machine()} {platform.system()}, {platform.python_implementation()} {platform.python_version()}")


def plot_ratio_figure(path, *, freq, psd_shallow, psd_deep, omega, log_ratio, log_ratio_err, band,
                      line=None, line_label="fitted line (Eq. 6)", curves=None, title=""):
    """Fig. 5-style figure: (a) the two probes' amplitude spectra, (b) log|P2/P1| against omega.

    freq (Hz), psd_* (units^2/Hz, shown as amplitude sqrt(psd)), omega (rad/s),
    log_ratio and its one-sigma error, band (bool: bins used), ``line`` =
    (intercept, slope in s) of a fitted straight line, ``curves`` = {"om":
    omega grid, label: log R on that grid, ...} of model curves.
    """
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
