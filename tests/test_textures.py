"""DirectionalTexture, StretchedTexture and ModeTexture: spectra, variance, rotation into the slip frame, scenes, recipes."""

import json
import math

import numpy as np
import pytest

import tactile_jax as tj
from tactile_jax.errors import TactileInputError
from tactile_jax.io.recipes import load_recipe, scene_from_recipe
from tactile_jax.simulation.scene import Scene, simulate
from tactile_jax.simulation.texture import (
    DirectionalTexture,
    ModeTexture,
    RandomTexture,
    StretchedTexture,
    describe_texture,
    texture_field,
)

N_GRID = 512
STEP = 1e-4          # 100 um: 51 mm square, Nyquist 31 rad/mm, at the 0.2 mm cut-off


def lobe(power):
    """(anisotropy, angle) of a 2-D power spectrum on the N_GRID fft grid, from its cos 2theta moment.

    For power Phi(|k|) (1 + c cos 2(theta - theta0)), sum P e^{2i theta} / sum P = (c / 2) e^{2i theta0}
    (the square grid makes sum f(|k|) e^{2i theta} vanish).
    """
    k = np.fft.fftfreq(N_GRID)
    z = (k[None, :] + 1j * k[:, None]) ** 2
    mag = np.abs(z)
    w = np.where(mag > 0, z / np.where(mag > 0, mag, 1.0), 0.0)
    m2 = np.sum(power * w) / np.sum(power)
    c = 2.0 * abs(m2)
    return (1.0 + c) / (1.0 - c), 0.5 * np.angle(m2)


def averaged_power(tex, slip_angle, seeds=range(4)):
    xi = np.arange(N_GRID) * STEP
    fields = [texture_field(tex, xi, xi, slip_angle, np.random.default_rng(s)) for s in seeds]
    return sum(np.abs(np.fft.fft2(u)) ** 2 for u in fields), fields


def angle_diff(a, b):
    """Difference of two axial angles (mod pi), in [-pi/2, pi/2)."""
    return (a - b + 0.5 * np.pi) % np.pi - 0.5 * np.pi


def test_directional_spectrum_has_the_anisotropy_along_its_angle_and_variance_rms2():
    tex = DirectionalTexture(rms=2.0, anisotropy=3.0, angle=0.5)
    power, fields = averaged_power(tex, 0.0)
    ratio, theta = lobe(power)
    assert ratio == pytest.approx(3.0, rel=0.25)
    assert abs(angle_diff(theta, 0.5)) < 0.1
    assert np.mean([u.var() for u in fields]) == pytest.approx(4.0, rel=0.1)
    assert all(abs(u.mean()) < 0.5 for u in fields)


@pytest.mark.parametrize("theta0, phi", [(0.0, 0.6), (1.2, -0.4)])
def test_directional_texture_is_turned_into_the_slip_frame(theta0, phi):
    power, _ = averaged_power(DirectionalTexture(angle=theta0, anisotropy=4.0), phi)
    ratio, theta = lobe(power)
    assert abs(angle_diff(theta, theta0 - phi)) < 0.1
    assert ratio == pytest.approx(4.0, rel=0.25)


def test_random_texture_output_is_unchanged_for_a_fixed_rng():
    xi, eta = np.arange(300) * 25e-6, np.arange(70) * 30e-6
    tex = RandomTexture(rms=0.7, correlation_length=1.3e-3)
    got = texture_field(tex, xi, eta, 0.3, np.random.default_rng(1))
    old = tex.sample((70, 300), (30e-6, 25e-6), np.random.default_rng(1))   # the old code path
    np.testing.assert_array_equal(got, old)


def test_directional_spectrum_is_the_radial_one_times_the_lobe():
    kx, ky = np.array([0.0, 800.0, 0.0, 3000.0, 2000.0]), np.array([0.0, 0.0, 800.0, 3000.0, -500.0])
    radial = RandomTexture().power_spectrum(np.hypot(kx, ky))
    np.testing.assert_allclose(DirectionalTexture(anisotropy=1.0).power_spectrum(kx, ky), radial, rtol=1e-14)
    d = DirectionalTexture(anisotropy=3.0, angle=0.0).power_spectrum(kx, ky)
    assert d[1] / d[2] == pytest.approx(3.0) and d[3] == pytest.approx(radial[3])
    xi = np.arange(200) * 25e-6
    assert texture_field(DirectionalTexture(), xi, xi[:50], 0.2, np.random.default_rng(0)).shape == (50, 200)


def test_stretched_spectrum_is_the_radial_one_at_the_stretched_wavenumber():
    kx, ky = np.array([0.0, 800.0, 0.0, 3000.0, 2e4]), np.array([0.0, 0.0, 800.0, 3000.0, -500.0])
    radial = RandomTexture().power_spectrum
    np.testing.assert_allclose(StretchedTexture(aspect=1.0).power_spectrum(kx, ky), radial(np.hypot(kx, ky)),
                               rtol=1e-14)
    # ridges across x: along x the radial spectrum, along y the radial one at aspect |k|
    tex = StretchedTexture(aspect=3.0, angle=0.0, smallest_scale=1e-9)
    k = np.array([20.0, 2e5])
    along, across = tex.power_spectrum(k, 0 * k), tex.power_spectrum(0 * k, k)
    fine = RandomTexture(smallest_scale=1e-9).power_spectrum
    np.testing.assert_allclose(along, fine(k), rtol=1e-14)
    np.testing.assert_allclose(across, fine(3.0 * k), rtol=1e-14)
    assert along[0] / across[0] == pytest.approx(1.0, rel=0.03)       # k l << 1: no lobe
    assert along[1] / across[1] == pytest.approx(27.0, rel=1e-3)      # k l >> 1: aspect^3
    turned = StretchedTexture(aspect=3.0, angle=np.pi / 2, smallest_scale=1e-9)
    np.testing.assert_allclose(turned.power_spectrum(0 * k, k), along, rtol=1e-12)


@pytest.mark.parametrize("phi", [0.0, 0.9])
def test_stretched_texture_has_rms2_and_its_lobe_along_its_angle_in_the_slip_frame(phi):
    power, fields = averaged_power(StretchedTexture(rms=2.0, aspect=2.5, angle=0.4), phi)
    ratio, theta = lobe(power)
    assert abs(angle_diff(theta, 0.4 - phi)) < 0.1
    assert ratio > 3.0
    assert np.mean([u.var() for u in fields]) == pytest.approx(4.0, rel=0.15)


@pytest.mark.parametrize("cls, kwargs, field", [
    (StretchedTexture, {"aspect": 0.5}, "aspect"),
    (StretchedTexture, {"angle": math.nan}, "angle"),
    (DirectionalTexture, {"anisotropy": 0.5}, "anisotropy"),
    (DirectionalTexture, {"angle": math.nan}, "angle"),
    (DirectionalTexture, {"angle": math.inf}, "angle"),
    (DirectionalTexture, {"rms": -1.0}, "rms"),
    (ModeTexture, {"anisotropy": 0.9}, "anisotropy"),
    (ModeTexture, {"angle": math.nan}, "angle"),
    (ModeTexture, {"n_modes": 0}, "n_modes"),
    (ModeTexture, {"n_modes": 2.5}, "n_modes"),
    (ModeTexture, {"seed": -1}, "seed"),
    (ModeTexture, {"smallest_scale": 0.0}, "smallest_scale"),
])
def test_bad_settings_are_one_line_errors_naming_the_field(cls, kwargs, field):
    with pytest.raises(TactileInputError, match=f"{cls.__name__}.{field}") as err:
        cls(**kwargs)
    assert err.value.code == "bad_setting" and "\n" not in str(err.value)


def test_mode_texture_variance_is_exact():
    tex = ModeTexture(rms=1.5, n_modes=64, seed=3)
    kvec, amp, phase = tex.modes
    assert kvec.shape == (64, 2) and amp.shape == phase.shape == (64,)
    assert np.sum(amp ** 2) / 2 == pytest.approx(1.5 ** 2, rel=1e-12)
    pts = np.random.default_rng(0).uniform(-0.5, 0.5, (2, 200_000))
    assert np.mean(tex.field(pts[0], pts[1]) ** 2) == pytest.approx(1.5 ** 2, rel=0.03)


def test_mode_texture_field_is_the_sum_of_its_modes_and_broadcasts():
    tex = ModeTexture(n_modes=40, seed=5, anisotropy=2.0, angle=0.3)
    kvec, amp, phase = tex.modes
    x = np.array([0.0, 1.3e-3, -4e-3, 0.2])
    y = np.array([0.0, 2.2e-3, 7e-4, -0.1])
    explicit = [sum(amp[j] * math.cos(kvec[j, 0] * xi + kvec[j, 1] * yi + phase[j]) for j in range(40))
                for xi, yi in zip(x, y)]
    np.testing.assert_allclose(tex.field(x, y), explicit, rtol=1e-9, atol=1e-12)
    grid = tex.field(x[None, :], y[:, None])
    assert grid.shape == (4, 4)
    np.testing.assert_allclose(np.diag(grid), explicit, rtol=1e-9, atol=1e-12)
    # texture_field evaluates it in the object frame at any slip angle
    xi, eta = np.array([1e-3, 2e-3]), np.array([0.0, 5e-4])
    c, s = math.cos(0.7), math.sin(0.7)
    u = texture_field(tex, xi, eta, 0.7)
    assert u[1, 0] == pytest.approx(float(tex.field(1e-3 * c - 5e-4 * s, 1e-3 * s + 5e-4 * c)), rel=1e-12)


def test_mode_texture_on_a_rotated_grid_is_its_pointwise_field():
    tex = ModeTexture(n_modes=50, anisotropy=2.0, angle=0.3)
    xi, eta, phi = np.linspace(0.0, 3e-3, 90), np.linspace(-1e-3, 1e-3, 41), 0.7
    x = xi[None, :] * math.cos(phi) - eta[:, None] * math.sin(phi)
    y = xi[None, :] * math.sin(phi) + eta[:, None] * math.cos(phi)
    grid = texture_field(tex, xi, eta, phi)
    assert grid.shape == (41, 90)
    assert np.allclose(grid, tex.field(x, y), rtol=0, atol=1e-12)


def test_mode_texture_follows_the_radial_spectrum_and_anisotropy():
    tex = ModeTexture(n_modes=2000, anisotropy=3.0, angle=0.4)
    kvec = tex.modes[0]
    k = np.hypot(kvec[:, 0], kvec[:, 1])
    # without the cut-off the radial power fraction below K is 1 - (1 + K^2 l^2)^(-1/2): half below sqrt(3) / l
    assert np.median(k) == pytest.approx(math.sqrt(3.0) / 1e-3, rel=0.1)
    z = np.mean(((kvec[:, 0] + 1j * kvec[:, 1]) / k) ** 2)
    c = 2 * abs(z)
    assert (1 + c) / (1 - c) == pytest.approx(3.0, rel=0.05)
    assert abs(angle_diff(0.5 * np.angle(z), 0.4)) < 0.02


def test_mode_texture_is_deterministic_by_seed_and_describes_small():
    a, b, c = ModeTexture(n_modes=30, seed=7), ModeTexture(n_modes=30, seed=7), ModeTexture(n_modes=30, seed=8)
    x, y = np.linspace(0, 0.01, 50), np.linspace(-0.01, 0, 50)
    np.testing.assert_array_equal(a.field(x, y), b.field(x, y))
    assert not np.allclose(a.field(x, y), c.field(x, y))
    assert a == b and a != c
    d = describe_texture(ModeTexture())
    assert d == {"name": "ModeTexture", "rms": 1.0, "correlation_length": 1e-3, "smallest_scale": 0.2e-3,
                 "n_modes": 300, "seed": 0, "anisotropy": 1.0, "angle": 0.0}
    assert len(json.dumps(d)) < 300
    assert json.loads(json.dumps(describe_texture(DirectionalTexture())))["anisotropy"] == 3.0
    assert tj.ModeTexture is ModeTexture and tj.DirectionalTexture is DirectionalTexture


@pytest.mark.parametrize("tex", [DirectionalTexture(angle=0.8), StretchedTexture(angle=0.8), ModeTexture(n_modes=64)],
                         ids=["directional", "stretched", "modes"])
def test_new_textures_run_through_a_scene(tex):
    rec = simulate(Scene(texture=tex, velocity=(0.02, 0.015), contact_radius=1.5e-3, fs=1000.0, duration=0.3,
                         snr_db=None))
    sig = rec.signals
    assert sig.shape == (4, 300) and np.all(np.isfinite(sig))
    rms = np.sqrt(np.mean(np.square(sig - sig.mean(axis=1, keepdims=True)), axis=1))
    assert rms[1] < rms[0] and rms[3] < rms[2]
    assert rms.min() > 0
    json.dumps(rec.truth)
    assert rec.truth["texture"]["name"] == type(tex).__name__


def test_recipe_with_a_mode_texture_loads(tmp_path):
    path = tmp_path / "modes.toml"
    path.write_text('description = "plane-wave texture"\n'
                    "[simulate]\nvelocity = [0.02, 0.015]\ncontact_radius = 1.5e-3\nduration = 0.3\n"
                    '[simulate.texture]\nname = "ModeTexture"\nn_modes = 50\nseed = 2\nanisotropy = 2.0\n')
    scene = scene_from_recipe(load_recipe(path))
    assert scene.texture == ModeTexture(n_modes=50, seed=2, anisotropy=2.0)
    path.write_text('[simulate]\nvelocity = [0.02, 0.0]\n[simulate.texture]\nname = "DirectionalTexture"\nangle = 0.3\n')
    assert scene_from_recipe(load_recipe(path)).texture == DirectionalTexture(angle=0.3)
    path.write_text('[simulate]\nvelocity = [0.02, 0.0]\n[simulate.texture]\nname = "StretchedTexture"\naspect = 2.5\n')
    assert scene_from_recipe(load_recipe(path)).texture == StretchedTexture(aspect=2.5)
    path.write_text('[simulate]\nvelocity = [0.02, 0.0]\n[simulate.texture]\nname = "Foam"\n')
    with pytest.raises(TactileInputError, match="ModeTexture"):
        scene_from_recipe(load_recipe(path))
