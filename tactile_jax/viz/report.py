"""A human-readable fit report in the style of lmfit's ``fit_report``, with units and reasons.

Values are printed for people: speeds in cm/s, lengths in mm, wavenumbers in rad/m,
each label naming its unit. A quantity without an error bar says why: held fixed,
bounded only (``a_lower``, ``vx_upper``/``vy_upper``), or not determined.
"""

from __future__ import annotations

import math
import numpy as np

__all__ = ["fit_report", "split_message"]

_MIN_CORREL = 0.3
_TEXTURE_PREFIX = "log_phi"               # internal names of the texture-spectrum knots

# (attribute, label, unit, scale from SI, error attribute, truth keys, internal name of the fitted parameter)
_QUANTITIES = (
    ("vx", "vx", "cm/s", 100.0, "vx_err", ("vx",), "log_vx"),
    ("vy", "vy", "cm/s", 100.0, "vy_err", ("vy",), "log_vy"),
    ("a", "a", "mm", 1e3, "a_err", ("a", "contact_radius"), "log_a"),
    ("contact_depth", "contact depth", "mm", 1e3, "contact_depth_err", ("contact_depth",), None),
    ("gain_ratio", "gain ratio x", "", 1.0, "gain_ratio_err", ("gain_ratio_x", "gain_ratio"), "log_gx"),
    ("gain_ratio_y", "gain ratio y", "", 1.0, "gain_ratio_y_err", ("gain_ratio_y", "gain_ratio"), "log_gy"),
)


def split_message(message: str | None) -> list[str]:
    """Split a result message on ``"; "`` outside parentheses (a note may hold ``;`` in brackets)."""
    if not message:
        return []
    parts, depth, start = [], 0, 0
    for i, ch in enumerate(message):
        if ch in "([":
            depth += 1
        elif ch in ")]":
            depth = max(depth - 1, 0)
        elif ch == ";" and depth == 0 and message[i + 1:i + 2] == " ":
            parts.append(message[start:i])
            start = i + 2
    parts.append(message[start:])
    return [p.strip() for p in parts if p.strip()]


def _finite(x) -> bool:
    try:
        return x is not None and math.isfinite(float(x))
    except (TypeError, ValueError):
        return False


def _num(x, digits: int = 5) -> str:
    return f"{float(x):.{digits}g}" if _finite(x) else "n/a"


def value_and_error_text(value: float, err: float) -> tuple[str, str]:
    """Value and error with the value rounded to the error's second significant digit."""
    if not (_finite(err) and err > 0):
        return _num(value, 6), _num(err, 2)
    decimals = 1 - int(math.floor(math.log10(err)))
    if -1 <= decimals <= 8 and abs(value) < 1e7:
        d = max(decimals, 0)
        return f"{value:.{d}f}", f"{err:.{d}f}"
    return f"{value:.6g}", f"{err:.2g}"


def _truth_value(truth: dict | None, keys) -> float | None:
    if not truth:
        return None
    for key in keys:
        v = truth.get(key)
        if _finite(v):
            return float(v)
    return None


def _free_mask(result) -> dict[str, bool]:
    """Internal parameter name -> fitted (True) or held fixed (False); empty when unknown."""
    problem = getattr(result, "problem", None)
    if problem is None:
        return {}
    names = tuple(problem.names) if problem.names else tuple(result.names)
    return {str(n): bool(f) for n, f in zip(names, problem.free)}


def _variable_line(result, spec, truth, free) -> str:
    attr, label, unit, scale, err_attr, truth_keys, internal = spec
    value, err = getattr(result, attr, None), getattr(result, err_attr, None)
    head = f"{label} ({unit})" if unit else label
    head = f"    {head + ':':<22}"
    t = _truth_value(truth, truth_keys)
    if t is not None and attr in ("vx", "vy"):
        t = abs(t)                                           # speeds are reported as |v|
    truth_txt = "" if t is None else f"truth {_num(t * scale)}"
    fixed = (internal is not None and free.get(internal) is False) or (
        not free and _finite(value) and err is None and attr in ("vx", "vy", "gain_ratio", "gain_ratio_y"))

    if not _finite(value):
        return head + _undetermined(result, attr, scale, unit, t)
    upper = getattr(result, f"{attr}_upper", None) if attr in ("vx", "vy") else None
    # against a speed's 95 % bound, the truth is placed inside or above it (never a deviation in sigma)
    bound_txt = (f"    {truth_txt}, {'inside' if t <= upper else 'above'} the bound"
                 if truth_txt and _finite(upper) else "")
    if fixed:
        if _finite(upper):      # a minor speed held at 0 (slip along an axis)
            return head + (f"{_num(value * scale, 6)} (held: slip {result.direction}; 95 % upper bound "
                           f"{_num(upper * scale, 3)} {unit})") + bound_txt
        return head + f"{_num(value * scale, 6)} (fixed)" + (f"    {truth_txt}" if truth_txt else "")
    if not _finite(err):
        line = f"{_num(value * scale, 6)} +/- n/a (no error bar: {_no_error_reason(result)})"
        return head + line + (f"    {truth_txt}" if truth_txt else "")
    v_txt, e_txt = value_and_error_text(value * scale, err * scale)
    rel = 100 * err / abs(value) if value != 0 else math.inf
    rel = f"({rel:.2f} %)" if rel < 1000 else (f"({rel:.3g} %)" if math.isfinite(rel) else "(n/a %)")
    line = f"{v_txt} +/- {e_txt} {rel}"
    if _finite(upper):
        # the profile bound, not the Laplace sigma, is what this component's error means: the truth is
        # placed against the bound, so that a deviation in sigma never sits beside "consistent with 0"
        line += f"  (consistent with 0, 95 % upper bound {_num(upper * scale, 3)} {unit})" + bound_txt
    elif truth_txt:
        dev = (value - t) / err if err > 0 else math.nan
        line += f"    {truth_txt}, {dev:+.2f} sigma" if math.isfinite(dev) else f"    {truth_txt}"
    return head + line


def _no_error_reason(result) -> str:
    if not result.converged:
        return "the fit did not converge"
    if _finite(result.cond) and result.cond > 1e10:
        return "singular curvature matrix"
    return "not estimated"


def _undetermined(result, attr, scale, unit, truth) -> str:
    why = ""
    if attr == "a" and _finite(result.a_lower):
        bound = result.a_lower * scale
        why = f"not determined, > {_num(bound, 3)} {unit} (95 % lower bound; the contact window is too weak)"
        if truth is not None:
            why += f"    truth {_num(truth * scale)} ({'inside' if truth >= result.a_lower else 'outside'} the bound)"
        return why
    if attr == "contact_depth" and _finite(result.a_lower):
        depth = _depth_bound(result)
        if depth is not None:
            return f"not determined, > {_num(depth * scale, 3)} {unit} (from the bound on a)"
        return "not determined (a is not determined)"
    if attr in ("vx", "vy") and _finite(getattr(result, f"{attr}_upper", None)):
        return (f"not determined (consistent with 0, 95 % upper bound "
                f"{_num(getattr(result, f'{attr}_upper') * scale, 3)} {unit})")
    if result.status != "ok":
        return f"not determined (fit status {result.status})"
    if attr == "contact_depth":
        return "not determined (a is not determined)"
    return "not determined (see warnings)"


def _depth_bound(result) -> float | None:
    """Contact depth at the lower bound of a, through the problem's own curvature radius."""
    problem = getattr(result, "problem", None)
    if problem is None or "log_a" not in tuple(problem.names):
        return None
    theta = np.array(problem.theta, float)
    theta[list(problem.names).index("log_a")] = math.log(result.a_lower)
    try:
        return float(problem.to_physical(theta)["contact_depth"])
    except Exception:  # noqa: BLE001 - a report never fails on an extra
        return None


def _k0_line(result, attr) -> str:
    value = getattr(result, attr, None)
    head = f"    {attr + ' (rad/m):':<22}"
    if not _finite(value):
        return head + "none (no single dominant spectral line in the band)"
    return head + f"{_num(value, 5)}  (wavelength {_num(2 * math.pi / value * 1e3, 4)} mm, Eq. 4 / 17)"


def _correlations(result) -> list[str]:
    corr = getattr(result, "correlations", None)
    if corr is None:
        return ["    (not available for this fit)"]
    corr = np.asarray(corr, float)
    names = [str(n) for n in result.names]
    free = _free_mask(result)
    if free and corr.shape[0] == len(names) and corr.shape[0] != sum(free.values()):
        idx = [i for i, n in enumerate(names) if free.get(n, True)]          # full matrix: keep the free ones
        corr = corr[np.ix_(idx, idx)]
        names = [names[i] for i in idx]
    elif free and corr.shape[0] == sum(free.values()):
        names = [n for n in names if free.get(n, True)]
    if corr.ndim != 2 or corr.shape[0] != len(names):
        return ["    (not available: correlation matrix and parameter names disagree)"]
    pairs, texture_pairs = [], []
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            c = corr[i, j]
            if not (math.isfinite(c) and abs(c) > _MIN_CORREL):
                continue
            both_texture = names[i].startswith(_TEXTURE_PREFIX) and names[j].startswith(_TEXTURE_PREFIX)
            (texture_pairs if both_texture else pairs).append((abs(c), c, names[i], names[j]))
    pairs.sort(key=lambda p: -p[0])
    lines = [f"    C({a}, {b}) = {c:+.4f}" for _, c, a, b in pairs]
    if texture_pairs:
        top = max(p[0] for p in texture_pairs)
        lines.append(f"    (+ {len(texture_pairs)} among the texture-spectrum knots {_TEXTURE_PREFIX}_*, "
                     f"max |C| = {top:.3f})")
    if not lines:
        lines = [f"    (none with |C| > {_MIN_CORREL})"]
    else:
        lines.insert(0, f"    (internal log parameters; |C| > {_MIN_CORREL}, largest first)")
    return lines


def _mcmc(result) -> list[str]:
    post = result.posterior
    lines = []
    n_walkers = np.shape(getattr(post, "log_prob", np.zeros((0, 0))))[0]
    lines.append(f"    walkers x steps     = {n_walkers} x {getattr(post, 'n_steps', '?')} "
                 f"(burn-in {getattr(post, 'n_burn', '?')}, thin {getattr(post, 'thin', '?')})")
    lines.append(f"    acceptance fraction = {_num(post.acceptance_fraction, 3)}")
    tau = np.asarray(post.tau, float)
    max_tau = float(np.nanmax(tau)) if tau.size and np.isfinite(tau).any() else math.nan
    lines.append(f"    max autocorr. time  = {_num(max_tau, 3)} steps")
    lines.append(f"    effective samples   = {_num(post.ess, 4)}")
    summary = post.summary()
    for name, label, unit, scale in (("vx", "vx", "cm/s", 100.0), ("vy", "vy", "cm/s", 100.0),
                                     ("a", "a", "mm", 1e3)):
        if name not in summary:
            continue
        s = summary[name]
        m, sd = s["mean"] * scale, s["sd"] * scale
        mv, me = value_and_error_text(m, sd)
        extra = ""
        if _finite(s.get("q2.5")) and _finite(s.get("q97.5")):
            extra = f"  (95 % interval {_num(s['q2.5'] * scale, 4)} .. {_num(s['q97.5'] * scale, 4)})"
        lines.append(f"    {label + ' (' + unit + '):':<20}posterior mean {mv} sd {me}{extra}")
    for w in getattr(post, "warnings", ()):
        lines.append(f"    warning: {w}")
    return lines


def fit_report(result, *, truth: dict | None = None) -> str:
    """Multi-line report of a ``fit.FitResult`` (lmfit style) with units, for people.

    Sections: a header (file, record index, model, window, status, solver,
    precision); ``[[Fit Statistics]]``; ``[[Variables]]`` (vx, vy in cm/s; a and contact
    depth in mm; gain ratios; k0x, k0y in rad/m) with one-sigma errors, relative errors
    and, given ``truth`` (a simulator's dict: ``vx``, ``vy``, ``a``, ``contact_depth``,
    ``gain_ratio_x``, ``gain_ratio_y``, SI units), the truth and the deviation in sigma;
    ``[[Correlations]]`` of the free (internal, log) parameters with |C| > 0.3;
    ``[[Warnings]]``; ``[[MCMC]]`` when ``result.posterior`` is set.
    """
    free = _free_mask(result)
    lines = ["[[Fit]]"]
    where = result.file if result.file else "<no file>"
    lines.append(f"    file:      {where}  (record {result.index})")
    chain = getattr(result, "cross_pairs", 0)
    chain = f", y pair given x ({chain} block{'s' if chain > 1 else ''}, x-y cross-spectra)" if chain else ""
    lines.append(f"    model:     {result.model}, window {result.window}, texture "
                 f"{getattr(result, 'texture', 'isotropic')}, slip {getattr(result, 'direction', 'oblique')}{chain}")
    lines.append(f"    status:    {result.status}, converged {bool(result.converged)}")
    lines.append(f"    solver:    {result.solver}, precision {result.precision}")

    lines.append("[[Fit Statistics]]")
    n_res, n_par = int(getattr(result, "n_residuals", 0) or 0), int(result.n_params or 0)
    dof = str(n_res - n_par) if n_res and n_par else "n/a"
    if n_res and n_par and result.chi2 and result.redchi:
        effective = float(result.chi2) / float(result.redchi)     # less what a lumpy texture's random effects take
        if n_res - n_par - effective > 0.5:
            dof = f"{effective:.1f} (the texture's random effects take {n_res - n_par - effective:.1f})"
    stats = (("residuals", f"{n_res} (from {int(result.n_bins)} usable frequency bins)" if n_res
              else "n/a"),
             ("variables", str(n_par) if n_par else "n/a"),
             ("degrees of freedom", dof),
             ("chi-square", _num(result.chi2, 6)), ("reduced chi-square", _num(result.redchi, 5)),
             ("Akaike info crit", _num(result.aic, 6)), ("Bayesian info crit", _num(result.bic, 6)),
             ("condition number", _num(result.cond, 3)))
    if getattr(result, "error_method", ""):
        stats += (("error scale", f"{_num(result.error_scale, 3)}  ({result.error_method})"),)
        own = getattr(result, "error_scales", None) or {}
        if own and result.error_method.startswith("laplace x jackknife"):
            stats += (("  of vx, vy, a", ", ".join(f"{k} {_num(v, 3)}" for k, v in own.items())),)
    lines += [f"    {k:<19}= {v}" for k, v in stats]

    lines.append("[[Variables]]")
    for spec in _QUANTITIES:
        lines.append(_variable_line(result, spec, truth, free))
    lines.append(_k0_line(result, "k0x"))
    lines.append(_k0_line(result, "k0y"))

    lines.append("[[Correlations]]")
    lines += _correlations(result)

    notes = split_message(result.message) + [str(w) for w in (result.warnings or [])]
    if notes:
        lines.append("[[Warnings]]")
        lines += [f"    {n}" for n in notes]

    if getattr(result, "posterior", None) is not None:
        lines.append("[[MCMC]]")
        try:
            lines += _mcmc(result)
        except Exception as err:  # noqa: BLE001 - a report never fails on an extra
            lines.append(f"    (summary unavailable: {err})")
    return "\n".join(lines)
