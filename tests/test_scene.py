"""Scene simulator: shapes, seeding, noise, gains, and the physics against independent references.

The physics checks compare the space-domain simulator with references
computed differently: 1-D quadrature of the kernel times the window for a
single mode, the quadrature line response of ``window`` for Hertz, a finer
grid for the fractional-shift path, and the arrival time of a ridge for the
direction convention.
"""

from __future__ import annotations

import dataclasses
import json
import math

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.integrate
import scipy.signal

import tactile_jax.simulation.scene as sim
from tactile_jax.model.decay import poisson_kernel
from tactile_jax.errors import TactileInputError
from tactile_jax.io.recording import Recording, validate_recording
from tactile_jax.model.sensor import PAPER_SENSOR
from tactile_jax.simulation.scene import Scene, probe_signals, simulate
from tactile_jax.simulation.texture import Grating, RandomTexture, WireNet, texture_field
from tactile_jax.model.window import gaussian_window, hertz_line_response, hertz_window

D1, D2 = PAPER_SENSOR.d1, PAPER_SENSOR.d2
EPS = D2 - D1


def _short(**kw) -> Scene:
    base = dict(duration=1.0, fs=500.0)
    base.update(kw)
    return Scene(**base)


def _sine_amplitudes(signals, fs, omega):
    """Least-squares amplitude of cos/sin at ``omega`` (rad/s) plus a constant, and the residual rms."""
    t = np.arange(signals.shape[-1]) / fs
    basis = np.stack([np.cos(omega * t), np.sin(omega * t), np.ones_like(t)], axis=1)
    coef, *_ = np.linalg.lstsq(basis, signals.T, rcond=None)
    resid = signals.T - basis @ coef
    return np.hypot(coef[0], coef[1]), np.sqrt(np.mean(resid ** 2, axis=0))


@dataclasses.dataclass(frozen=True)
class Ridge:
    """A straight Gaussian ridge at x = x0 (axis 'x') or y = y0 (axis 'y'), metres."""

    at: float
    axis: str = "x"
    width: float = 0.3e-3

    def field(self, x, y):
        s = np.asarray(x if self.axis == "x" else y)
        return np.exp(-0.5 * ((s - self.at) / self.width) ** 2) + 0.0 * (np.asarray(x) + np.asarray(y))


# ---------------------------------------------------------------- contract and bookkeeping

def test_shapes_dtype_and_metadata():
    rec = simulate(_short())
    assert isinstance(rec, Recording)
    assert rec.signals.shape == (4, 500) and rec.signals.dtype == np.float64
    assert np.all(np.isfinite(rec.signals))
    validate_recording(rec)
    assert rec.fs == 500.0
    assert rec.depths == (D1, D2)
    assert rec.curvature_radius == PAPER_SENSOR.curvature_radius
    assert rec.velocity is None and rec.gain_ratio is None
    truth = json.loads(json.dumps(rec.truth))       # JSON-serialisable
    for key in ("vx", "vy", "a", "contact_depth", "window", "gains", "snr_db", "noise_std", "fs",
                "duration", "texture", "seed", "gain_ratio_x", "gain_ratio_y"):
        assert key in truth
    assert truth["vx"] == 0.023 and truth["vy"] == 0.0 and truth["a"] == 3e-3
    assert truth["texture"]["name"] == "RandomTexture"
    assert truth["texture"]["correlation_length"] == 1e-3
    assert math.isclose(truth["contact_depth"], 3e-3 ** 2 / 30e-3)


def test_seeding():
    a = simulate(_short(seed=3)).signals
    b = simulate(_short(seed=3)).signals
    c = simulate(_short(seed=4)).signals
    np.testing.assert_array_equal(a, b)
    assert np.max(np.abs(a - c)) > 0.1 * np.std(a)


def test_noise_level_matches_snr():
    clean = simulate(_short(snr_db=None, seed=7))
    noisy = simulate(_short(snr_db=20.0, seed=7))
    assert clean.truth["noise_std"] == 0.0
    p_ref = max(np.mean(clean.signals[0] ** 2), np.mean(clean.signals[2] ** 2))
    expected = math.sqrt(p_ref) * 10 ** (-20.0 / 20)
    assert math.isclose(noisy.truth["noise_std"], expected, rel_tol=1e-12)
    noise = noisy.signals - clean.signals           # texture and noise draw from separate streams
    measured = noise.std(axis=1)
    np.testing.assert_allclose(measured, expected, rtol=0.1)   # 500 samples: ~3% sd
    assert abs(np.corrcoef(noise[0], noise[1])[0, 1]) < 0.2


def test_gains_offset_and_clip():
    g = (2.0, 0.5, 1.5, 3.0)
    base = simulate(_short(snr_db=None))
    gained = simulate(_short(snr_db=None, gains=g))
    np.testing.assert_allclose(gained.signals, base.signals * np.array(g)[:, None], rtol=1e-12)
    assert gained.truth["gain_ratio_x"] == 0.25 and gained.truth["gain_ratio_y"] == 2.0
    # gains act before the noise: the noise level follows the gained shallow channels
    noisy = simulate(_short(snr_db=30.0, gains=g))
    p_ref = max(np.mean(gained.signals[0] ** 2), np.mean(gained.signals[2] ** 2))
    assert math.isclose(noisy.truth["noise_std"], math.sqrt(p_ref) * 10 ** -1.5, rel_tol=1e-12)
    off = (1e-3, -2e-3, 0.0, 5e-4)
    shifted = simulate(_short(snr_db=None, dc_offset=off))
    np.testing.assert_allclose(shifted.signals - base.signals, np.broadcast_to(np.array(off)[:, None], (4, 500)),
                               atol=1e-15)
    level = 0.5 * np.abs(base.signals).max()
    clipped = simulate(_short(snr_db=None, clip=level))
    assert np.abs(clipped.signals).max() <= level
    np.testing.assert_array_equal(clipped.signals, np.clip(base.signals, -level, level))


def test_contact_depth_gives_hertz_radius():
    depth = 0.16e-3
    sc = _short(contact_radius=None, contact_depth=depth, snr_db=None)
    a = math.sqrt(PAPER_SENSOR.curvature_radius * depth)
    assert math.isclose(sc.a, a)
    rec = simulate(sc)
    assert math.isclose(rec.truth["a"], a) and math.isclose(rec.truth["contact_depth"], depth)
    same = simulate(_short(contact_radius=a, snr_db=None))
    np.testing.assert_allclose(rec.signals, same.signals, rtol=1e-12, atol=0)


def test_numpy_windows_match_library():
    x = np.linspace(-4e-3, 4e-3, 41)[:, None]
    y = np.linspace(-3e-3, 3e-3, 31)[None, :]
    a = 2.5e-3
    np.testing.assert_allclose(sim._window_np(x, y, a, "gaussian"), np.asarray(gaussian_window(x, y, a)),
                               rtol=1e-13)
    np.testing.assert_allclose(sim._window_np(x, y, a, "hertz"), np.asarray(hertz_window(x, y, a)), atol=1e-15)
    np.testing.assert_allclose(sim._poisson_np(x, D1), np.asarray(poisson_kernel(jnp.asarray(x), D1)), rtol=1e-13)


# ---------------------------------------------------------------- physics

def test_sine_grating_large_contact():
    """Single mode, a = 8 mm: pure sinusoids at k|v|; amplitudes match 1-D quadrature; ratio ~ exp(-k eps)."""
    grating = Grating(pitch=1.5e-3, profile="sine")
    k, v, a = grating.wavenumber, 0.025, 8e-3
    rec = simulate(Scene(texture=grating, velocity=(v, 0.0), contact_radius=a, fs=1000.0, duration=1.0,
                         snr_db=None, grid_spacing=25e-6))
    omega = k * v
    amp, resid = _sine_amplitudes(rec.signals, rec.fs, omega)
    assert np.all(resid[:2] < 1e-9 * amp[:2])          # a pure sinusoid at omega = k |v|
    spec = np.abs(np.fft.rfft(rec.signals[0] * np.hanning(rec.n_samples)))
    f_peak = np.fft.rfftfreq(rec.n_samples, 1 / rec.fs)[np.argmax(spec)]
    assert abs(2 * np.pi * f_peak - omega) <= 2 * np.pi * 1.0   # within one 1 Hz bin
    # the y probes see no texture motion for a mode along x
    assert np.all(amp[2:] < 1e-9 * amp[0])

    def line_response(d):
        # x-probe response to cos(k x) under the Gaussian window, by 1-D quadrature in x
        f = lambda x: d / (np.pi * (x * x + d * d)) * np.exp(-1.5 * x * x / a ** 2) * np.cos(k * x)
        return a * math.sqrt(2 * math.pi / 3) * 2 * scipy.integrate.quad(f, 0, 6 * a, limit=800,
                                                                         points=[d, 3 * d, 10 * d])[0]

    np.testing.assert_allclose(amp[:2], [line_response(D1), line_response(D2)], rtol=1e-6)
    ratio = amp[1] / amp[0]
    # window correction for a = 8 mm: exp(3 (d2^2 - d1^2) / (2 a^2)) = 1.0186
    assert abs(ratio / math.exp(-k * EPS) - 1.0) < 0.025
    assert abs(ratio / math.exp(-k * EPS + 1.5 * (D2 ** 2 - D1 ** 2) / a ** 2) - 1.0) < 1e-3


def test_hertz_window_matches_line_response():
    grating = Grating(pitch=1.5e-3)
    k, v, a = grating.wavenumber, 0.025, 3e-3
    rec = simulate(Scene(texture=grating, velocity=(v, 0.0), contact_radius=a, window="hertz", fs=1000.0,
                         duration=0.5, snr_db=None))
    assert np.all(np.isfinite(rec.signals))
    amp, _ = _sine_amplitudes(rec.signals, rec.fs, k * v)
    ref = np.array([float(hertz_line_response(k, 0.0, d, a)) for d in (D1, D2)])
    np.testing.assert_allclose(amp[:2], ref, rtol=3e-3)   # the disk edge is point-sampled


@pytest.mark.parametrize("axis,speed", [("x", 0.01), ("x", -0.01), ("y", 0.01)])
def test_direction_convention(axis, speed):
    """The field at time t is u0(r - v t): a ridge at -v t* reaches the probe line at t*."""
    t_star = 0.5
    ridge = Ridge(at=-speed * t_star, axis=axis)
    velocity = (speed, 0.0) if axis == "x" else (0.0, speed)
    rec = simulate(Scene(texture=ridge, velocity=velocity, contact_radius=2e-3, fs=200.0, duration=1.0,
                         snr_db=None))
    ch = 0 if axis == "x" else 2
    t = np.arange(rec.n_samples) / rec.fs
    assert abs(t[np.argmax(rec.signals[ch])] - t_star) <= 1.0 / rec.fs
    sig = rec.signals[ch]
    # symmetric kernel: the pulse is symmetric about t*
    i = int(round(t_star * rec.fs))
    np.testing.assert_allclose(sig[i - 50:i], sig[i + 50:i:-1], rtol=1e-9, atol=1e-12 * sig.max())


def test_directional_selectivity_of_grating():
    """Paper Fig. 4: a 1.5 mm grating slid along its wavevector; the x-probe response falls off with angle."""
    v, a = 0.025, 3e-3

    def x1_rms(deg, window):
        th = math.radians(deg)
        sc = Scene(texture=Grating(pitch=1.5e-3, angle=th, profile="pipes"),
                   velocity=(v * math.cos(th), v * math.sin(th)), contact_radius=a, window=window,
                   fs=1000.0, duration=0.5, snr_db=None)
        return probe_signals(sc)[0].std(axis=1)

    g0, g60 = x1_rms(0, "gaussian"), x1_rms(60, "gaussian")
    assert g60[0] < 1e-3 * g0[0]
    h0, h60 = x1_rms(0, "hertz"), x1_rms(60, "hertz")
    assert h60[0] < 0.2 * h0[0]        # the disk's edge leaks more than the Gaussian (about 6% here)


def _pair_speed(p1, p2, fs, speed_guess, kmin=1000.0, kmax=6000.0):
    """Speed from the slope of log|S12 / S11| over k in [kmin, kmax] (rad/m), free intercept."""
    f, s11 = scipy.signal.welch(p1, fs, nperseg=512)
    _, s12 = scipy.signal.csd(p1, p2, fs, nperseg=512)
    w = 2 * np.pi * f
    sel = (w > kmin * speed_guess) & (w < kmax * speed_guess)
    slope = np.polyfit(w[sel], np.log(np.abs(s12[sel]) / s11[sel]), 1)[0]
    return -EPS / slope


def test_oblique_random_slip_pairs_see_their_components():
    v = 0.023
    vx, vy = v * math.cos(math.radians(60)), v * math.sin(math.radians(60))
    rec = simulate(Scene(velocity=(vx, vy), contact_radius=3e-3, fs=250.0, duration=8.0, snr_db=None, seed=1))
    sx = _pair_speed(rec.signals[0], rec.signals[1], rec.fs, vx)
    sy = _pair_speed(rec.signals[2], rec.signals[3], rec.fs, vy)
    # the x pair hears mostly vx (pulled toward vy by the finite window, docs/model.md), not |v|
    assert abs(sx / vx - 1) < 0.2 and sx < 0.75 * v
    assert abs(sy / vy - 1) < 0.1


def test_fractional_shift_path_matches_fine_grid():
    """Slow slip (a sample moves the texture by 1/q cell) against a grid where it moves one whole cell."""
    base = dict(texture=Grating(pitch=1.5e-3, angle=0.3, profile="pipes"), velocity=(0.004, 0.003),
                contact_radius=1e-3, fs=1000.0, duration=0.25, snr_db=None)
    coarse_scene = Scene(grid_spacing=25e-6, **base)
    fine_scene = Scene(grid_spacing=5e-6, **base)
    assert sim._plan(coarse_scene).q == 5 and sim._plan(fine_scene).q == 1
    coarse, _ = probe_signals(coarse_scene)
    fine, _ = probe_signals(fine_scene)
    np.testing.assert_allclose(coarse, fine, atol=1e-6 * np.abs(fine).max())


def test_direct_interpolation_path(monkeypatch):
    sc = Scene(texture=Grating(pitch=1.5e-3, angle=0.3), velocity=(0.002, -0.001), contact_radius=1e-3,
               window="hertz", fs=1000.0, duration=0.25, snr_db=None)
    upsampled, _ = probe_signals(sc)
    monkeypatch.setattr(sim, "_MAX_UPSAMPLED", 0)
    direct, _ = probe_signals(sc)
    np.testing.assert_allclose(direct, upsampled, atol=1e-12 * np.abs(upsampled).max())


def test_wire_net_and_multiple_cells_per_sample():
    """Fast slip (several cells per sample) against a finer grid, with the 2-D wire net."""
    base = dict(texture=WireNet(), velocity=(0.08, -0.06), contact_radius=1e-3, fs=1000.0, duration=0.1,
                snr_db=None)
    coarse, _ = probe_signals(Scene(grid_spacing=25e-6, **base))
    fine, _ = probe_signals(Scene(grid_spacing=10e-6, **base))
    assert sim._plan(Scene(grid_spacing=25e-6, **base)).m == 4
    # AC parts agree (the point-sampled wires leave a small grid-dependent mean)
    ac = lambda s: s - s.mean(axis=1, keepdims=True)
    np.testing.assert_allclose(ac(coarse)[[0, 2]], ac(fine)[[0, 2]], atol=0.02 * np.abs(ac(fine)[0]).max())


# ---------------------------------------------------------------- textures

def test_random_texture_statistics():
    tex = RandomTexture(rms=2.0, correlation_length=0.5e-3, smallest_scale=0.2e-3)
    u = tex.sample((400, 600), 50e-6, np.random.default_rng(0))
    assert u.shape == (400, 600) and u.dtype == np.float64
    assert abs(u.std() / 2.0 - 1) < 0.15
    assert abs(u.mean()) < 0.2
    # exponential covariance: correlation at lag l along x is about exp(-1) (less the cut-off's smoothing)
    lag = 10
    rho = np.mean(u[:, :-lag] * u[:, lag:]) / np.mean(u * u)
    assert 0.25 < rho < 0.5


def test_analytic_textures_zero_mean_and_rotation():
    x = np.linspace(0, 1.5e-3, 3000, endpoint=False)
    assert abs(Grating(pitch=1.5e-3, profile="pipes").field(x, 0 * x).mean()) < 1e-12
    xx, yy = np.meshgrid(np.linspace(0, 0.5e-3, 1000, endpoint=False), np.linspace(0, 0.5e-3, 1000, endpoint=False))
    assert abs(WireNet().field(xx, yy).mean()) < 1e-5
    # texture_field rotates slip-frame coordinates into the object frame
    g = Grating(pitch=1e-3, angle=0.7)
    xi, eta = np.linspace(0, 2e-3, 41), np.linspace(-1e-3, 1e-3, 21)
    u = texture_field(g, xi, eta, slip_angle=0.7)
    np.testing.assert_allclose(u, np.broadcast_to(np.cos(g.wavenumber * xi), (21, 41)), atol=1e-12)


def test_a_periodic_texture_is_band_limited_to_its_grid():
    """On a grid, a grating or net keeps its harmonics up to the grid's Nyquist wavenumber and no others: on a
    fine grid it is the pointwise field (to the Gibbs ripple at a net's kinks); on the scene's grid no harmonic
    folds onto a wavenumber the probes hear, so a net slid along x rings at its own harmonics only."""
    from tactile_jax.simulation.texture import _lattice_modes
    from tactile_jax.spectral.peaks import find_lines

    xi, eta = np.arange(400) * 5e-6, np.arange(300) * 5e-6
    c, s = math.cos(0.7), math.sin(0.7)
    x, y = xi[None, :] * c - eta[:, None] * s, xi[None, :] * s + eta[:, None] * c
    for tex, tol in ((Grating(profile="pipes", angle=0.4), 1e-4), (WireNet(angle=0.3, shear=0.2), 0.04)):
        assert np.abs(texture_field(tex, xi, eta, 0.7) - tex.field(x, y)).max() < tol * np.abs(tex.field(x, y)).max()
    k = 2 * np.pi / 0.5e-3
    kvec, amp, _ = _lattice_modes(k * np.array([1.0, 0.0]), k * np.array([0.0, 1.0]),
                                  lambda u1, u2: np.maximum(np.cos(2 * np.pi * u1), np.cos(2 * np.pi * u2)), 3.5 * k)
    assert np.hypot(*kvec.T).max() <= 3.5 * k and amp.size > 4
    rec = simulate(Scene(texture=WireNet(), velocity=(0.047, 0.0), contact_radius=0.85e-3, duration=4.0,
                         snr_db=45.0, seed=0))
    f = find_lines(np.asarray(rec.signals, float), rec.fs).omega / (2 * np.pi)
    assert f.size >= 1 and np.allclose(f / 94.0, np.round(f / 94.0), atol=0.02)


# ---------------------------------------------------------------- bad settings

@pytest.mark.parametrize("kw", [
    dict(velocity=(0.0, 0.0)),
    dict(velocity=(0.01,)),
    dict(velocity=(float("nan"), 0.0)),
    dict(fs=0.0),
    dict(fs=-100.0),
    dict(duration=0.0),
    dict(duration=-1.0),
    dict(duration=1e-3),                          # one sample
    dict(contact_radius=0.0),
    dict(contact_radius=-1e-3),
    dict(contact_radius=3e-3, contact_depth=1e-4),
    dict(contact_radius=None, contact_depth=None),
    dict(contact_radius=None, contact_depth=-1e-4),
    dict(window="box"),
    dict(gains=(1.0, 1.0, 1.0)),
    dict(dc_offset=(0.0,)),
    dict(clip=0.0),
    dict(grid_spacing=0.0),
    dict(grid_spacing=1e-3),
    dict(contact_radius=0.2, duration=100.0),     # far too large a grid
])
def test_bad_settings_raise(kw):
    with pytest.raises(TactileInputError) as err:
        simulate(_short(**kw))
    assert err.value.code == "bad_setting"
    assert "\n" not in str(err.value)


def test_sheared_wire_net_is_periodic_on_its_lattice_with_zero_mean():
    """A net sheared by 15 deg: its second family's wavevector at angle + 90 deg + shear, so the field repeats
    under the translations T with T . n1 = pitch, T . n2 = 0 (and the reverse), and the mean stays 0."""
    net = WireNet(pitch=1e-3, wire_width=0.2e-3, angle=0.3, shear=math.radians(15.0))
    n1 = np.array([math.cos(0.3), math.sin(0.3)])
    n2 = np.array([-math.sin(0.3 + net.shear), math.cos(0.3 + net.shear)])
    cell = np.linalg.inv(np.stack([n1, n2])) * net.pitch        # columns: the two lattice translations
    rng = np.random.default_rng(0)
    x, y = rng.uniform(-2e-3, 2e-3, (2, 200))
    for t in cell.T:
        np.testing.assert_allclose(net.field(x + t[0], y + t[1]), net.field(x, y), atol=1e-9)
    # off the lattice it does not repeat: a square net's translation is not one of this net's
    square = net.pitch * np.array([-n1[1], n1[0]])
    assert np.abs(net.field(x + square[0], y + square[1]) - net.field(x, y)).max() > 0.1
    xx, yy = np.meshgrid(np.linspace(0, 20e-3, 1500), np.linspace(0, 20e-3, 1500))
    assert abs(net.field(xx, yy).mean()) < 2e-3


@pytest.mark.parametrize("make", [
    lambda: Grating(pitch=0.0),
    lambda: Grating(profile="square"),
    lambda: WireNet(pitch=0.5e-3, wire_width=0.6e-3),
    lambda: WireNet(shear=math.pi / 2),
    lambda: RandomTexture(correlation_length=-1.0),
])
def test_bad_textures_raise(make):
    with pytest.raises(TactileInputError) as err:
        make()
    assert err.value.code == "bad_setting"


def test_unknown_texture_raises():
    with pytest.raises(TactileInputError) as err:
        simulate(_short(texture=object()))
    assert err.value.code == "bad_setting"
