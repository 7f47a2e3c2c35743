"""Surface textures for the scene simulator (numpy; not differentiated).

A texture is the dimensionless surface divergence field u0(x, y) (paper
Eq. 1) of the object, in the object's own frame at time 0; x, y in metres.
Every texture here has zero mean: the static contact pressure is not part of
the texture (a scene's ``dc_offset`` models what reaches the signals).

Two kinds, used polymorphically through :func:`texture_field`:

* analytic textures (:class:`Grating`, :class:`WireNet`, or any object with a
  method ``field(x, y) -> u0``) are evaluated pointwise;
* random textures (:class:`RandomTexture`, :class:`DirectionalTexture`,
  :class:`StretchedTexture`, or any object with a method ``sample(shape, spacing, rng) -> u0`` on a regular
  grid) are generated on the whole grid at once. :class:`RandomTexture` is
  isotropic, so the grid may be given in any rotated frame; a sampler with a
  ``rotation`` keyword (the directional textures) is told the grid's angle.

:class:`ModeTexture` (a finite sum of plane waves with RandomTexture's
spectrum) is analytic: exact at any angle, reproducible from its own seed.

Analytic profiles are point-sampled by the simulator; a profile's harmonics
above the grid's Nyquist frequency (pi / spacing) fold back. With the default
25 um grid the folded part of a 0.1 mm wire is below 1e-3 of its fundamental;
it shows mostly as a small grid-dependent mean (a DC of the signals).
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import math

import numpy as np

from ..errors import TactileInputError

__all__ = [
    "RandomTexture",
    "DirectionalTexture",
    "StretchedTexture",
    "ModeTexture",
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


def _anisotropy(name: str, value, meaning: str = "power along angle / across it") -> float:
    v = _finite(name, value)
    if v < 1.0:
        raise TactileInputError(f"{name} must be >= 1 ({meaning}), got {value!r}", code="bad_setting")
    return v


def _count(name: str, value, minimum: int) -> int:
    ok = not isinstance(value, bool) and isinstance(value, (int, np.integer, float, np.floating))
    if ok and float(value).is_integer() and value >= minimum:
        return int(value)
    raise TactileInputError(f"{name} must be an integer >= {minimum}, got {value!r}", code="bad_setting")


def _check_scales(name: str, texture) -> None:
    """A random texture's rms, correlation_length and smallest_scale are positive numbers."""
    for field in ("rms", "correlation_length", "smallest_scale"):
        _positive(f"{name}.{field}", getattr(texture, field))


def _radial_power(k, correlation_length: float, smallest_scale: float):
    """Unnormalised radial spectrum (1 + (k l)^2)^(-3/2) exp(-(k s / (2 pi))^2), k in rad/m."""
    k = np.asarray(k, dtype=float)
    return ((1.0 + np.square(k * correlation_length)) ** -1.5
            * np.exp(-np.square(k * smallest_scale / (2.0 * np.pi))))


def _angular_factor(kx, ky, contrast: float, angle: float):
    """1 + c cos 2(theta - angle), theta the direction of (kx, ky); 1 at k = 0."""
    kx = np.asarray(kx, dtype=float)
    ky = np.asarray(ky, dtype=float)
    k2 = np.square(kx) + np.square(ky)
    safe = np.where(k2 > 0, k2, 1.0)
    cos2 = (np.square(kx) - np.square(ky)) / safe
    sin2 = 2.0 * kx * ky / safe
    return 1.0 + contrast * np.where(k2 > 0, cos2 * math.cos(2.0 * angle) + sin2 * math.sin(2.0 * angle), 0.0)


def _spectral_sample(shape, spacing, rng, pad: float, rms: float, row_power) -> np.ndarray:
    """Gaussian field on a ``shape`` grid with 2-D spectrum ``row_power(ky, kx)`` (one ky row at a time).

    White noise filtered by sqrt(power) by FFT on a grid padded by ``pad`` (m)
    along each axis, then cropped; the k = 0 mode is zero and the power is
    normalised to mean 1 over the padded grid, so the variance is rms^2 in
    expectation.
    """
    import scipy.fft  # here, not at import: importing scipy.fft takes about 0.5 s

    ny, nx = (int(n) for n in shape)
    dy, dx = (float(spacing), float(spacing)) if np.ndim(spacing) == 0 else (float(s) for s in spacing)
    fy = scipy.fft.next_fast_len(ny + int(math.ceil(pad / dy)), real=True)
    fx = scipy.fft.next_fast_len(nx + int(math.ceil(pad / dx)), real=True)
    ky = 2.0 * np.pi * scipy.fft.fftfreq(fy, d=dy)
    kx = 2.0 * np.pi * scipy.fft.rfftfreq(fx, d=dx)
    # Power on the half plane, built row by row to keep memory at one complex grid.
    amp = np.empty((fy, kx.size))
    for j in range(fy):
        amp[j] = row_power(ky[j], kx)
    amp[0, 0] = 0.0
    # Mean of the power over the full (two-sided) grid: interior rfft columns count twice.
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
    out *= rms
    return np.ascontiguousarray(out) if (ny, nx) != (fy, fx) else out


def _plane_waves_on_grid(kvec, amp, phase, xi, eta, slip_angle: float, columns: int = 1 << 14) -> np.ndarray:
    """sum_j amp_j cos(k_j . r + phase_j) on the slip-frame grid ``xi`` (nx,) by ``eta`` (ny,): (ny, nx) float64.
    A plane wave is separable on a rotated grid, cos(a xi + b eta + p) = Re(e^{i b eta} e^{i p} e^{i a xi}), so
    the sum is a complex matrix product (in blocks of ``columns`` xi, so memory stays bounded)."""
    xi = np.asarray(xi, dtype=float).ravel()
    eta = np.asarray(eta, dtype=float).ravel()
    c, s = math.cos(slip_angle), math.sin(slip_angle)
    a = kvec[:, 0] * c + kvec[:, 1] * s           # the wavevector's component along xi
    b = -kvec[:, 0] * s + kvec[:, 1] * c          # and along eta
    left = np.exp(1j * np.multiply.outer(eta, b)) * (amp * np.exp(1j * phase))
    out = np.empty((eta.size, xi.size))
    for i0 in range(0, xi.size, columns):
        out[:, i0:i0 + columns] = (left @ np.exp(1j * np.multiply.outer(a, xi[i0:i0 + columns]))).real
    return out


#: cells per period of a lattice texture's unit cell in its Fourier transform (``_lattice_modes``): a kinked
#: profile's harmonics fall as n^-2, so those folded back from near this many land 1e-6 of the fundamental low
LATTICE_CELLS = 1024
#: a lattice texture's plane waves below this fraction of its largest amplitude are left out
LATTICE_FLOOR = 1e-12


def _lattice_modes(g1, g2, cell, k_max: float, n: int = LATTICE_CELLS):
    """The plane waves (wavevectors (J, 2) rad/m, amplitudes (J,), phases (J,) rad) of a periodic texture with
    |k| <= ``k_max``: ``cell(u1, u2)`` is the texture at fractions (u1, u2) of its periods along the reciprocal
    vectors ``g1``, ``g2`` (2,) rad/m (``g2`` None: one-dimensional, ``cell(u1)``), its wavevectors n1 g1 + n2 g2.
    Each pair of opposite wavevectors is one cosine; the mean (k = 0) is left out. Waves the depth kernel alone
    would silence are kept: a Hertz disk's edge spreads a wave's power down to the wavenumbers the probes hear
    (leaving out those with amp exp(-|k| d1) below 1e-12 changed a net's deep probe signals by 1.6e-3 under the
    disk, 7e-10 under the Gaussian window)."""
    u = np.arange(n) / n
    g1 = np.asarray(g1, float)
    if g2 is None:
        c = np.fft.rfft(cell(u)) / n
        idx = np.arange(1, c.size)
        keep = idx < n // 2
        kvec = np.outer(idx[keep], g1)
        coef = c[1:][keep]
    else:
        g2 = np.asarray(g2, float)
        c = np.fft.fft2(cell(u[:, None], u[None, :])) / (n * n)
        f = np.fft.fftfreq(n, 1.0 / n).astype(int)
        n1, n2 = np.meshgrid(f, f, indexing="ij")
        half = ((n1 > 0) | ((n1 == 0) & (n2 > 0))) & (np.abs(n1) < n // 2) & (np.abs(n2) < n // 2)
        kvec = n1[half][:, None] * g1 + n2[half][:, None] * g2
        coef = c[half]
    amp = 2.0 * np.abs(coef)
    keep = (np.hypot(kvec[:, 0], kvec[:, 1]) <= k_max) & (amp >= LATTICE_FLOOR * max(float(amp.max(initial=0.0)),
                                                                                    1e-300))
    return kvec[keep], amp[keep], np.angle(coef[keep])


@functools.lru_cache(maxsize=16)
def _periodic_modes(texture, k_max: float):
    """``texture._lattice(k_max)``, kept: a scene evaluates its texture in many blocks of rows."""
    return texture._lattice(k_max)


def _grid_nyquist(xi, eta) -> float:
    """The Nyquist wavenumber (rad/m) of the regular grid ``xi`` by ``eta``: pi over its coarser step."""
    steps = [abs(float(v[1] - v[0])) for v in (np.ravel(xi), np.ravel(eta)) if np.size(v) > 1]
    return math.pi / max(steps) if steps else math.inf


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
        _check_scales("RandomTexture", self)

    def power_spectrum(self, k):
        """Unnormalised Phi(k) (C = 1) at spatial frequency ``k`` (rad/m)."""
        return _radial_power(k, self.correlation_length, self.smallest_scale)

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
        return _spectral_sample(shape, spacing, rng, 5.0 * self.correlation_length, self.rms,
                                lambda ky, kx: self.power_spectrum(np.hypot(ky, kx)))


@dataclasses.dataclass(frozen=True)
class DirectionalTexture:
    """Anisotropic Gaussian random texture: RandomTexture's spectrum times a cos 2theta lobe.

    The 2-D power spectral density at wavevector k = |k| (cos theta, sin theta) is

        Phi(k) (1 + c cos 2(theta - angle)),   c = (anisotropy - 1) / (anisotropy + 1)

    with Phi RandomTexture's radial spectrum (same rms, correlation_length,
    smallest_scale), normalised so the variance of u0 is rms^2 in
    expectation. Wavevectors along ``angle`` carry ``anisotropy`` times the
    power of those across it, so ridges run across ``angle``.

    rms: dimensionless; correlation_length, smallest_scale: metres;
    anisotropy: >= 1 (1 is RandomTexture); angle: rad, in the object frame.
    """

    rms: float = 1.0
    correlation_length: float = 1.0e-3
    smallest_scale: float = 0.2e-3
    anisotropy: float = 3.0
    angle: float = 0.0

    def __post_init__(self):
        _check_scales("DirectionalTexture", self)
        _anisotropy("DirectionalTexture.anisotropy", self.anisotropy)
        _finite("DirectionalTexture.angle", self.angle)

    @property
    def contrast(self) -> float:
        """c = (anisotropy - 1) / (anisotropy + 1), in [0, 1)."""
        a = float(self.anisotropy)
        return (a - 1.0) / (a + 1.0)

    def power_spectrum(self, kx, ky):
        """Unnormalised Phi(|k|) (1 + c cos 2(theta - angle)) at wavevector (kx, ky), rad/m."""
        return (_radial_power(np.hypot(kx, ky), self.correlation_length, self.smallest_scale)
                * _angular_factor(kx, ky, self.contrast, float(self.angle)))

    def sample(self, shape, spacing, rng, rotation: float = 0.0) -> np.ndarray:
        """One realisation on a regular grid, shape ``(ny, nx)``, float64, zero mean.

        spacing: (dy, dx) metres (or one number); rng: a ``numpy.random.Generator``;
        rotation: angle (rad) of the grid's x axis in the object frame (the slip
        angle for a scene). As RandomTexture.sample, but padded by 10
        correlation lengths: the cos 2theta lobe makes the covariance decay
        as c l^2 / r^2 rather than exponentially (wrap-around below ~c / 50).
        """
        # Rotation: a stationary field defined by its spectrum, seen in axes
        # turned by phi, has the spectrum turned by -phi; so the grid's field
        # is drawn directly with the lobe at angle - rotation. Exact, and no
        # larger grid or interpolation than an object-frame draw would need.
        contrast, lobe = self.contrast, float(self.angle) - float(rotation)
        return _spectral_sample(
            shape, spacing, rng, 10.0 * self.correlation_length, self.rms,
            lambda ky, kx: (_radial_power(np.hypot(ky, kx), self.correlation_length, self.smallest_scale)
                            * _angular_factor(kx, ky, contrast, lobe)))


@dataclasses.dataclass(frozen=True)
class StretchedTexture:
    """RandomTexture stretched along its ridges: a brushed or lapped surface (geometric anisotropy).

    The correlation length is ``correlation_length`` across the ridges and
    ``aspect`` times it along them; the ridges run across ``angle``. The 2-D
    power spectral density at wavevector k is RandomTexture's radial spectrum
    at the stretched wavenumber

        K = sqrt((k . u)^2 + aspect^2 (k . u_perp)^2),   u = (cos angle, sin angle),

    so its angular profile sharpens with |k| (power along ``angle`` over power
    across it: aspect^3 where k l >> 1, 1 where k l << 1): unlike the
    directional fit's lobe, it is not a function of angle times one of |k|.
    Variance rms^2 in expectation.

    rms: dimensionless; correlation_length, smallest_scale: metres (across the
    ridges); aspect: >= 1 (1 is RandomTexture); angle: rad, in the object frame.
    """

    rms: float = 1.0
    correlation_length: float = 1.0e-3
    smallest_scale: float = 0.2e-3
    aspect: float = 2.0
    angle: float = 0.0

    def __post_init__(self):
        _check_scales("StretchedTexture", self)
        _anisotropy("StretchedTexture.aspect", self.aspect, "correlation length along the ridges / across them")
        _finite("StretchedTexture.angle", self.angle)

    def _power(self, kx, ky, angle: float):
        c, s = math.cos(angle), math.sin(angle)
        along_u = np.asarray(kx, dtype=float) * c + np.asarray(ky, dtype=float) * s
        across_u = -np.asarray(kx, dtype=float) * s + np.asarray(ky, dtype=float) * c
        stretched = np.hypot(along_u, float(self.aspect) * across_u)
        return _radial_power(stretched, self.correlation_length, self.smallest_scale)

    def power_spectrum(self, kx, ky):
        """Unnormalised Phi(K) at wavevector (kx, ky), rad/m (K the stretched wavenumber)."""
        return self._power(kx, ky, float(self.angle))

    def sample(self, shape, spacing, rng, rotation: float = 0.0) -> np.ndarray:
        """One realisation on a regular grid, shape ``(ny, nx)``, float64, zero mean; as
        DirectionalTexture.sample (``rotation``: the grid's x axis in the object frame), padded by 5
        correlation lengths along the ridges."""
        lobe = float(self.angle) - float(rotation)
        return _spectral_sample(shape, spacing, rng, 5.0 * float(self.aspect) * self.correlation_length, self.rms,
                                lambda ky, kx: self._power(kx, ky, lobe))


@dataclasses.dataclass(frozen=True)
class ModeTexture:
    """Finite sum of plane waves with RandomTexture's spectrum: an analytic random texture.

    u0(x, y) = sum_j A cos(k_j . r + phase_j) over ``n_modes`` modes drawn
    once from ``seed``: |k_j| from the radial power density k Phi(k) of
    RandomTexture (same rms, correlation_length, smallest_scale; stratified
    quantiles, so few modes follow it closely), directions from
    1 + c cos 2(theta - angle) as in DirectionalTexture (uniform at the
    default anisotropy 1), phases uniform. All amplitudes are
    A = rms sqrt(2 / n_modes), so sum A^2 / 2 = rms^2 exactly. The field is
    not Gaussian for few modes; its spectrum is a set of lines.

    rms: dimensionless; correlation_length, smallest_scale: metres;
    anisotropy: >= 1; angle: rad; n_modes: >= 1; seed: int >= 0.
    The modes are in ``modes`` (not dataclass fields).
    """

    rms: float = 1.0
    correlation_length: float = 1.0e-3
    smallest_scale: float = 0.2e-3
    n_modes: int = 300
    seed: int = 0
    anisotropy: float = 1.0
    angle: float = 0.0

    def __post_init__(self):
        rms = _positive("ModeTexture.rms", self.rms)
        ell = _positive("ModeTexture.correlation_length", self.correlation_length)
        small = _positive("ModeTexture.smallest_scale", self.smallest_scale)
        c = (_anisotropy("ModeTexture.anisotropy", self.anisotropy) - 1.0) / (float(self.anisotropy) + 1.0)
        angle = _finite("ModeTexture.angle", self.angle)
        n = _count("ModeTexture.n_modes", self.n_modes, 1)
        seed = _count("ModeTexture.seed", self.seed, 0)
        object.__setattr__(self, "n_modes", n)
        object.__setattr__(self, "seed", seed)
        rng = np.random.default_rng(seed)
        # |k|: inverse CDF of k Phi(k) on a log grid spanning both scales, up to exp(-16) of the cut-off.
        kmax = 4.0 * 2.0 * np.pi / small
        kgrid = np.concatenate([[0.0], np.geomspace(1e-4 * min(1.0 / ell, 2.0 * np.pi / small), kmax, 4096)])
        dens = kgrid * _radial_power(kgrid, ell, small)
        cdf = np.concatenate([[0.0], np.cumsum(0.5 * (dens[1:] + dens[:-1]) * np.diff(kgrid))])
        cdf /= cdf[-1]
        k = np.interp((rng.permutation(n) + rng.random(n)) / n, cdf, kgrid)
        # Directions: inverse CDF of (1 + c cos 2t) / (2 pi), t = theta - angle.
        u = (rng.permutation(n) + rng.random(n)) / n
        if c > 0:
            tgrid = np.linspace(0.0, 2.0 * np.pi, 4097)
            theta = angle + np.interp(u, (tgrid + 0.5 * c * np.sin(2.0 * tgrid)) / (2.0 * np.pi), tgrid)
        else:
            theta = angle + 2.0 * np.pi * u
        phase = 2.0 * np.pi * rng.random(n)
        kvec = np.stack([k * np.cos(theta), k * np.sin(theta)], axis=1)
        amp = np.full(n, rms * math.sqrt(2.0 / n))
        for arr in (kvec, amp, phase):
            arr.setflags(write=False)
        object.__setattr__(self, "_modes", (kvec, amp, phase))

    @property
    def modes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(wavevectors (n, 2) rad/m, amplitudes (n,), phases (n,) rad), read-only."""
        return self._modes

    def field(self, x, y) -> np.ndarray:
        """u0 at positions ``x``, ``y`` (m, broadcastable arrays), float64.

        Evaluated in blocks of points (about 2^20 point-mode products at a
        time), so memory stays at a few times the output's.
        """
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        shape = np.broadcast_shapes(x.shape, y.shape)
        xf = np.ascontiguousarray(np.broadcast_to(x, shape)).reshape(-1)
        yf = np.ascontiguousarray(np.broadcast_to(y, shape)).reshape(-1)
        kvec, amp, phase = self._modes
        kx, ky = np.ascontiguousarray(kvec[:, 0]), np.ascontiguousarray(kvec[:, 1])
        out = np.empty(xf.size)
        step = max(1, (1 << 20) // amp.size)
        buf = np.empty((min(step, xf.size), amp.size))
        tmp = np.empty_like(buf)
        for i0 in range(0, xf.size, step):
            i1 = min(xf.size, i0 + step)
            b, t = buf[:i1 - i0], tmp[:i1 - i0]
            np.multiply.outer(xf[i0:i1], kx, out=b)
            np.multiply.outer(yf[i0:i1], ky, out=t)
            b += t
            b += phase
            np.cos(b, out=b)
            out[i0:i1] = b @ amp
        return out.reshape(shape)

    def grid_field(self, xi, eta, slip_angle: float = 0.0) -> np.ndarray:
        """u0 on the slip-frame grid ``xi`` (nx,) by ``eta`` (ny,), metres, as :func:`texture_field` lays it
        out: (ny, nx) float64: one complex matrix product (``_plane_waves_on_grid``), about 100 times faster
        than :meth:`field` pointwise."""
        return _plane_waves_on_grid(*self._modes, xi, eta, slip_angle)


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

    def grid_field(self, xi, eta, slip_angle: float = 0.0) -> np.ndarray:
        """u0 on the slip-frame grid ``xi`` by ``eta`` (as :func:`texture_field`), band-limited to the grid's
        Nyquist wavenumber: the harmonics of the profile above it, sampled on the grid, would fold onto
        wavenumbers the probes hear (``_lattice_modes``)."""
        return _plane_waves_on_grid(*_periodic_modes(self, _grid_nyquist(xi, eta)), xi, eta, slip_angle)

    def _lattice(self, k_max: float):
        g = self.wavenumber * np.array([math.cos(self.angle), math.sin(self.angle)])
        if self.profile == "sine":
            keep = self.wavenumber <= k_max
            return np.tile(g, (int(keep), 1)), np.full(int(keep), float(self.amplitude)), np.zeros(int(keep))
        return _lattice_modes(g, None, lambda u: self.amplitude * (
            _raised_cosine_bumps(u * self.pitch, self.pitch, 0.5 * self.pitch) - 0.25), k_max)


@dataclasses.dataclass(frozen=True)
class WireNet:
    """Two crossed gratings of wires, like the paper's 0.5 mm wire net (Fig. 7).

    Each wire is a raised-cosine bump 0.5 (1 + cos(2 pi s' / wire_width)) of
    full base width ``wire_width``, repeated every ``pitch``; one family of
    wires runs along direction ``angle`` + pi/2 (its wavevector at ``angle``),
    the other perpendicular to it, or ``shear`` further round (a sheared
    net, wavevector at ``angle`` + pi/2 + ``shear``). The height where wires
    cross is the MAX of the two families (a height map; not their sum), minus
    its exact mean w/p - (w / (pi p))^2 (pi^2 - 4) / 2, w = wire_width,
    p = pitch (the same for any shear). pitch, wire_width: metres,
    wire_width < pitch; angle: rad; shear: rad, |shear| < pi/2.
    """

    pitch: float = 0.5e-3
    wire_width: float = 0.1e-3
    angle: float = 0.0
    amplitude: float = 1.0
    shear: float = 0.0

    def __post_init__(self):
        p = _positive("WireNet.pitch", self.pitch)
        w = _positive("WireNet.wire_width", self.wire_width)
        _finite("WireNet.angle", self.angle)
        _finite("WireNet.amplitude", self.amplitude)
        if w >= p:
            raise TactileInputError(f"WireNet.wire_width ({w}) must be smaller than its pitch ({p})",
                                    code="bad_setting")
        if not abs(_finite("WireNet.shear", self.shear)) < 0.5 * math.pi:
            raise TactileInputError(f"WireNet.shear must lie strictly between -pi/2 and pi/2 (the two families "
                                    f"would be parallel), got {self.shear!r}", code="bad_setting")

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
        c2, s2 = math.cos(self.angle + self.shear), math.sin(self.angle + self.shear)
        f1 = _raised_cosine_bumps(x * c + y * s, self.pitch, self.wire_width)
        f2 = _raised_cosine_bumps(-x * s2 + y * c2, self.pitch, self.wire_width)
        return self.amplitude * (np.maximum(f1, f2) - self.mean_height)

    def grid_field(self, xi, eta, slip_angle: float = 0.0) -> np.ndarray:
        """u0 on the slip-frame grid ``xi`` by ``eta`` (as :func:`texture_field`), band-limited to the grid's
        Nyquist wavenumber: the net's harmonics above it (a wire 0.1 mm wide rings to the 20th harmonic and
        beyond), sampled on the grid, would fold onto wavenumbers the probes hear (``_lattice_modes``)."""
        return _plane_waves_on_grid(*_periodic_modes(self, _grid_nyquist(xi, eta)), xi, eta, slip_angle)

    def _lattice(self, k_max: float):
        k = 2.0 * math.pi / self.pitch
        g1 = k * np.array([math.cos(self.angle), math.sin(self.angle)])
        g2 = k * np.array([-math.sin(self.angle + self.shear), math.cos(self.angle + self.shear)])

        def cell(u1, u2):
            f1 = _raised_cosine_bumps(u1 * self.pitch, self.pitch, self.wire_width)
            f2 = _raised_cosine_bumps(u2 * self.pitch, self.pitch, self.wire_width)
            return self.amplitude * (np.maximum(f1, f2) - self.mean_height)

        return _lattice_modes(g1, g2, cell, k_max)


def texture_field(texture, xi, eta, slip_angle: float = 0.0, rng=None) -> np.ndarray:
    """u0 on the grid of slip-frame coordinates ``xi`` (along the slip) by ``eta`` (across).

    xi: (nx,) and eta: (ny,) metres; the point (xi, eta) is the object-frame
    position (x, y) = (xi cos(phi) - eta sin(phi), xi sin(phi) + eta cos(phi)),
    phi = ``slip_angle`` (rad). Returns float64 of shape (ny, nx).

    Textures with a ``grid_field`` method evaluate themselves on the grid (plane-wave sums; periodic
    textures band-limited to the grid's Nyquist wavenumber). Other analytic textures (a ``field(x, y)``
    method) are evaluated at the grid's points. Random
    textures (a ``sample(shape, spacing, rng)`` method) need regular ``xi`` and
    ``eta`` and an ``rng``; they are generated directly in the slip frame, so
    a sampler is told ``rotation=phi`` if it takes that keyword
    (:class:`DirectionalTexture`) and must otherwise be isotropic.
    """
    xi = np.asarray(xi, dtype=float).ravel()
    eta = np.asarray(eta, dtype=float).ravel()
    if hasattr(texture, "grid_field"):
        return np.asarray(texture.grid_field(xi, eta, slip_angle), dtype=float)
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
        kw = {"rotation": float(slip_angle)} if "rotation" in inspect.signature(texture.sample).parameters else {}
        return np.asarray(texture.sample((eta.size, xi.size), (dy, dx), rng, **kw), dtype=float)
    raise TactileInputError(
        f"unknown texture {type(texture).__name__}: it needs a field(x, y) or sample(shape, spacing, rng) method",
        code="bad_setting")


def describe_texture(texture) -> dict:
    """JSON-serialisable description: ``{"name": class name, **parameters}``."""
    out = {"name": type(texture).__name__}
    if dataclasses.is_dataclass(texture):
        for f in dataclasses.fields(texture):
            v = getattr(texture, f.name)
            if f.type in ("int", int) and isinstance(v, (int, np.integer)) and not isinstance(v, bool):
                out[f.name] = int(v)      # counts and seeds stay integers
                continue
            out[f.name] = v if isinstance(v, (str, bool, type(None))) else (
                float(v) if np.ndim(v) == 0 else np.asarray(v, dtype=float).tolist())
    else:
        out["repr"] = repr(texture)
    return out
