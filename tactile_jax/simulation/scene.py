"""Scene simulator: four-channel recordings with known truth, computed in space and time.

The probe signals are computed from the surface field directly, never from
the ratio formulas of ``r_curve`` (so that tests of the estimators are not
tests of themselves). Physics (see docs/model.md): the object's texture u0 slides
with velocity v = (vx, vy); the field under the contact is
w(x, y; a) u0(x - vx t, y - vy t) with the stationary contact window w
(Gaussian exp(-3 r^2 / (2 a^2)) or Hertz sqrt(1 - r^2 / a^2)); an x-probe at
depth d outputs

    p(t) = Int Int K_d(x) w(x, y) u0(x - vx t, y - vy t) dx dy        (metres x u0)

with K_d the 1-D Poisson kernel of ``decay``, and a y-probe the same with
K_d(y). Channels [x1, x2, y1, y2] as in docs/model.md.

Algorithm (numpy / scipy.fft, bounded memory)
---------------------------------------------
Work in the slip-aligned frame (xi along v, eta across) on a square grid of
step D. One sample moves the texture by delta = |v| / fs. If delta >= the
target step D_t, D = delta / m with m = ceil(delta / D_t) (a sample is m
cells); otherwise D = q delta with q = floor(D_t / delta) (a sample is 1/q
cell). The kernels h_c(xi, eta) = K_d(x) w(x, y) D^2 ((x, y) the probe-frame
coordinates of (xi, eta)) live on a square patch of half-width 4a (Gaussian,
w < 4e-11 beyond) or a (Hertz); the texture on a strip that spans the patch
plus the whole slip path (so a random texture never repeats along the path).
Then

    p_c(n) = sum_{i, j} h_c(i, j) U(i + s_n, j),   s_n = S - n m / q

(U the strip, S the path length in cells): a correlation along xi for each
eta row, done by FFT and summed over rows in the frequency domain, in chunks
of rows so memory stays bounded. For q > 1 the correlation is read at
fractional shifts by exact trigonometric (band-limited) interpolation of the
discrete correlation. That correlation is smooth on the grid (the depth
kernel passes exp(-pi d1 / D), about 5e-15 at the defaults, at the grid's
Nyquist frequency, the Gaussian window less), so the interpolation error is
negligible: tests agree with a five times finer grid to 1e-6 of the peak.

The samples are point samples of p(t): no anti-alias filter. A scene whose
probe band reaches above fs / 2 (k > pi fs / |v|, fast slips) aliases like an
unfiltered ADC would.

The windows and the Poisson kernel are re-implemented here in numpy (the same
one-liners as ``window.gaussian_window``, ``window.hertz_window`` and
``decay.poisson_kernel``; a test checks they agree): the jnp versions would
compute in float32 unless the caller has enabled x64, and this is not
differentiated.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..errors import TactileInputError
from ..io.recording import Recording
from ..model.sensor import PAPER_SENSOR, Sensor
from .texture import RandomTexture, describe_texture, texture_field
from ..model.window import WINDOWS

__all__ = ["Scene", "simulate", "probe_signals", "MAX_GRID_CELLS"]

#: Largest texture strip (grid cells) a scene may need; about 3 GB of work memory.
MAX_GRID_CELLS = 120_000_000

_GAUSSIAN_TRUNCATION = 4.0   # patch half-width in units of a for the Gaussian window
_INTERP_MARGIN = 16          # extra strip cells at both ends of the path when interpolating
_MAX_UPSAMPLED = 1 << 23     # longest upsampled correlation; beyond it, evaluate the interpolant directly


def _bad(msg: str) -> TactileInputError:
    return TactileInputError(msg, code="bad_setting")


@dataclasses.dataclass(frozen=True)
class Scene:
    """A simulated rubbing experiment (SI units).

    texture: a texture of ``tactile_jax.texture`` (u0 in the object frame).
    velocity: (vx, vy) of the object over the sensor, m/s.
    contact_radius: a, m; or give ``contact_depth`` (m) instead, a = sqrt(R d)
        with R = ``sensor.curvature_radius`` (exactly one of the two).
    window: "gaussian" (paper Eq. 24) or "hertz" (Eq. 12).
    fs: sample rate, Hz. duration: seconds; n_samples = round(duration fs).
    snr_db: signal-to-noise ratio of the white Gaussian noise, dB, or None for
        none. The noise has the same std on all four channels,
        sigma = sqrt(P_ref) 10^(-snr_db / 20), P_ref the larger of the mean
        powers mean(p^2) of the two shallow channels x1, y1 after their gains.
    gains: per-probe gains [x1, x2, y1, y2], applied before the noise.
    dc_offset: per-channel constant added after the noise.
    clip: symmetric clipping level applied last (after gain, noise, offset).
    sensor: probe depths and curvature radius.
    seed: seeds the texture and (independently) the noise.
    grid_spacing: target grid step D_t, m (the step used is in ``truth``).
    """

    texture: object = RandomTexture()
    velocity: tuple[float, float] = (0.023, 0.0)
    contact_radius: float | None = 3.0e-3
    contact_depth: float | None = None
    window: str = "gaussian"
    fs: float = 1000.0
    duration: float = 16.0
    snr_db: float | None = 50.0
    gains: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    dc_offset: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)
    clip: float | None = None
    sensor: Sensor = PAPER_SENSOR
    seed: int = 0
    grid_spacing: float = 25e-6

    @property
    def a(self) -> float:
        """Resolved contact radius, m."""
        has_r, has_d = self.contact_radius is not None, self.contact_depth is not None
        if has_r == has_d:
            raise _bad("give exactly one of contact_radius and contact_depth"
                       f" (got contact_radius={self.contact_radius!r}, contact_depth={self.contact_depth!r})")
        if has_r:
            a = _number("contact_radius", self.contact_radius)
            if a <= 0:
                raise _bad(f"contact_radius must be positive, got {self.contact_radius!r}")
            return a
        d = _number("contact_depth", self.contact_depth)
        if d <= 0:
            raise _bad(f"contact_depth must be positive, got {self.contact_depth!r}")
        return math.sqrt(float(self.sensor.curvature_radius) * d)

    @property
    def n_samples(self) -> int:
        """Number of samples, round(duration fs)."""
        return int(round(float(self.duration) * float(self.fs)))


def _number(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise _bad(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v):
        raise _bad(f"{name} must be finite, got {value!r}")
    return v


def _vector(name: str, value, n: int) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=float).ravel()
    except (TypeError, ValueError):
        raise _bad(f"{name} must be {n} numbers, got {value!r}") from None
    if v.shape != (n,):
        raise _bad(f"{name} must have {n} entries, got {len(v)}")
    if not np.all(np.isfinite(v)):
        raise _bad(f"{name} must be finite, got {v.tolist()}")
    return v


@dataclasses.dataclass(frozen=True)
class _Plan:
    """Validated geometry of one simulation (all lengths in metres)."""

    vx: float
    vy: float
    speed: float
    slip_angle: float
    a: float
    window: str
    d1: float
    d2: float
    fs: float
    n: int                 # samples
    m: int                 # cells per sample (numerator)
    q: int                 # samples per cell (denominator); one of m, q is 1
    D: float               # grid step
    c: int                 # patch half-width, cells; patch is P = 2c + 1 cells square
    path: int              # S: ceil((n - 1) m / q), cells
    margin: int            # extra cells at both ends of the path
    nfft: int

    @property
    def P(self) -> int:
        return 2 * self.c + 1

    @property
    def L(self) -> int:
        return self.P + self.path + 2 * self.margin


def _plan(scene: Scene) -> _Plan:
    import scipy.fft  # here, not at import: importing scipy.fft takes about 0.5 s

    vx, vy = _vector("velocity", scene.velocity, 2)
    speed = math.hypot(vx, vy)
    if speed == 0:
        raise _bad("velocity must be non-zero (the texture must slide)")
    fs = _number("fs", scene.fs)
    if fs <= 0:
        raise _bad(f"fs must be positive, got {scene.fs!r}")
    duration = _number("duration", scene.duration)
    if duration <= 0:
        raise _bad(f"duration must be positive, got {scene.duration!r}")
    n = scene.n_samples
    if n < 2:
        raise _bad(f"duration {duration} s at fs {fs} Hz gives {n} samples; need at least 2")
    a = scene.a
    if scene.window not in WINDOWS:
        raise _bad(f"window must be one of {', '.join(WINDOWS)}, got {scene.window!r}")
    d1, d2 = float(scene.sensor.d1), float(scene.sensor.d2)
    if not (0 < d1 < d2) or not math.isfinite(d2):
        raise _bad(f"sensor depths must satisfy 0 < d1 < d2, got d1={d1}, d2={d2}")
    _number("sensor.curvature_radius", scene.sensor.curvature_radius)
    _vector("gains", scene.gains, 4)
    _vector("dc_offset", scene.dc_offset, 4)
    if scene.snr_db is not None:
        _number("snr_db", scene.snr_db)
    if scene.clip is not None and _number("clip", scene.clip) <= 0:
        raise _bad(f"clip must be positive or None, got {scene.clip!r}")
    dt = _number("grid_spacing", scene.grid_spacing)
    if dt <= 0:
        raise _bad(f"grid_spacing must be positive, got {scene.grid_spacing!r}")
    if dt > 0.5 * d1:
        raise _bad(f"grid_spacing {dt} m must be at most d1 / 2 = {0.5 * d1} m to resolve the depth kernel")

    delta = speed / fs
    if delta >= dt:
        m, q = int(math.ceil(delta / dt * (1.0 - 1e-12))), 1
        D = delta / m
    else:
        m, q = 1, max(1, int(math.floor(dt / delta * (1.0 + 1e-12))))
        D = q * delta
    half = (_GAUSSIAN_TRUNCATION if scene.window == "gaussian" else 1.0) * a
    c = int(math.ceil(half / D))
    path = int(math.ceil((n - 1) * m / q - 1e-9))
    margin = 0 if q == 1 else _INTERP_MARGIN
    P = 2 * c + 1
    L = P + path + 2 * margin
    if P * L > MAX_GRID_CELLS:
        raise _bad(f"scene needs a {P} x {L} texture grid (> {MAX_GRID_CELLS} cells);"
                   " shorten the duration, shrink the contact or raise grid_spacing")
    nfft = scipy.fft.next_fast_len(L, real=True)
    return _Plan(vx=float(vx), vy=float(vy), speed=speed, slip_angle=math.atan2(vy, vx), a=a,
                 window=scene.window, d1=d1, d2=d2, fs=fs, n=n, m=m, q=q, D=D, c=c, path=path,
                 margin=margin, nfft=nfft)


def _window_np(x, y, a, kind):
    """numpy copy of ``window.gaussian_window`` / ``window.hertz_window`` (x, y, a in m)."""
    r2 = (np.square(x) + np.square(y)) / (a * a)
    if kind == "gaussian":
        return np.exp(-1.5 * r2)
    return np.sqrt(np.clip(1.0 - r2, 0.0, None))


def _poisson_np(x, depth):
    """numpy copy of ``decay.poisson_kernel``: d / (pi (x^2 + d^2)), 1/m."""
    return depth / (np.pi * (np.square(x) + depth * depth))


def _kernel_rows(plan: _Plan, eta):
    """Kernels h_c(xi, eta) D^2 for the rows ``eta`` (m): array (4, len(eta), P)."""
    xi = (np.arange(plan.P) - plan.c) * plan.D
    cs, sn = math.cos(plan.slip_angle), math.sin(plan.slip_angle)
    x = xi[None, :] * cs - eta[:, None] * sn
    y = xi[None, :] * sn + eta[:, None] * cs
    w = _window_np(x, y, plan.a, plan.window)
    if plan.window == "gaussian":
        w[np.square(x) + np.square(y) > (_GAUSSIAN_TRUNCATION * plan.a) ** 2] = 0.0
    w *= plan.D * plan.D
    out = np.empty((4,) + w.shape)
    for ch, (coord, d) in enumerate(((x, plan.d1), (x, plan.d2), (y, plan.d1), (y, plan.d2))):
        np.multiply(_poisson_np(coord, d), w, out=out[ch])
    return out


def _read_shifts(acc: np.ndarray, plan: _Plan) -> np.ndarray:
    """Correlations (4, F) in the frequency domain -> probe signals (4, n) at shifts s_n."""
    import scipy.fft

    n_idx = np.arange(plan.n)
    nfft, q = plan.nfft, plan.q
    if q == 1:
        corr = scipy.fft.irfft(acc, n=nfft, axis=-1, workers=-1)
        return corr[:, plan.path - n_idx * plan.m]
    acc = acc.copy()
    if nfft % 2 == 0:
        acc[:, -1] *= 0.5          # split the Nyquist term for trigonometric interpolation
    if nfft * q <= _MAX_UPSAMPLED:
        corr = scipy.fft.irfft(acc, n=nfft * q, axis=-1, workers=-1) * q
        return corr[:, q * (plan.path + plan.margin) - n_idx]
    # Very slow slips: evaluate the trigonometric interpolant directly at the shifts.
    shifts = (plan.path + plan.margin) - n_idx / q
    f = np.arange(acc.shape[-1])
    wts = np.full(f.size, 2.0)
    wts[0] = 1.0
    if nfft % 2 == 0:
        wts[-1] = 2.0              # already halved above: cos(pi s) term counts as 2 * (C / 2)
    out = np.empty((4, plan.n))
    step = max(1, (1 << 21) // f.size)
    for i0 in range(0, plan.n, step):
        ph = np.exp(2j * np.pi * np.outer(shifts[i0:i0 + step], f) / nfft)
        out[:, i0:i0 + step] = np.real((acc * wts) @ ph.T) / nfft
    return out


def probe_signals(scene: Scene, rng=None) -> tuple[np.ndarray, float]:
    """Noiseless probe signals (4, n), metres x u0, and the grid step used (m).

    ``rng`` (numpy Generator) draws a random texture; default: from ``scene.seed``
    as :func:`simulate` does.
    """
    import scipy.fft

    plan = _plan(scene)
    if rng is None:
        rng = _rngs(scene.seed)[0]
    xi_strip = (np.arange(plan.L) - (plan.c + plan.path + plan.margin)) * plan.D
    eta_rows = (np.arange(plan.P) - plan.c) * plan.D
    strip = None
    if not hasattr(scene.texture, "field"):
        strip = texture_field(scene.texture, xi_strip, eta_rows, plan.slip_angle, rng)
    F = plan.nfft // 2 + 1
    acc = np.zeros((4, F), dtype=complex)
    chunk = max(1, int(1_500_000 // plan.nfft))   # ~60 MB of row spectra per chunk
    for j0 in range(0, plan.P, chunk):
        j1 = min(plan.P, j0 + chunk)
        eta = eta_rows[j0:j1]
        U = strip[j0:j1] if strip is not None else texture_field(scene.texture, xi_strip, eta, plan.slip_angle)
        Uf = scipy.fft.rfft(U, n=plan.nfft, axis=-1, workers=-1)
        del U
        Hf = scipy.fft.rfft(_kernel_rows(plan, eta), n=plan.nfft, axis=-1, workers=-1)
        np.conj(Hf, out=Hf)
        for ch in range(4):
            acc[ch] += np.einsum("jf,jf->f", Uf, Hf[ch])
        del Uf, Hf
    del strip
    return _read_shifts(acc, plan), plan.D


def _rngs(seed):
    texture_seq, noise_seq = np.random.SeedSequence(int(seed)).spawn(2)
    return np.random.default_rng(texture_seq), np.random.default_rng(noise_seq)


def simulate(scene: Scene) -> Recording:
    """Simulate ``scene``: a Recording with signals (4, n) float64 and the scene in ``truth``.

    The recording carries depths (d1, d2) and the curvature radius; velocity
    and gain_ratio are left None (the arm does not know them unless told).
    ``truth`` (JSON-serialisable) holds vx, vy, a, contact_depth (a^2 / R),
    window, gains, gain_ratio_x = g_x2 / g_x1, gain_ratio_y = g_y2 / g_y1,
    snr_db, noise_std, dc_offset, clip, fs, duration, n_samples, texture
    (name and parameters), seed, grid_spacing (the step used, m), depths and
    curvature_radius. Raises ``TactileInputError`` (code "bad_setting") for a
    bad scene.
    """
    plan = _plan(scene)
    rng_texture, rng_noise = _rngs(scene.seed)
    clean, D = probe_signals(scene, rng_texture)
    gains = _vector("gains", scene.gains, 4)
    sig = clean * gains[:, None]
    noise_std = 0.0
    if scene.snr_db is not None:
        p_ref = max(float(np.mean(np.square(sig[0]))), float(np.mean(np.square(sig[2]))))
        noise_std = math.sqrt(p_ref) * 10.0 ** (-float(scene.snr_db) / 20.0)
        sig = sig + noise_std * rng_noise.standard_normal(sig.shape)
    sig = sig + _vector("dc_offset", scene.dc_offset, 4)[:, None]
    if scene.clip is not None:
        sig = np.clip(sig, -float(scene.clip), float(scene.clip))
    R = float(scene.sensor.curvature_radius)
    truth = {
        "vx": plan.vx,
        "vy": plan.vy,
        "a": plan.a,
        "contact_depth": plan.a * plan.a / R,
        "window": plan.window,
        "gains": [float(g) for g in gains],
        "gain_ratio_x": float(gains[1] / gains[0]) if gains[0] != 0 else None,
        "gain_ratio_y": float(gains[3] / gains[2]) if gains[2] != 0 else None,
        "snr_db": None if scene.snr_db is None else float(scene.snr_db),
        "noise_std": noise_std,
        "dc_offset": [float(o) for o in scene.dc_offset],
        "clip": None if scene.clip is None else float(scene.clip),
        "fs": plan.fs,
        "duration": float(scene.duration),
        "n_samples": plan.n,
        "texture": describe_texture(scene.texture),
        "seed": int(scene.seed),
        "grid_spacing": D,
        "depths": [plan.d1, plan.d2],
        "curvature_radius": R,
    }
    return Recording(
        signals=np.ascontiguousarray(sig, dtype=np.float64),
        fs=plan.fs,
        depths=(plan.d1, plan.d2),
        curvature_radius=R,
        velocity=None,
        gain_ratio=None,
        truth=truth,
        source=f"simulate(seed={int(scene.seed)})",
    )
