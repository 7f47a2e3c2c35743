"""Spectral estimation: scipy agreement, density scaling, amplitude-ratio errors, bin selection."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.signal as ss
from scipy.signal.windows import dpss

from tactile_jax.errors import TactileInputError
from tactile_jax.spectral.estimate import (
    neighbour_log_ratio_err,
    AmplitudeRatio,
    CrossSpectra,
    amplitude_ratio,
    coherence,
    default_nperseg,
    estimate_spectra,
    multitaper_spectra,
    usable_band,
    welch_spectra,
)

FS = 1000.0


def _pairs(x1, x2, y1, y2):
    return np.stack([x1, x2, y1, y2], axis=-2)


def _scipy_welch(sig, fs, **kw):
    """scipy reference: psd (4, M), csd (2, M), coherence (2, M)."""
    f, psd = ss.welch(sig, fs, **kw)
    _, csd = ss.csd(sig[..., 0::2, :], sig[..., 1::2, :], fs, **kw)
    _, coh = ss.coherence(sig[..., 0::2, :], sig[..., 1::2, :], fs, **kw)
    return f, psd, csd, coh


def _correlated(rng, n, shape=()):
    """Four channels whose pairs share part of their signal."""
    base = rng.standard_normal(shape + (4, n))
    sig = base.copy()
    sig[..., 1, :] = 0.5 * base[..., 0, :] + base[..., 1, :]
    sig[..., 3, :] = 0.7 * base[..., 2, :] + 0.3 * base[..., 3, :]
    return sig


@pytest.mark.parametrize(
    "kw",
    [
        dict(nperseg=256),
        dict(nperseg=300, noverlap=100, window=("tukey", 0.3)),
        dict(nperseg=128, noverlap=0, window="boxcar", detrend="linear"),
        dict(nperseg=257, noverlap=200, detrend=False),
    ],
)
def test_welch_matches_scipy(kw):
    rng = np.random.default_rng(1)
    sig = _correlated(rng, 4000) + 3.0  # offset: detrend matters
    s = welch_spectra(sig, FS, **kw)
    f, psd, csd, coh = _scipy_welch(sig, FS, **kw)
    assert s.method == "welch"
    assert isinstance(s.n_segments, int) and isinstance(s.dof, float)
    np.testing.assert_allclose(s.freq, f, rtol=1e-12, atol=0)
    np.testing.assert_allclose(s.omega, 2 * np.pi * f, rtol=1e-12, atol=0)
    # atol: after detrending the DC bin holds only rounding noise (~1e-33)
    np.testing.assert_allclose(s.psd, psd, rtol=1e-10, atol=1e-13 * np.max(psd))
    scale = np.max(np.abs(csd))
    np.testing.assert_allclose(s.csd, csd, rtol=1e-10, atol=1e-13 * scale)
    _, xy = ss.csd(sig[..., [0, 0, 1, 1], :], sig[..., [2, 3, 2, 3], :], FS, **kw)     # x_i with y_j
    np.testing.assert_allclose(s.xy, xy, rtol=1e-10, atol=1e-13 * np.max(np.abs(xy)))
    g2 = np.asarray(coherence(s))
    # DC coherence of a detrended record is a ratio of rounding noise: compare it only without detrending
    first = 0 if kw.get("detrend", "constant") is False else 1
    np.testing.assert_allclose(g2[:, first:], coh[:, first:], rtol=1e-10, atol=1e-13)


def test_welch_batch_matches_per_record():
    rng = np.random.default_rng(2)
    sig = _correlated(rng, 3000, shape=(3,))
    s = welch_spectra(sig, FS, nperseg=256)
    assert s.psd.shape == (3, 4, 129) and s.csd.shape == (3, 2, 129) and s.freq.shape == (129,)
    for i in range(3):
        one = welch_spectra(sig[i], FS, nperseg=256)
        np.testing.assert_allclose(s.psd[i], one.psd, rtol=1e-13)
        np.testing.assert_allclose(s.csd[i], one.csd, rtol=1e-13, atol=1e-18)
        _, psd, csd, coh = _scipy_welch(sig[i], FS, nperseg=256)
        np.testing.assert_allclose(s.psd[i], psd, rtol=1e-10)
        np.testing.assert_allclose(coherence(s)[i], coh, rtol=1e-10, atol=1e-13)


def test_welch_under_jit_and_vmap_with_traced_fs():
    rng = np.random.default_rng(3)
    sig = rng.standard_normal((2, 4, 2048))
    ref = welch_spectra(sig, FS, nperseg=256)

    @jax.jit
    def run(x, fs):
        s = welch_spectra(x, fs, nperseg=256)
        r = amplitude_ratio(s)
        return s, r, usable_band(r, fmin=10.0, fmax=fs / 4)

    s, r, mask = run(sig, FS)
    assert isinstance(s, CrossSpectra) and isinstance(r, AmplitudeRatio)
    assert s.n_segments == ref.n_segments and s.dof == ref.dof and s.method == "welch"
    np.testing.assert_allclose(s.psd, ref.psd, rtol=1e-12)
    assert mask.dtype == bool and mask.shape == (2, 2, 129)

    sv = jax.vmap(lambda x: welch_spectra(x, FS, nperseg=256))(sig)
    np.testing.assert_allclose(sv.psd, ref.psd, rtol=1e-12)
    assert sv.dof == ref.dof


def test_default_nperseg_and_dof():
    assert default_nperseg(16000) == 1024
    assert default_nperseg(100) == 16
    assert default_nperseg(2**20) == 2**17
    s = welch_spectra(np.zeros((4, 16000)), FS)
    assert s.psd.shape[-1] == 513 and s.n_segments == 30
    # Hann, 50 % overlap: rho(1) = 1/6 exactly (periodic Hann), so K_eff = K / (1 + 2 (1 - 1/K) / 36)
    k = 30
    assert s.dof == pytest.approx(k / (1 + 2 * (1 - 1 / k) / 36), rel=1e-12)
    # no overlap: independent segments
    s0 = welch_spectra(np.zeros((4, 16000)), FS, nperseg=1000, noverlap=0)
    assert s0.n_segments == 16 and s0.dof == pytest.approx(16.0)


def test_multitaper_white_noise_level_matches_welch():
    rng = np.random.default_rng(4)
    s2, fs, n = 4.0, 500.0, 8192
    sig = np.sqrt(s2) * rng.standard_normal((4, n))
    mt = multitaper_spectra(sig, fs)
    assert mt.method == "multitaper" and mt.n_segments == 5 and mt.dof == 5.0  # floor(2 nw) - 3
    level = 2 * s2 / fs
    mean_mt = np.mean(np.asarray(mt.psd)[:, 1:-1])
    mean_w = np.mean(np.asarray(welch_spectra(sig, fs).psd)[:, 1:-1])
    assert mean_mt == pytest.approx(level, rel=0.03)
    assert mean_w == pytest.approx(level, rel=0.03)
    assert mean_mt == pytest.approx(mean_w, rel=0.03)


def test_multitaper_sinusoid_peak():
    rng = np.random.default_rng(5)
    n, k0 = 4096, 123
    t = np.arange(n) / FS
    f0 = k0 * FS / n
    sig = 0.1 * rng.standard_normal((4, n)) + np.sin(2 * np.pi * f0 * t)
    mt = multitaper_spectra(sig, FS, nw=3.0)
    assert mt.n_segments == 3  # floor(2 nw) - 3
    assert np.all(np.argmax(np.asarray(mt.psd), axis=-1) == k0)
    assert float(mt.freq[k0]) == pytest.approx(f0)
    # zero padding: peak still at f0, on a finer grid
    mtp = multitaper_spectra(sig, FS, nw=3.0, nfft=2 * n)
    assert mtp.psd.shape[-1] == n + 1
    assert np.all(np.argmax(np.asarray(mtp.psd), axis=-1) == 2 * k0)


def test_multitaper_matches_numpy_reference():
    rng = np.random.default_rng(6)
    n, nw, k, nfft = 1000, 2.5, 4, 1200
    sig = _correlated(rng, n) + 1.5
    mt = multitaper_spectra(sig, FS, nw=nw, n_tapers=k, nfft=nfft)

    tapers = dpss(n, nw, Kmax=k)  # unit energy
    x = sig - sig.mean(axis=-1, keepdims=True)
    spec = np.fft.rfft(x[:, None, :] * tapers, n=nfft, axis=-1)  # (4, K, M)
    fac = np.full(nfft // 2 + 1, 2.0)
    fac[0] = fac[-1] = 1.0
    psd = np.mean(np.abs(spec) ** 2, axis=1) * fac / FS
    csd = np.mean(np.conj(spec[0::2]) * spec[1::2], axis=1) * fac / FS
    np.testing.assert_allclose(mt.freq, np.fft.rfftfreq(nfft, 1 / FS), rtol=1e-12)
    np.testing.assert_allclose(mt.psd, psd, rtol=1e-10)
    np.testing.assert_allclose(mt.csd, csd, rtol=1e-10, atol=1e-13 * np.max(np.abs(csd)))


@pytest.mark.slow
@pytest.mark.parametrize("method", ["welch", "multitaper"])
def test_amplitude_ratio_recovers_gain_with_calibrated_errors(method):
    rng = np.random.default_rng(7)
    n, gain = 16000, 0.3
    x1 = rng.standard_normal((2, n))
    x2 = gain * x1 + 0.15 * rng.standard_normal((2, n))  # coherence ~ 0.8
    sig = _pairs(x1[0], x2[0], x1[1], x2[1])
    # multitaper: 13 tapers (nw = 8), since with 5 a coherence of 0.8 is not significant
    # against the family-wise zero-coherence level over thousands of bins
    kw = {"nw": 8.0} if method == "multitaper" else {}
    r = amplitude_ratio(estimate_spectra(sig, FS, method=method, **kw))
    mask = np.asarray(usable_band(r))
    assert mask.shape == (2, r.omega.shape[0])
    assert mask.mean() > 0.9 and not mask[:, 0].any()
    lr = np.asarray(r.log_ratio)[mask]
    assert np.median(lr) == pytest.approx(np.log(gain), abs=0.03)
    z = (lr - np.log(gain)) / np.asarray(r.log_ratio_err)[mask]
    assert abs(z.mean()) < 0.4
    assert 0.6 < z.std() < 1.6


def test_usable_band_drops_dc_and_noise_only_bins():
    rng = np.random.default_rng(8)
    n, cutoff = 16000, 100.0
    x1 = rng.standard_normal((2, n))
    f = np.fft.rfftfreq(n, 1 / FS)
    low = np.fft.irfft(np.fft.rfft(x1, axis=-1) * (f < cutoff), n=n, axis=-1)  # brick-wall low-pass
    x2 = 0.3 * low + 0.02 * rng.standard_normal((2, n))  # deep probe: pure noise above 100 Hz
    sig = _pairs(x1[0], x2[0], x1[1], x2[1])
    s = welch_spectra(sig, FS)
    r = amplitude_ratio(s)
    mask = np.asarray(usable_band(r))
    freq = np.asarray(s.freq)
    assert not mask[:, freq == 0].any()
    assert not mask[:, freq > cutoff + 5].any()
    assert mask[:, (freq > 2) & (freq < cutoff - 5)].mean() > 0.95
    # frequency limits are in Hz
    mask_band = np.asarray(usable_band(r, fmin=20.0, fmax=50.0))
    assert not mask_band[:, (freq < 20) | (freq > 50)].any()
    assert mask_band[:, (freq >= 20) & (freq <= 50)].all()
    # traced thresholds under jit agree
    jit_mask = jax.jit(lambda r, lo, hi: usable_band(r, min_snr=1.0, fmin=lo, fmax=hi))(r, 20.0, 50.0)
    np.testing.assert_array_equal(jit_mask, mask_band)


def test_float32_in_float32_out():
    rng = np.random.default_rng(9)
    sig = _correlated(rng, 4096).astype(np.float32)
    for method in ("welch", "multitaper"):
        s = estimate_spectra(sig, np.float32(FS), method=method)
        assert s.freq.dtype == jnp.float32 and s.omega.dtype == jnp.float32
        assert s.psd.dtype == jnp.float32 and s.csd.dtype == jnp.complex64
        r = amplitude_ratio(s)
        assert r.log_ratio.dtype == jnp.float32 and r.log_ratio_err.dtype == jnp.float32
        assert r.coherence.dtype == jnp.float32
        assert np.all(np.isfinite(s.psd)) and np.all(np.isfinite(s.csd))
        assert np.all(np.isfinite(r.coherence))
        assert np.all(np.isfinite(np.asarray(r.log_ratio)[:, 1:]))
        assert not np.any(np.isnan(r.log_ratio)) and not np.any(np.isnan(r.log_ratio_err))
    ref = welch_spectra(sig.astype(np.float64), FS)
    np.testing.assert_allclose(welch_spectra(sig, FS).psd, ref.psd, rtol=1e-4, atol=1e-6 * float(ref.psd.max()))


@pytest.mark.parametrize("method", ["welch", "multitaper"])
def test_exact_zero_channels_give_no_nan(method):
    rng = np.random.default_rng(10)
    sig = rng.standard_normal((4, 2048))
    sig[1] = 0.0  # deep x probe silent: ratio 0
    sig[2] = 0.0  # shallow y probe silent: ratio undefined
    s = estimate_spectra(sig, FS, method=method)
    r = amplitude_ratio(s)
    for a in (s.psd, s.csd, r.coherence, r.log_ratio, r.log_ratio_err):
        assert not np.any(np.isnan(a))
    assert np.all(np.asarray(r.coherence) == 0)
    assert np.all(np.asarray(r.log_ratio) == -np.inf)
    assert np.all(np.asarray(r.log_ratio_err) == np.inf)
    assert not np.asarray(usable_band(r)).any()
    # gradients stay finite through the safe divisions and logs
    g = jax.grad(lambda x: jnp.sum(coherence(welch_spectra(x, FS, nperseg=256))))(jnp.asarray(sig))
    assert np.all(np.isfinite(g))


def test_too_short_and_bad_settings_raise():
    with pytest.raises(TactileInputError) as info:
        welch_spectra(np.zeros((4, 100)), FS, nperseg=256)
    assert info.value.code == "too_short"
    assert "N=100" in str(info.value) and "nperseg=256" in str(info.value)
    assert "\n" not in str(info.value)
    with pytest.raises(TactileInputError) as info:
        welch_spectra(np.zeros((4, 10)), FS)
    assert info.value.code == "too_short"
    with pytest.raises(TactileInputError) as info:
        multitaper_spectra(np.zeros((4, 6)), FS, nw=4.0)
    assert info.value.code == "too_short"
    with pytest.raises(TactileInputError) as info:
        estimate_spectra(np.zeros((4, 1000)), FS, method="periodogram")
    assert info.value.code == "bad_setting"
    for kw in (dict(nperseg=64, noverlap=64), dict(nperseg=0), dict(detrend="quadratic"), dict(window="nope")):
        with pytest.raises(TactileInputError) as info:
            welch_spectra(np.zeros((4, 1000)), FS, **kw)
        assert info.value.code == "bad_setting"
    with pytest.raises(TactileInputError) as info:
        multitaper_spectra(np.zeros((4, 1000)), FS, nfft=500)
    assert info.value.code == "bad_setting"
    with pytest.raises(TactileInputError) as info:
        welch_spectra(np.zeros((3, 1000)), FS)
    assert info.value.code == "bad_shape"
    with pytest.raises(TactileInputError) as info:
        welch_spectra(np.zeros((4, 1000)), -1.0)
    assert info.value.code == "bad_fs"


@pytest.mark.slow
def test_burg_recovers_ar2_and_prewhitening_keeps_ratio():
    from tactile_jax.spectral.prewhiten import burg_ar

    rng = np.random.default_rng(11)
    n = 20000
    e = rng.standard_normal(n + 100)
    x = np.zeros_like(e)
    for i in range(2, e.size):                      # x[n] = 1.6 x[n-1] - 0.8 x[n-2] + e[n]
        x[i] = 1.6 * x[i - 1] - 0.8 * x[i - 2] + e[i]
    x = x[100:]
    a = np.asarray(burg_ar(jnp.asarray(x), 2))
    np.testing.assert_allclose(a, [1.0, -1.6, 0.8], atol=0.02)
    # a steep (red) shallow spectrum and a deep probe = 0.3 x shallow: the ratio is exact either way,
    # the PSDs are restored after the filter is divided out
    sig = _pairs(x, 0.3 * x + 0.01 * rng.standard_normal(n), x, 0.5 * x)
    plain = estimate_spectra(sig, FS)
    white = estimate_spectra(sig, FS, prewhiten=8)
    r = amplitude_ratio(white)
    band = np.asarray(usable_band(r))
    assert band[0].mean() > 0.9
    np.testing.assert_allclose(np.asarray(r.log_ratio)[1], np.log(0.5), atol=1e-9)
    assert np.median(np.abs(np.asarray(r.log_ratio)[0][band[0]] - np.log(0.3))) < 0.01
    mid = slice(20, 400)
    ratio_psd = np.asarray(white.psd)[0, mid] / np.asarray(plain.psd)[0, mid]
    assert np.median(ratio_psd) == pytest.approx(1.0, abs=0.05)
    # the x-y spectra are restored too, although the pairs' filters (phases) differ: y = a delayed, filtered x
    y = np.convolve(x, [0.2, 0.5, 0.3])[:n]
    sig = _pairs(x, 0.3 * x, y + 0.01 * rng.standard_normal(n), 0.5 * y)
    plain, white = estimate_spectra(sig, FS), estimate_spectra(sig, FS, prewhiten=8)
    ratio_xy = np.asarray(white.xy)[0, mid] / np.asarray(plain.xy)[0, mid]
    assert np.median(np.abs(ratio_xy)) == pytest.approx(1.0, abs=0.05)
    assert np.median(np.abs(np.angle(ratio_xy))) < 0.05
    with pytest.raises(TactileInputError) as err:
        estimate_spectra(sig[:, :20], FS, prewhiten=8)
    assert err.value.code == "too_short"


@pytest.mark.slow
@pytest.mark.parametrize("method", ["welch", "multitaper"])
def test_leave_one_out_spectra_average_to_the_estimate(method):
    x = np.random.default_rng(8).standard_normal((4, 2048))
    full = estimate_spectra(x, 1000.0, method=method, prewhiten=4)
    loo = estimate_spectra(x, 1000.0, method=method, prewhiten=4, leave_one_out=True)
    k = full.n_segments
    assert loo.psd.shape == (k, 4, full.omega.size) and loo.csd.shape == (k, 2, full.omega.size)
    assert (loo.n_segments, loo.dof) == (k, full.dof)
    np.testing.assert_allclose(np.mean(loo.psd, axis=0), full.psd, rtol=1e-10)
    np.testing.assert_allclose(np.mean(loo.csd, axis=0), full.csd, rtol=1e-9, atol=1e-12 * np.abs(full.csd).max())
    np.testing.assert_allclose(np.mean(loo.xy, axis=0), full.xy, rtol=1e-9, atol=1e-12 * np.abs(full.xy).max())
    with pytest.raises(TactileInputError, match="leave_one_out"):
        welch_spectra(x, 1000.0, nperseg=2048, leave_one_out=True)


def test_neighbour_selection_removes_the_band_edge_selection_bias():
    # Monte-Carlo of the H1 log ratio with 30 averages over 40 bins whose coherence falls from
    # 0.97 to 0.25 (a band edge), 1500 realisations: the bins kept by their own coherence are
    # biased up; the bins kept by their neighbours' coherence are not
    rng = np.random.default_rng(11)
    reps, m, k, h = 1500, 40, 30, 0.3
    snr = np.geomspace(30.0, 0.33, m)
    cn = lambda shape, var: np.sqrt(var / 2) * (rng.standard_normal(shape) + 1j * rng.standard_normal(shape))
    s = cn((reps, m, k), 1.0)
    x1 = s + cn((reps, m, k), 1e-3)
    x2 = h * s + cn((reps, m, k), (h * h / snr)[None, :, None])
    s11, s22 = np.mean(np.abs(x1) ** 2, -1), np.mean(np.abs(x2) ** 2, -1)
    s12 = np.mean(np.conj(x1) * x2, -1)
    g2 = np.abs(s12) ** 2 / (s11 * s22)
    lr = np.log(np.abs(s12) / s11)
    ratio = AmplitudeRatio(jnp.arange(1.0, m + 1.0), jnp.asarray(lr), jnp.asarray(np.sqrt((1 - g2) / (2 * k * g2))),
                           jnp.asarray(g2), float(k), 1.0)
    edge = (snr > 0.5) & (snr < 2.0)                    # true coherence 0.33-0.67
    bias = {}
    for n in (0, 3):
        keep = np.asarray(usable_band(ratio, neighbours=n))
        bias[n] = np.sum(np.where(keep, lr - np.log(h), 0.0)[:, edge]) / keep[:, edge].sum()
    assert bias[0] > 0.03, bias                          # the winner's curse: +0.043 here
    assert abs(bias[3]) < 0.015, bias
    with pytest.raises(TactileInputError, match="neighbours"):
        usable_band(ratio, neighbours=-1)


@pytest.mark.slow
def test_bin_corr_is_the_log_ratios_neighbour_correlation():
    """``CrossSpectra.bin_corr`` (Hann Welch: 4/9, 1/36) is the correlation of the log ratio's errors
    between neighbouring bins for a coherent pair with noise on the deep probe."""
    rng = np.random.default_rng(3)
    n, gain = 128_000, 0.3
    x1 = rng.standard_normal((2, n))
    x2 = gain * x1 + 0.15 * rng.standard_normal((2, n))
    spec = welch_spectra(_pairs(x1[0], x2[0], x1[1], x2[1]), FS, nperseg=512)
    assert spec.bin_corr == pytest.approx((4 / 9, 1 / 36))
    assert spec.bin_factor == pytest.approx(1 + 2 * sum(spec.bin_corr))
    dev = np.asarray(amplitude_ratio(spec).log_ratio)[:, 1:-1] - np.log(gain)
    dev = dev - dev.mean(axis=1, keepdims=True)
    lag = [np.sum(dev[:, :-j] * dev[:, j:]) / np.sqrt(np.sum(dev[:, :-j] ** 2) * np.sum(dev[:, j:] ** 2))
           for j in (1, 2, 3)]
    assert lag[0] == pytest.approx(spec.bin_corr[0], abs=0.08)      # 508 pairs of bins: sd ~0.04
    assert abs(lag[1] - spec.bin_corr[1]) < 0.08 and abs(lag[2]) < 0.08
    taper = multitaper_spectra(_pairs(x1[0], x2[0], x1[1], x2[1])[..., :4000], FS)
    assert len(taper.bin_corr) > 2 and taper.bin_factor == pytest.approx(1 + 2 * sum(taper.bin_corr), rel=1e-3)


@pytest.mark.slow
def test_errors_from_the_neighbours_do_not_weight_the_ratio_up():
    """A bin's own coherence rises with its own |S12|, so inverse-variance weights from it favour the
    bins whose log ratio came out high; weights from the neighbours' coherence do not."""
    rng = np.random.default_rng(11)
    n, gain = 64_000, 0.3
    x1 = rng.standard_normal((2, n))
    x2 = gain * x1 + 0.25 * rng.standard_normal((2, n))           # coherence ~0.59, 30 segments of 4096
    ratio = amplitude_ratio(welch_spectra(_pairs(x1[0], x2[0], x1[1], x2[1]), FS, nperseg=4096))
    dev = np.asarray(ratio.log_ratio)[:, 4:-4] - np.log(gain)
    def weighted_mean(err):
        w = 1.0 / np.asarray(err)[:, 4:-4] ** 2
        return float(np.sum(w * dev) / np.sum(w))
    sd_mean = float(np.std(dev) / np.sqrt(dev.size / 2))           # 2 x ~4,000 bins, neighbours correlated
    own = weighted_mean(ratio.log_ratio_err)
    neighbours = weighted_mean(neighbour_log_ratio_err(ratio, 3))
    assert own > 5 * sd_mean                                        # measured: +0.021 (sd of the mean 0.0025)
    assert abs(neighbours) < 3 * sd_mean
    assert neighbour_log_ratio_err(ratio, 0) is ratio.log_ratio_err


def test_welch_many_gives_each_records_segments():
    """The chunk's spectra in one jnp program equal numpy's record by record (per-record fs, prewhitening on
    and off, a given segment)."""
    from tactile_jax.spectral.segments import segments
    from tactile_jax.spectral.welch_many import welch_many

    sig = _correlated(np.random.default_rng(3), 4096, (3,))
    sig[..., 1:] += 0.9 * sig[..., :-1]                      # coloured, so that prewhitening has work to do
    fs = np.array([1000.0, 2000.0, 1500.0])
    for kw in (dict(), dict(prewhiten=0), dict(nperseg=300, prewhiten=3)):
        many = welch_many(sig, fs, **kw)
        for i in range(3):
            one = segments(sig[i], fs[i], **kw)
            for name in one._fields:
                a, b = np.asarray(getattr(one, name)), np.asarray(getattr(many, name))[i]
                assert a.shape == b.shape, name
                np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-12 * np.max(np.abs(a)), err_msg=name)
    with pytest.raises(TactileInputError, match="prewhiten"):
        welch_many(sig, 1000.0, prewhiten=12)


def test_records_of_lengthens_the_segments_of_slow_slips_as_record_of():
    """The chunk's records at once (``fit.records_of``): the same segments, bands and lengthened segments as
    ``fit.record_of`` record by record (a slow slip gets a longer segment, a fast one keeps the default)."""
    import jax

    from tactile_jax.inference.fit import record_of, records_of
    from tactile_jax.inference.options import FitOptions
    from tactile_jax.simulation.scene import Scene, simulate

    recs = [simulate(Scene(velocity=v, contact_radius=1.5e-3, duration=8.0, snr_db=45.0, seed=7))
            for v in ((0.01, 0.0), (0.04, 0.01))]
    sig = np.stack([np.asarray(r.signals, float) for r in recs])
    options = FitOptions()
    many = records_of(sig, [FS, FS], [recs[0].depths] * 2, [options] * 2)
    ones = [record_of(s, FS, recs[0].depths, options) for s in sig]
    assert int(ones[0].seg.nperseg) > int(ones[1].seg.nperseg) == default_nperseg(sig.shape[-1])
    for one, got in zip(ones, many):
        for a, b in zip(jax.tree.leaves(one), jax.tree.leaves(got)):
            np.testing.assert_allclose(np.asarray(b) * 1.0, np.asarray(a) * 1.0, rtol=1e-9,
                                       atol=1e-12 * np.max(np.abs(np.asarray(a) * 1.0), initial=0.0))


@pytest.mark.parametrize("n, nw, k", [(2000, 4.0, 5), (1993, 4.0, 7), (64, 3.0, 5)])
def test_dpss_tapers_are_scipys(n, nw, k):
    """The package's tapers (scipy.linalg's tridiagonal eigenproblem) are scipy.signal's, signs included."""
    from tactile_jax.spectral.estimate import dpss_tapers

    np.testing.assert_allclose(dpss_tapers(n, nw, k), np.asarray(dpss(n, nw, Kmax=k, sym=True, norm=2)).reshape(k, n),
                               atol=1e-12)
