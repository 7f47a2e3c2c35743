"""Surface textures for the scene simulator (numpy; not differentiated).

A texture is the dimensionless surface divergence field u0(x, y) (paper
Eq. 1) of the object, in the object's own frame at time 0; x, y in metres.
Every texture here has zero mean: the static contact pressure is not part of
the texture (a scene's ``dc_offset`` models what reaches the signals).

Two kinds, used polymorphically through :func:`texture_field`:

* analytic textures (:class:`Grating`, :class:`WireNet`, or any object with a
  method ``field(x, y) -> u0``) are evaluated pointwise;
* random textures (:class:`RandomTexture`, or any object with a method
  ``sample(shape, spacing, rng) -> u0`` on a regular grid) are generated on
  the whole grid at once. :class:`RandomTexture` is isotropic, so the grid may
  be given in any rotated frame.

Analytic profiles are point-sampled by the simulator; a profile's harmonics
above the grid's Nyquist frequency (pi / spacing) fold back. With the default
25 um grid the folded part of a 0.1 mm wire is below 1e-3 of its fundamental;
it shows mostly as a small grid-dependent mean (a DC of the signals).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .errors import TactileInputError

__all__ = [
    "RandomTexture",
    "Grating",
    "WireNet",
    "GRATING_PROFILES",
    "texture_field",
    "describe_texture",
]

GRATING_PROFILES = ("sine", "pipes")


def _positive(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise TactileInputError(f"{name} must be a number, got {value!r}", code="bad_setting") from None
    if not math.isfinite(v) or v <= 0:
        raise TactileInputError(f"{name} must be positive and finite, got {value!r}", code="bad_setting")
    return v


def _finite(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise TactileInputError(f"{name} must be a number, got {value!r}", code="bad_setting") from None
    if not math.isfinite(v):
        raise TactileInputError(f"{name} must be finite, got {value!r}", code="bad_setting")
    return v


def _raised_cosine_bumps(s, period: float, width: float):
    """Periodic raised-cosine bumps: 0.5 (1 + cos(2 pi s' / width)) for |s'| < width / 2, else 0.

    ``s`` (m) is the coordinate along the bump axis, ``s'`` its distance to the
    nearest bump centre (centres at multiples of ``period``); peak 1, mean
    ``width / (2 period)``.
    """
    u = np.asarray(s, dtype=float) / period
    sp = (u - np.round(u)) * period
    return np.where(np.abs(sp) < 0.5 * width, 0.5 * (1.0 + np.cos(2.0 * np.pi * sp / width)), 0.0)


@dataclasses.dataclass(frozen=True)
class RandomTexture:
    """Isotropic Gaussian random texture, like the paper's foamed polystyrene.

    The 2-D power spectral density of u0 at spatial frequency k = |k| (rad/m) is

        Phi(k) = C (1 + (k l)^2)^(-3/2) exp(-(k s / (2 pi))^2)

    with l = ``correlation_length`` (m), s = ``smallest_scale`` (m) and C
    chosen so that the variance of u0 is ``rms``^2. Without the cut-off factor
    this is the spectrum of the exponential covariance rms^2 exp(-r / l) (so
    ``correlation_length`` is its e-folding length; its 1-D cross-section
    Int Phi dky is the Lorentzian (1 + (kx l)^2)^(-1)); the Gaussian factor
    removes scales finer than about s (it is exp(-1) at wavelength s).
    The defaults put the texture scales between 0.2 mm and ~10 mm.

    rms: standard deviation of u0 (dimensionless). correlation_length,
    smallest_scale: metres.
    """

    rms: float = 1.0
    correlation_length: float = 1.0e-3
    smallest_scale: float = 0.2e-3

    def __post_init__(self):
        _positive("RandomTexture.rms", self.rms)
        _positive("RandomTexture.correlation_length", self.correlation_length)
        _positive("RandomTexture.smallest_scale", self.smallest_scale)

    def power_spectrum(self, k):
        """Unnormalised Phi(k) (C = 1) at spatial frequency ``k`` (rad/m)."""
        k = np.asarray(k, dtype=float)
        return ((1.0 + np.square(k * self.correlation_length)) ** -1.5
                * np.exp(-np.square(k * self.smallest_scale / (2.0 * np.pi))))

    def sample(self, shape, spacing, rng) -> np.ndarray:
        """One realisation on a regular grid, shape ``(ny, nx)``, float64, zero mean.

        spacing: (dy, dx) grid steps in metres (or one number for both).
        rng: a ``numpy.random.Generator``. The field is made by filtering white
        noise with sqrt(Phi) by FFT on a grid padded by 5 correlation lengths
        along each axis (then cropped), so it does not repeat within ``shape``:
        the wrap-around correlation is below exp(-5). The k = 0 mode is zero;
        the variance is rms^2 in expectation over realisations (not forced per
        realisation).
        """
        import scipy.fft  # here, not at import: importing scipy.fft takes about 0.5 s

        ny, nx = (int(n) for n in shape)
        dy, dx = (float(spacing), float(spacing)) if np.ndim(spacing) == 0 else (float(s) for s in spacing)
        pad = 5.0 * self.correlation_length
        fy = scipy.fft.next_fast_len(ny + int(math.ceil(pad / dy)), real=True)
        fx = scipy.fft.next_fast_len(nx + int(math.ceil(pad / dx)), real=True)
        ky = 2.0 * np.pi * scipy.fft.fftfreq(fy, d=dy)
        kx = 2.0 * np.pi * scipy.fft.rfftfreq(fx, d=dx)
        # Phi on the half plane, built row by row to keep memory at one complex grid.
        amp = np.empty((fy, kx.size))
        for j in range(fy):
            amp[j] = self.power_spectrum(np.hypot(ky[j], kx))
        amp[0, 0] = 0.0
        # Mean of Phi over the full (two-sided) grid: interior rfft columns count twice.
        col_w = np.full(kx.size, 2.0)
        col_w[0] = 1.0
        if fx % 2 == 0:
            col_w[-1] = 1.0
        mean_phi = float(np.sum(amp.sum(axis=0) * col_w)) / (fy * fx)
        np.sqrt(amp / mean_phi, out=amp)
        spec = scipy.fft.rfft2(rng.standard_normal((fy, fx)), workers=-1, overwrite_x=True)
        spec *= amp
        del amp
        field = scipy.fft.irfft2(spec, s=(fy, fx), workers=-1, overwrite_x=True)
        del spec
        out = field[:ny, :nx]
        out *= self.rms
        return np.ascontiguousarray(out) if (ny, nx) != (fy, fx) else out


@dataclasses.dataclass(frozen=True)
class Grating:
    """1-D periodic texture, like the paper's 1.5 mm pipes (Fig. 4).

    u0 = amplitude * f(x cos(angle) + y sin(angle)): the wavevector, of size
    k = 2 pi / pitch (rad/m), makes ``angle`` (rad) with the x axis.
    ``profile``:
      "sine":  f(s) = cos(2 pi s / pitch) (a single mode);
      "pipes": raised-cosine bumps 0.5 (1 + cos(4 pi s' / pitch)) of full
               width pitch / 2 centred on s = n pitch (s' the distance to the
               nearest centre), minus their mean 1/4. Harmonics n of the
               fundamental have amplitude ~ n^-3.
    pitch: metres; amplitude: the peak of f's bump (dimensionless).
    """

    pitch: float = 1.5e-3
    angle: float = 0.0
    profile: str = "sine"
    amplitude: float = 1.0

    def __post_init__(self):
        _positive("Grating.pitch", self.pitch)
        _finite("Grating.angle", self.angle)
        _finite("Grating.amplitude", self.amplitude)
        if self.profile not in GRATING_PROFILES:
            raise TactileInputError(
                f"Grating.profile must be one of {', '.join(GRATING_PROFILES)}, got {self.profile!r}",
                code="bad_setting")

    @property
    def wavenumber(self) -> float:
        """k = 2 pi / pitch, rad/m."""
        return 2.0 * np.pi / self.pitch

    def field(self, x, y) -> np.ndarray:
        """u0 at positions ``x``, ``y`` (m, broadcastable arrays)."""
        s = np.asarray(x, dtype=float) * math.cos(self.angle) + np.asarray(y, dtype=float) * math.sin(self.angle)
        if self.profile == "sine":
            return self.amplitude * np.cos(self.wavenumber * s)
        return self.amplitude * (_raised_cosine_bumps(s, self.pitch, 0.5 * self.pitch) - 0.25)


@dataclasses.dataclass(frozen=True)
class WireNet:
    """Two orthogonal gratings of wires, like the paper's 0.5 mm wire net (Fig. 7).

    Each wire is a raised-cosine bump 0.5 (1 + cos(2 pi s' / wire_width)) of
    full base width ``wire_width``, repeated every ``pitch``; one family of
    wires runs along direction ``angle`` + pi/2 (its wavevector at ``angle``),
    the other perpendicular. The height where wires cross is the MAX of the
    two families (a height map; not their sum), minus its exact mean
    w/p - (w / (pi p))^2 (pi^2 - 4) / 2, w = wire_width, p = pitch.
    pitch, wire_width: metres, wire_width < pitch; angle: rad.
    """

    pitch: float = 0.5e-3
    wire_width: float = 0.1e-3
    angle: float = 0.0
    amplitude: float = 1.0

    def __post_init__(self):
        p = _positive("WireNet.pitch", self.pitch)
        w = _positive("WireNet.wire_width", self.wire_width)
        _finite("WireNet.angle", self.angle)
        _finite("WireNet.amplitude", self.amplitude)
        if w >= p:
            raise TactileInputError(f"WireNet.wire_width ({w}) must be smaller than its pitch ({p})",
                                    code="bad_setting")

    @property
    def mean_height(self) -> float:
        """Mean of max(f1, f2) over a cell (subtracted in ``field``)."""
        r = self.wire_width / self.pitch
        return r - (r / np.pi) ** 2 * (np.pi ** 2 - 4.0) / 2.0

    def field(self, x, y) -> np.ndarray:
        """u0 at positions ``x``, ``y`` (m, broadcastable arrays)."""
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        c, s = math.cos(self.angle), math.sin(self.angle)
        f1 = _raised_cosine_bumps(x * c + y * s, self.pitch, self.wire_width)
        f2 = _raised_cosine_bumps(-x * s + y * c, self.pitch, self.wire_width)
        return self.amplitude * (np.maximum(f1, f2) - self.mean_height)


def texture_field(texture, xi, eta, slip_angle: float = 0.0, rng=None) -> np.ndarray:
    """u0 on the grid of slip-frame coordinates ``xi`` (along the slip) by ``eta`` (across).

    xi: (nx,) and eta: (ny,) metres; the point (xi, eta) is the object-frame
    position (x, y) = (xi cos(phi) - eta sin(phi), xi sin(phi) + eta cos(phi)),
    phi = ``slip_angle`` (rad). Returns float64 of shape (ny, nx).

    Analytic textures (a ``field(x, y)`` method) are evaluated there. Random
    textures (a ``sample(shape, spacing, rng)`` method) need regular ``xi`` and
    ``eta`` and an ``rng``; they must be isotropic, since they are generated
    directly in the slip frame.
    """
    xi = np.asarray(xi, dtype=float).ravel()
    eta = np.asarray(eta, dtype=float).ravel()
    if hasattr(texture, "field"):
        c, s = math.cos(slip_angle), math.sin(slip_angle)
        x = xi[None, :] * c - eta[:, None] * s
        y = xi[None, :] * s + eta[:, None] * c
        return np.asarray(texture.field(x, y), dtype=float)
    if hasattr(texture, "sample"):
        if rng is None:
            raise TactileInputError(f"{type(texture).__name__} needs an rng", code="bad_setting")
        dx = float(xi[1] - xi[0]) if xi.size > 1 else 1.0
        dy = float(eta[1] - eta[0]) if eta.size > 1 else dx
        return np.asarray(texture.sample((eta.size, xi.size), (dy, dx), rng), dtype=float)
    raise TactileInputError(
        f"unknown texture {type(texture).__name__}: it needs a field(x, y) or sample(shape, spacing, rng) method",
        code="bad_setting")


def describe_texture(texture) -> dict:
    """JSON-serialisable description: ``{"name": class name, **parameters}``."""
    out = {"name": type(texture).__name__}
    if dataclasses.is_dataclass(texture):
        for f in dataclasses.fields(texture):
            v = getattr(texture, f.name)
            out[f.name] = v if isinstance(v, (str, bool, type(None))) else (
                float(v) if np.ndim(v) == 0 else np.asarray(v, dtype=float).tolist())
    else:
        out["repr"] = repr(texture)
    return out
