"""Prototype: what a fit that uses the x-y cross-spectra reaches on slow slips (issue #3's next step).

Not the library's fit. For each seed of one scene, the recording is fitted by
``fit_recording(FitOptions(prewhiten=0))`` (for its bins, masks, spectral window
and texture knots; with no AR prewhitening the measured cross-spectra need no
un-whitening). Then (vx, vy, a, the texture knots and the y pair's level) are
refitted by the complex-Wishart (Whittle) likelihood of both pairs' 4 x 4
spectral matrix at the fit's bins,

    -log L = K sum_bins [log det S + tr(S^-1 S_hat)] + the joint model's priors,

S the ``spectral_matrix`` model averaged over the bin's spectral window, S_hat the
Welch estimate of all 16 entries (``scipy.signal.csd``, the fit's segment length).
The fit is minimised with optimistix BFGS from the joint fit's solution. Its errors
come from the expected Fisher information plus the priors' curvature. With
``--pairs`` the cross-pair entries are zeroed in both S and S_hat, which gives the
same likelihood restricted to each pair's own 2 x 2 matrix.

    python benchmarks/cross_pair_prototype.py --speed 0.012 --angle 45 --radius 0.0012 --seeds 8

Prints one line per seed and the RMS deviation, the mean stated error and the
share with both speeds within 2 % of |v|, for the prototype and the joint fit.
"""

from __future__ import annotations

import argparse
import platform
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import optimistix as optx  # noqa: E402
from scipy.signal import csd  # noqa: E402

from tactile_jax import joint_model as jm  # noqa: E402
from tactile_jax.crb import bound_covariance, wishart_fisher  # noqa: E402
from tactile_jax.fit import FitOptions, fit_recording  # noqa: E402
from tactile_jax.scene import Scene, simulate  # noqa: E402
from tactile_jax.spectral_matrix import spectral_matrix  # noqa: E402
from tactile_jax.texture import RandomTexture  # noqa: E402

_PAIRS = np.kron(np.eye(2), np.ones((2, 2)))


def measured_matrix(signals, fs, nperseg, omega):
    """Welch estimate (F, 4, 4) of all 16 auto- and cross-spectra at the bins ``omega`` (rad/s)."""
    x = np.asarray(signals)
    out = np.zeros((omega.size, 4, 4), complex)
    for c in range(4):
        for d in range(4):
            f, s = csd(x[c], x[d], fs, nperseg=nperseg, noverlap=nperseg // 2, window="hann", detrend="constant")
            out[:, c, d] = s[np.rint(omega / (2 * np.pi * f[1])).astype(int)]
    return out


def model_matrix(theta, data, rows, cross=True):
    """Model (F, 4, 4) at the bins ``rows`` of ``data``: spectral-window averages of the grid densities, plus noise."""
    s = spectral_matrix(theta, data.grid_omega, data.depths, data.log_k_knots, jnp.full(4, -700.0))
    sb = jnp.einsum("lj,ljcd->lcd", jnp.exp(data.kernel_log_w[rows]), s[data.kernel_index[rows]])
    sb = sb + jnp.eye(4)[None] * jnp.exp(jnp.ravel(data.log_noise_c22))[None, :, None]
    return sb if cross else sb * _PAIRS


def whittle_fit(rec, cross=True):
    """The prototype fit of one recording: a dict of values and errors (SI), with the joint fit's beside them."""
    res = fit_recording(rec, FitOptions(prewhiten=0))
    data = res.problem.args
    free = np.asarray(res.problem.free).copy()
    free[6] = False                                            # the measured noise levels stand
    rows = np.flatnonzero(np.asarray(data.mask_s11 | data.mask_h).any(axis=0))
    omega = np.asarray(data.omega)[rows]
    nperseg = int(round(2 * np.pi * rec.fs / float(data.omega[1] - data.omega[0])))
    s_hat = jnp.asarray(measured_matrix(rec.signals, rec.fs, nperseg, omega) * (1 if cross else _PAIRS))
    dof = float(data.c22_weight) ** 2 + 1.0
    theta0, fr = jnp.asarray(res.problem.theta), jnp.asarray(free)
    n_prior = jm.n_prior_residuals(theta0.shape[0])

    def neg_log_l(t, _):
        t = jnp.where(fr, t, theta0)
        s = model_matrix(t, data, rows, cross)
        chol = jnp.linalg.cholesky(s)
        log_det = 2.0 * jnp.sum(jnp.log(jnp.diagonal(chol, axis1=1, axis2=2)))
        trace = jnp.real(jnp.trace(jnp.linalg.solve(s.astype(complex), s_hat), axis1=1, axis2=2))
        prior = jm.residuals(t, data)[-n_prior:]
        return dof * jnp.sum(log_det + trace) + 0.5 * jnp.sum(prior ** 2)

    sol = optx.minimise(neg_log_l, optx.BFGS(rtol=1e-8, atol=1e-8), theta0, max_steps=500, throw=False)
    theta = jnp.where(fr, sol.value, theta0)

    fisher = wishart_fisher(lambda t: model_matrix(t, data, rows, cross), theta, fr, dof)
    jp = jax.jacfwd(lambda t: jm.residuals(t, data)[-n_prior:])(theta) * fr[None]
    sd = np.sqrt(np.diag(np.asarray(bound_covariance(fisher + jp.T @ jp, fr))))
    vx, vy, rad = np.exp(np.asarray(theta[:3]))
    return {"vx": vx, "vy": vy, "a": rad, "vx_err": vx * sd[0], "vy_err": vy * sd[1], "a_err": rad * sd[2],
            "converged": sol.result == optx.RESULTS.successful, "steps": int(sol.stats["num_steps"]),
            "joint": (res.vx, res.vy, res.a, res.vx_err, res.vy_err, res.a_err)}


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--speed", type=float, default=0.012, help="|v|, m/s")
    p.add_argument("--angle", type=float, default=45.0, help="slip direction, deg from x")
    p.add_argument("--radius", type=float, default=1.2e-3, help="contact radius, m")
    p.add_argument("--snr", type=float, default=50.0)
    p.add_argument("--seeds", type=int, default=8)
    p.add_argument("--first-seed", type=int, default=1000)
    p.add_argument("--pairs", action="store_true", help="zero the cross-pair entries (each pair's 2 x 2 alone)")
    a = p.parse_args()
    v, ang, rad = a.speed, np.radians(a.angle), a.radius
    print(f"# cross-pair prototype: |v| {100 * v:.2f} cm/s at {a.angle:.0f} deg, a {1e3 * rad:.2f} mm, "
          f"{a.snr:.0f} dB, 16 s; {'pairs only' if a.pairs else '4 x 4'}; {platform.machine()}, "
          f"jax {jax.__version__}, numpy {np.__version__}")
    rows = []
    for seed in range(a.first_seed, a.first_seed + a.seeds):
        scene = Scene(texture=RandomTexture(), velocity=(v * np.cos(ang), v * np.sin(ang)), contact_radius=rad,
                      snr_db=a.snr, duration=16.0, seed=seed)
        t0 = time.perf_counter()
        o = whittle_fit(simulate(scene), cross=not a.pairs)
        tx, ty = abs(scene.velocity[0]), abs(scene.velocity[1])
        j = o["joint"]
        row = 100 * np.array([(o["vx"] - tx) / v, (o["vy"] - ty) / v, o["a"] / rad - 1,
                              o["vx_err"] / v, o["vy_err"] / v, o["a_err"] / rad,
                              (j[0] - tx) / v, (j[1] - ty) / v, j[2] / rad - 1, j[3] / v, j[4] / v, j[5] / rad])
        rows.append(row)
        print(f"seed {seed}: prototype dev {row[0]:+.2f} / {row[1]:+.2f} / {row[2]:+.2f} +/- "
              f"{row[3]:.2f} / {row[4]:.2f} / {row[5]:.2f} ({o['steps']} steps, converged {o['converged']}) | "
              f"joint fit dev {row[6]:+.2f} / {row[7]:+.2f} / {row[8]:+.2f} +/- {row[9]:.2f} / {row[10]:.2f} / "
              f"{row[11]:.2f} | {time.perf_counter() - t0:.0f} s", flush=True)
    x = np.array(rows)
    for name, k in (("prototype", 0), ("joint fit", 6)):
        rms = np.sqrt(np.mean(x[:, k:k + 3] ** 2, axis=0))
        within = np.mean((np.abs(x[:, k]) < 2) & (np.abs(x[:, k + 1]) < 2))
        print(f"{name}: RMS vx / vy / a {rms[0]:.2f} / {rms[1]:.2f} / {rms[2]:.2f} % | mean "
              f"{x[:, k].mean():+.2f} / {x[:, k + 1].mean():+.2f} / {x[:, k + 2].mean():+.2f} | stated "
              + " / ".join(f"{e:.2f}" for e in x[:, k + 3:k + 6].mean(axis=0))
              + f" | both speeds within 2 %: {within:.0%}")


if __name__ == "__main__":
    main()
