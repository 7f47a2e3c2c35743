"""How to fit a scene: ``FitOptions``, the compiled pipeline's ``Settings`` made from them, and ``FitOptions``
from a scene recipe's [fit] table (``recipe_options``; ``io.recipes`` reads the TOML)."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..errors import TactileInputError
from .analysis import DIRECTIONS
from .core import Settings
from .select import MODELS

__all__ = ["FitOptions", "WINDOWS", "settings_of", "analysis_settings", "choices_of", "options_from_file",
           "known_gains", "recipe_options"]


@dataclasses.dataclass(frozen=True)
class FitOptions:
    """How to fit a scene (SI units). Defaults suit the paper's sensor at 1 kHz.

    method, prewhiten, nperseg: spectral estimator (``spectral.segments.segments``): "welch"
        (Hann, half overlap; ``nperseg`` samples, at least ``spectral.segments.min_nperseg()`` = 14,
        checked with the recording's name where the segments are made; default the largest power
        of two <= N / 8, lengthened for slow slips) or "multitaper"; the order of the Burg AR prewhitening
        filter (0 or None: off).
    velocity: known (|vx|, |vy|) in m/s (the arm's command, paper section 4.3): held fixed.
    gain_ratio: known deep/shallow gain ratios (gx, gy) or one for both; None: the
        file's ``gain_ratio`` if any, else 1. ``fit_gain``: fit them instead.
    noise_floor: fit a white noise floor on the shallow probes.
    smoothness: the prior sd of the log texture spectrum's second differences between its knots.
    min_snr, max_err, fmin, fmax: usable-band selection (``spectral.band.select``; Hz).
    leakage_db: a bin whose shallow PSD lies this far below the highest within +/- 3 bins holds
        only spectral leakage (between the lines of a line texture) and is dropped.
    conditioned: fit each pair's conditioned deep PSD S22.1 = S22 - |S12|^2 / S11 too: the deep
        power the shallow probe does not explain, which 2-D slip through a small contact sets.
    cross_pairs: the y pair conditioned on the x pair (``model.cross_pair``): None (default) 2 where
        the data have the x-y cross-spectra (recordings, files from ``tactile-jax spectra``), else 0;
        0 off, 1 y1 given (x1, x2) in place of y1's PSD, 2 also y2 given (x1, x2, y1) in place of
        the y pair's ratio and S22.1.
    profile_minor: give a speed component below ``MINOR_PROFILE`` of the other a
        profile-likelihood interval (``FitResult.vx_lo`` ...).
    window: the contact window: None (default: the Hertz disk, a fingertip's contact, against the
        Gaussian of the paper's closed forms, chosen per record by chi-square and reported with its
        margin in ``FitResult.window``), "hertz" or "gaussian".
    texture: the texture model: None (default: isotropic, or directional where the isotropic fit
        does not describe the spectra and the directional one does, chosen per record and reported
        in ``FitResult.texture``), "isotropic" (Phi(|k|)) or "directional" (Phi(|k|) times a
        lobe whose log is a Fourier series in 2 theta to the fourth harmonic, ``model.lines``).
    direction: the slip direction: None (default: both speeds fitted, or a minor speed within 1.4
        sigma of 0 held at 0, chosen per record and reported in ``FitResult.direction``),
        "oblique" (both fitted), "along x" (vy held at 0) or "along y" (vx held at 0).
    model: the scene model (``select.MODELS``): None (default: slip and contact window,
        plus gains / noise floor as ``fit_gain`` / ``noise_floor`` say; a window the data do
        not need is reported as a lower bound on a), "slip" (window negligible), "window",
        "window+gain", "window+noise", "window+gain+noise" (these set the two flags) or "auto"
        (chosen per recording by BIC; the choice and margin are in the result).
    solver: "optimistix" (Levenberg-Marquardt) or "jaxopt", for ratio-only spectra, which fit
        each pair alone.
    """

    method: str = "welch"
    prewhiten: int | None = 8
    nperseg: int | None = None
    velocity: tuple[float, float] | None = None
    gain_ratio: Any = None
    fit_gain: bool = False
    noise_floor: bool = False
    smoothness: float = 1.0
    min_snr: float = 1.0
    max_err: float = 0.5
    fmin: float | None = None
    fmax: float | None = None
    leakage_db: float = 20.0
    conditioned: bool = True
    cross_pairs: int | None = None
    profile_minor: bool = True
    window: str | None = None
    texture: str | None = None
    direction: str | None = None
    model: str | None = None
    solver: str = "optimistix"


WINDOWS = ("hertz", "gaussian")


def settings_of(options: FitOptions, *, has_xy: bool = True, window: str | None = None) -> Settings:
    """The pipeline's ``Settings`` (data, not a new program) for ``options``; ``window`` overrides
    ``options.window`` (None: the Hertz window, which the default fits first)."""
    window = window or options.window or "hertz"
    if window not in WINDOWS:
        raise TactileInputError(f"window must be one of {', '.join(WINDOWS)} or None, got {window!r}",
                                code="bad_setting")
    if options.direction not in (None,) + DIRECTIONS:
        raise TactileInputError(f"direction must be one of {', '.join(DIRECTIONS)} or None, got "
                                f"{options.direction!r}", code="bad_setting")
    hertz = None
    if window == "hertz":
        from ..model.hertz import hertz_table

        hertz = hertz_table().coef
    chain = (2 if has_xy else 0) if options.cross_pairs is None else int(options.cross_pairs)
    return Settings(min_snr=float(options.min_snr), max_err=float(options.max_err),
                    fmin=-np.inf if options.fmin is None else float(options.fmin),
                    fmax=np.inf if options.fmax is None else float(options.fmax),
                    leakage_db=float(options.leakage_db), smoothness=float(options.smoothness),
                    noise_floor=bool(options.noise_floor), fit_gain=bool(options.fit_gain),
                    conditioned=bool(options.conditioned), chain=chain if has_xy else 0,
                    directional=options.texture == "directional", hertz=hertz)


def analysis_settings(options: FitOptions, *, has_xy: bool = True) -> Settings:
    """The analysis program's ``Settings`` for ``options``: both windows' (the Hertz table as data), or the
    Gaussian window's alone where ``options.window`` gives it (a smaller program); the window given, if any,
    goes in ``choices_of`` too."""
    return settings_of(options, has_xy=has_xy, window="gaussian" if options.window == "gaussian" else "hertz")


def choices_of(options: FitOptions):
    """The analysis program's ``analysis.Choices`` for ``options``: what the user fixed, as data."""
    from .analysis import Choices, TEXTURES, WINDOWS as WINS

    settings_of(options)                        # checks window and direction with their one-line errors
    texture = options.texture
    if texture not in (None,) + TEXTURES:
        raise TactileInputError(f"texture must be one of {', '.join(TEXTURES)} or None, got {texture!r}",
                                code="bad_setting")
    return Choices(window=0 if options.window is None else 1 + WINS.index(options.window),
                   texture=0 if texture is None else 1 + TEXTURES.index(texture),
                   direction=0 if options.direction is None else 1 + DIRECTIONS.index(options.direction),
                   test_window=options.model is None, refit=False)


def options_from_file(options: FitOptions, rec) -> FitOptions:
    """``options`` with what a file knows and the options leave open: its ``velocity`` and ``gain_ratio``."""
    if options.velocity is None and rec.velocity is not None:
        options = dataclasses.replace(options, velocity=tuple(abs(float(v)) for v in rec.velocity))
    if options.gain_ratio is None and rec.gain_ratio is not None:
        options = dataclasses.replace(options, gain_ratio=rec.gain_ratio)
    return options


def known_gains(options: FitOptions) -> tuple[float, float]:
    """The deep/shallow gain ratios (gx, gy) that ``options`` give (1 where none)."""
    g = options.gain_ratio
    if g is None:
        return 1.0, 1.0
    g = np.atleast_1d(np.asarray(g, float))
    return (float(g[0]), float(g[-1]))


# --------------------------------------------------------------------------- scene recipes' [fit] tables


_OPTION_FIELDS = {f.name: f for f in dataclasses.fields(FitOptions)}
_CHOICES = {"method": ("welch", "multitaper"), "solver": ("optimistix", "jaxopt"), "window": ("gaussian", "hertz"),
            "texture": ("isotropic", "directional"), "model": MODELS}


def _bad(path, problem: str) -> TactileInputError:
    return TactileInputError(problem, source=str(path), code="bad_setting")


def _number(path, key, value, *, integer=False, positive=False):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _bad(path, f"[fit] {key} must be a number, got {value!r}")
    if integer and int(value) != value:
        raise _bad(path, f"[fit] {key} must be an integer, got {value!r}")
    if positive and not value > 0:
        raise _bad(path, f"[fit] {key} must be positive, got {value!r}")
    return int(value) if integer else float(value)


def _option(path, key: str, value) -> Any:
    """One [fit] entry, checked and converted to the FitOptions field's type."""
    if key in _CHOICES:
        if value not in _CHOICES[key]:
            raise _bad(path, f"[fit] {key} = {value!r}: expected one of {', '.join(_CHOICES[key])}")
        return value
    if key in ("fit_gain", "noise_floor"):
        if not isinstance(value, bool):
            raise _bad(path, f"[fit] {key} must be true or false, got {value!r}")
        return value
    if key == "velocity":
        if not (isinstance(value, list) and len(value) == 2):
            raise _bad(path, f"[fit] velocity must be [vx, vy] in m/s, got {value!r}")
        return tuple(abs(_number(path, key, v)) for v in value)
    if key == "gain_ratio":
        vals = value if isinstance(value, list) else [value]
        if not 1 <= len(vals) <= 2:
            raise _bad(path, f"[fit] gain_ratio must be g or [gx, gy], got {value!r}")
        vals = [_number(path, key, v, positive=True) for v in vals]
        return vals[0] if len(vals) == 1 else tuple(vals)
    if key == "prewhiten":
        n = _number(path, key, value, integer=True)
        return n if n > 0 else None
    if key == "nperseg":
        return _number(path, key, value, integer=True, positive=True)
    if key in ("smoothness", "max_err"):
        return _number(path, key, value, positive=True)
    return _number(path, key, value)          # min_snr, fmin, fmax, leakage_db


def recipe_options(table: dict, path="<recipe>", base: FitOptions | None = None) -> FitOptions:
    """FitOptions from a scene recipe's [fit] table (``io.recipes.Recipe.fit``: plain TOML values), on top of
    ``base`` (default ``FitOptions()``). Unknown keys or wrong types: a one-line ``TactileInputError`` naming
    ``path`` and the key."""
    if not isinstance(table, dict):
        raise _bad(path, "[fit] must be a table")
    changes = {}
    for key, value in table.items():
        if key not in _OPTION_FIELDS:
            raise _bad(path, f"unknown key [fit] {key!r}; expected one of {', '.join(_OPTION_FIELDS)}")
        changes[key] = _option(path, key, value)
    return dataclasses.replace(base or FitOptions(), **changes)
