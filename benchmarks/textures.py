"""The default fit on each kind of texture: statuses, accuracy, coverage, confident wrong answers, time.

Seeded scenes per kind, 16 s at 1 kHz, Gaussian window, oblique slips (|v|
log-uniform 1-8 cm/s, direction uniform 0-90 deg), contact radius uniform
0.8-3 mm, SNR uniform 40-50 dB:

- ``isotropic``: RandomTexture (the model's own assumption);
- ``directional``: DirectionalTexture, anisotropy uniform 1.5-3, lobe angle uniform 0-180 deg;
- ``stretched``: StretchedTexture (a brushed surface: correlation length 1.5-3 times longer along the
  ridges than across, ridges at any angle), whose angular profile is not the directional model's lobe;
- ``modes``: ModeTexture, 300 plane waves (seeded per scene);
- ``grating``: a sine Grating, pitch uniform 0.7-1.5 mm, wavevector angle uniform 0-180 deg;
- ``wire_net``: WireNet, pitch uniform 0.8-1.5 mm, wire width pitch / 5, angle uniform 0-90 deg;
- ``sheared_net``: the same with the families 3-20 deg off perpendicular (either way): a net the fit's
  right-angle tie-break between sign choices must not mistake for a square one.

Each record goes through ``fit_recording`` with its defaults (the texture
model chosen per record: isotropic, directional, or the line model where the
smooth models find no band or do not fit) and through the per-pair scipy
reference (``scipy_reference.fit_record``). Reported per kind: statuses and the
texture model chosen; over all scenes (a scene whose speeds are not reported
counts as a miss), both speeds within 3 % of |v| with status ok, a within 5 %,
and for gratings and nets the speed along the lines' normal within 3 % (of the
family nearest the reported value); 1-sigma coverage of vx, vy and a over the
``ok`` rows; and the share of scenes with a confident wrong answer (a value
with an error bar, status ok or undetermined, more than 3 of its sigmas from
the truth). Times are medians per record after compilation.

    python benchmarks/textures.py --scenes 50 --out benchmarks/out     # ~30 min on 2 cores
    python benchmarks/textures.py --kinds directional,modes --scenes 50 --out /tmp/tex
    python benchmarks/textures.py --summarize benchmarks/out/textures.json --cache /tmp/texsim --out /tmp/tex

Gratings and nets are also counted over the scenes whose probes determine what
the target asks for (``determinable``): a grating's line held by both deep
probes ``HEARD_DB`` above the noise in its bin (one pair
alone gives one wavevector component, not the normal's direction), or two
non-parallel lines of a net (its fundamentals, their sum and difference) so held,
by the Gaussian window's line responses and the simulator's noise.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import json
import platform
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import scipy_reference  # noqa: E402

from tactile_jax.errors import TactileInputError  # noqa: E402
from tactile_jax.io.files import read_recording, write_recording  # noqa: E402
from tactile_jax.inference.options import FitOptions
from tactile_jax.inference.fit import fit_recording  # noqa: E402
from tactile_jax.simulation.scene import Scene, simulate  # noqa: E402
from tactile_jax.spectral.estimate import default_nperseg  # noqa: E402
from tactile_jax.model import r_curve  # noqa: E402
from tactile_jax.simulation.texture import DirectionalTexture, Grating, ModeTexture, RandomTexture, WireNet  # noqa: E402
from tactile_jax.simulation.texture import StretchedTexture  # noqa: E402
from tactile_jax.simulation.texture import _raised_cosine_bumps  # noqa: E402

KINDS = ("isotropic", "directional", "modes", "grating", "wire_net", "stretched", "sheared_net")
#: where simulated recordings are kept between runs (``--cache``); None: simulate every time
_CACHE: Path | None = None
FS, DURATION = 1000.0, 16.0
#: a line counts as heard by a pair where its deep probe holds it this far above its noise floor (dB)
HEARD_DB = 10.0


def texture(kind: str, rng, seed: int):
    if kind == "isotropic":
        return RandomTexture()
    if kind == "directional":
        return DirectionalTexture(anisotropy=float(rng.uniform(1.5, 3.0)), angle=float(rng.uniform(0, np.pi)))
    if kind == "stretched":
        return StretchedTexture(aspect=float(rng.uniform(1.5, 3.0)), angle=float(rng.uniform(0, np.pi)))
    if kind == "modes":
        return ModeTexture(n_modes=300, seed=seed)
    if kind == "grating":
        return Grating(pitch=float(rng.uniform(0.7e-3, 1.5e-3)), angle=float(rng.uniform(0, np.pi)), profile="sine")
    if kind == "wire_net":
        pitch = float(rng.uniform(0.8e-3, 1.5e-3))
        return WireNet(pitch=pitch, wire_width=pitch / 5, angle=float(rng.uniform(0, np.pi / 2)))
    if kind == "sheared_net":
        pitch = float(rng.uniform(0.8e-3, 1.5e-3))
        shear = float(rng.choice([-1.0, 1.0]) * rng.uniform(np.radians(3.0), np.radians(20.0)))
        return WireNet(pitch=pitch, wire_width=pitch / 5, angle=float(rng.uniform(0, np.pi / 2)), shear=shear)
    raise ValueError(f"unknown kind {kind!r}; expected one of {', '.join(KINDS)}")


def scenes(kind: str, n: int, seed: int = 31):
    rng = np.random.default_rng([seed, KINDS.index(kind)])
    for i in range(n):
        speed = float(np.exp(rng.uniform(np.log(0.01), np.log(0.08))))
        angle = float(rng.uniform(0, np.pi / 2))
        a = float(rng.uniform(0.8e-3, 3e-3))
        snr = float(rng.uniform(40, 50))
        s = int(rng.integers(1 << 30))
        yield Scene(texture=texture(kind, rng, s), velocity=(speed * np.cos(angle), speed * np.sin(angle)),
                    contact_radius=a, snr_db=snr, duration=DURATION, fs=FS, seed=s)


def use_cache(folder: Path | None) -> None:
    """Keep simulated recordings in ``folder`` (created) between runs; None: simulate every time."""
    global _CACHE
    _CACHE = folder
    if folder is not None:
        folder.mkdir(parents=True, exist_ok=True)


def _simulate(scene):
    cached = _CACHE / f"{scene.seed}.npz" if _CACHE else None
    if cached is not None and cached.exists():
        return read_recording(cached)
    rec = _simulate_fresh(scene)
    if cached is not None:
        write_recording(cached, rec)
    return rec


def _simulate_fresh(scene):
    try:
        return simulate(scene)
    except TactileInputError:       # a large contact at a fast slip: a coarser grid still resolves d1
        return simulate(dataclasses.replace(scene, grid_spacing=60e-6))


def _normal_speeds(scene) -> list[float]:
    """|v . n| for each family of parallel lines of a grating or a net (n its lines' normal); [] otherwise."""
    tex = scene.texture
    if isinstance(tex, Grating):
        angles = [tex.angle]
    elif isinstance(tex, WireNet):
        angles = [tex.angle, tex.angle + np.pi / 2 + tex.shear]
    else:
        return []
    v = np.asarray(scene.velocity, float)
    return [float(abs(np.cos(t) * v[0] + np.sin(t) * v[1])) for t in angles]


def _line_coefficients(scene, order: int = 16):
    """The texture's lines: their orders (n, m) (L, 2) on the basis (e1, e2) (a grating: e1 alone), wavevectors
    (L, 2) rad/m and complex amplitudes (L,) of u0 = sum c e^{i k.r}, from one periodic cell (a sine grating:
    its two half-amplitude terms; a net: a 2-D FFT of max(f1, f2))."""
    tex = scene.texture
    k0 = 2 * np.pi / tex.pitch
    e1 = np.array([np.cos(tex.angle), np.sin(tex.angle)])
    if isinstance(tex, Grating):
        if tex.profile != "sine":
            raise ValueError("heard_by_both_pairs models sine gratings only")
        orders = np.array([[1, 0], [-1, 0]])
        return orders, k0 * orders[:, :1] * e1, np.array([0.5, 0.5], complex)
    e2 = np.array([-np.sin(tex.angle + tex.shear), np.cos(tex.angle + tex.shear)])
    m = 256
    s = (np.arange(m) + 0.5) / m * tex.pitch
    f1 = _raised_cosine_bumps(s, tex.pitch, tex.wire_width)
    c = np.fft.fft2(np.maximum(f1[:, None], f1[None, :])) / m ** 2
    n = np.arange(-order, order + 1)
    nn, mm = np.meshgrid(n, n, indexing="ij")
    keep = (nn != 0) | (mm != 0)
    orders = np.stack([nn[keep], mm[keep]], 1)
    return orders, k0 * (orders[:, :1] * e1 + orders[:, 1:] * e2), c[orders[:, 0] % m, orders[:, 1] % m]


def pair_powers(power, kv, depth: float, a: float) -> np.ndarray:
    """(2, L): each line's power (``power`` (L,), wavevectors ``kv`` (L, 2) rad/m) in the x and the y probe at
    ``depth`` (m), up to a common factor, by the Gaussian window's line responses (x pair: W(ky) G(|kx|; d, a),
    y pair alike; ``model.r_curve.log_g``)."""
    def response(along, across):
        return np.exp(np.asarray(r_curve.log_g(np.abs(along), depth, a), float) - a * a * across ** 2 / 6.0)

    return power * np.stack([response(kv[:, 0], kv[:, 1]), response(kv[:, 1], kv[:, 0])]) ** 2


def welch_noise(shallow: np.ndarray, snr_db: float) -> float:
    """The simulator's noise power in one default Welch bin, on the scale of ``pair_powers``' ``shallow`` (2, L):
    the same sigma on every channel, sigma^2 = P_ref 10^(-SNR/10), P_ref the larger shallow power."""
    return float(np.max(shallow.sum(-1))) * 10.0 ** (-snr_db / 10.0) / default_nperseg(int(DURATION * FS))


def heard_by_both_pairs(rec, scene, margin_db: float = HEARD_DB) -> list[bool]:
    """For each line that can fix a direction (a grating's wavevector; a net's two fundamentals and their sum
    and difference, pairwise non-parallel): whether both deep probes hold it ``margin_db`` above the noise
    in its Welch bin (``pair_powers``, ``welch_noise``). A line that one pair alone hears gives one wavevector
    component: its direction is unknown. [] for random textures."""
    if not isinstance(scene.texture, (Grating, WireNet)):
        return []
    d1, d2 = (float(d) for d in rec.depths)
    orders, kv, coef = _line_coefficients(scene)
    power = np.abs(coef) ** 2
    floor = welch_noise(pair_powers(power, kv, d1, scene.a), scene.snr_db) * 10.0 ** (margin_db / 10.0)
    deep = pair_powers(power, kv, d2, scene.a)
    targets = [(1, 0)] if isinstance(scene.texture, Grating) else [(1, 0), (0, 1), (1, 1), (1, -1)]
    return [bool(deep[:, int(np.flatnonzero((orders == nm).all(1))[0])].min() >= floor) for nm in targets]


def determinable(row) -> bool | None:
    """Whether the probes hold what the issue's target asks for: a grating's line heard by both pairs (its
    normal speed), or two non-parallel lines of a net heard by both pairs (both speeds). None: other kinds."""
    heard = row.get("heard_2d")
    if not heard:
        return None
    return heard[0] if row["kind"] == "grating" else sum(heard) >= 2


def run_kind(kind: str, n: int, verbose: bool = True) -> list[dict]:
    rows = []
    nperseg = default_nperseg(int(DURATION * FS))
    for i, scene in enumerate(scenes(kind, n)):
        rec = _simulate(scene)
        t0 = time.perf_counter()
        res = fit_recording(rec, FitOptions())
        t1 = time.perf_counter()
        x = np.asarray(rec.signals, float)
        sp = scipy_reference.fit_record(x, FS, rec.depths[0], rec.depths[1], nperseg)
        t2 = time.perf_counter()
        vx, vy = (abs(v) for v in scene.velocity)
        row = {"kind": kind, "i": i, "vx_true": vx, "vy_true": vy, "a_true": scene.a, "speed": float(np.hypot(vx, vy)),
               "snr_db": scene.snr_db, "texture": type(scene.texture).__name__, "fit_s": t1 - t0, "scipy_s": t2 - t1,
               **{k: getattr(res, k) for k in ("vx", "vx_err", "vy", "vy_err", "a", "a_err", "redchi", "message",
                                               "texture", "texture_margin", "error_method",
                                               "v_normal", "v_normal_err", "normal_angle")},
               "status": str(res.status), "v_normal_true": _normal_speeds(scene),
               "heard_2d": heard_by_both_pairs(rec, scene),
               "scipy": dict(zip(("vx", "vx_err", "vy", "vy_err", "a", "a_err"),
                                 (None if not np.isfinite(v) else float(v) for v in sp)))}
        rows.append(row)
        if verbose:
            def f(v, s=100.0):
                return "  -  " if v is None else f"{s * v:.3f}"
            print(f"{kind:11s} {i:3d} v=({100 * vx:.2f}, {100 * vy:.2f}) a={1e3 * scene.a:.2f} | {row['status']:13s} "
                  f"{row['texture']:11s} vn {f(row['v_normal'])} "
                  f"vx {f(row['vx'])}+/-{f(row['vx_err'])} vy {f(row['vy'])}+/-{f(row['vy_err'])} "
                  f"a {f(row['a'], 1e3)}+/-{f(row['a_err'], 1e3)} chi2r {row['redchi'] or 0:.2f} "
                  f"{row['fit_s']:.1f}s", flush=True)
    return rows


def _dev(r, name, src=None):
    src = r if src is None else src
    if src.get(name) is None:
        return None
    return abs(src[name] - r[name + "_true"])


def _vn_dev(r):
    """|v_n - truth| / truth for the family nearest the reported v_n, or None."""
    if r.get("v_normal") is None or not r["v_normal_true"]:
        return None
    return min(abs(r["v_normal"] - t) / t for t in r["v_normal_true"] if t > 0)


def summarize(rows: list[dict]) -> dict:
    n = len(rows)
    ok = [r for r in rows if r["status"] == "ok"]
    out = {"n": n, "status": dict(collections.Counter(r["status"] for r in rows)), "ok_share": len(ok) / n if n else None,
           "texture": dict(collections.Counter(r["texture"] for r in rows))}

    def share(pred, pool):
        return float(np.mean([pred(r) for r in pool])) if pool else None

    # accuracy over every scene: a scene whose speeds are not reported counts as a miss
    out["both_speeds_3pct"] = share(lambda r: r["status"] == "ok" and all(
        _dev(r, k) is not None and _dev(r, k) <= 0.03 * r["speed"] for k in ("vx", "vy")), rows)
    out["a_5pct"] = share(lambda r: r["status"] == "ok" and _dev(r, "a") is not None
                          and _dev(r, "a") <= 0.05 * r["a_true"], rows)
    out["v_normal_3pct"] = share(lambda r: (_vn_dev(r) or 1.0) <= 0.03, rows) if rows and rows[0]["v_normal_true"] else None
    det = [r for r in rows if determinable(r)]
    out["determinable"] = share(lambda r: bool(determinable(r)), rows) if rows and rows[0].get("heard_2d") else None
    out["n_determinable"] = len(det)
    out["both_speeds_3pct_determinable"] = share(lambda r: r["status"] == "ok" and all(
        _dev(r, k) is not None and _dev(r, k) <= 0.03 * r["speed"] for k in ("vx", "vy")), det)
    out["v_normal_3pct_determinable"] = share(lambda r: (_vn_dev(r) or 1.0) <= 0.03, det)
    out["speeds_undetermined"] = share(lambda r: r["vx"] is None and r["vy"] is None, rows)
    for name in ("vx", "vy", "a"):
        pool = [r for r in ok if r[name] is not None and r[name + "_err"]]
        out[name + "_cover1_ok"] = share(lambda r: _dev(r, name) <= r[name + "_err"], pool)
        poor = [r for r in rows if r["status"] == "poor_fit" and r[name] is not None and r[name + "_err"]]
        out[name + "_cover1_poor"] = share(lambda r: _dev(r, name) <= r[name + "_err"], poor)
        out[name + "_cover3_poor"] = share(lambda r: _dev(r, name) <= 3 * r[name + "_err"], poor)

    def wrong(r):
        """A number with an error bar (status ok or undetermined) more than 3 of its sigmas off."""
        if r["status"] not in ("ok", "undetermined"):
            return False
        bad = any(r[k] is not None and r[k + "_err"] and _dev(r, k) > 3 * r[k + "_err"] for k in ("vx", "vy", "a"))
        vn = r.get("v_normal")
        if vn is not None and r.get("v_normal_err") and r["v_normal_true"]:
            bad |= min(abs(vn - t) for t in r["v_normal_true"]) > 3 * r["v_normal_err"]
        return bad
    out["confident_wrong_share"] = share(wrong, rows)
    out["fit_s_median"] = float(np.median([r["fit_s"] for r in rows[1:]] or [rows[0]["fit_s"]])) if rows else None
    sp = [r for r in rows if r["scipy"]["vx"] is not None and r["scipy"]["vy"] is not None]
    out["scipy_both_speeds_3pct"] = share(lambda r: all(_dev(r, k, r["scipy"]) <= 0.03 * r["speed"]
                                                        for k in ("vx", "vy")), sp)
    out["scipy_s_median"] = float(np.median([r["scipy_s"] for r in rows])) if rows else None
    return out


def _pct(x):
    return "-" if x is None else f"{100 * x:.0f} %"


def table(summary: dict) -> str:
    lines = ["| texture | scenes | statuses | model chosen | both speeds within 3 % | a within 5 % | "
             "speed along the normal within 3 % | probes determine it | within 3 % where determined | "
             "1-sigma cover vx / vy / a (ok) | 1 / 3-sigma cover vx, vy, a (poor_fit) | confident wrong | fit s | "
             "scipy: both speeds within 3 % |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for kind, s in summary.items():
        st = ", ".join(f"{k} {v}" for k, v in sorted(s["status"].items()))
        tx = ", ".join(f"{k} {v}" for k, v in sorted(s["texture"].items()))
        cover = " / ".join(_pct(s[k + "_cover1_ok"]) for k in ("vx", "vy", "a"))
        poor = ", ".join(f"{_pct(s.get(k + '_cover1_poor'))} / {_pct(s.get(k + '_cover3_poor'))}"
                         for k in ("vx", "vy", "a")) if s.get("vx_cover1_poor") is not None else "-"
        det, within = "-", "-"
        if s.get("determinable") is not None:
            det = f"{s['n_determinable']} of {s['n']}"
            within = _pct(s["v_normal_3pct_determinable" if kind == "grating" else "both_speeds_3pct_determinable"])
        lines.append(f"| {kind} | {s['n']} | {st} | {tx} | {_pct(s['both_speeds_3pct'])} | {_pct(s['a_5pct'])} | "
                     f"{_pct(s['v_normal_3pct'])} | {det} | {within} | {cover} | {poor} | {_pct(s['confident_wrong_share'])} | "
                     f"{s['fit_s_median']:.2f} | {_pct(s['scipy_both_speeds_3pct'])} |")
    return "\n".join(lines)


def figure(summary: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tactile_jax.viz.figures import save_figure

    kinds = list(summary)
    x = np.arange(len(kinds))
    fig, ax = plt.subplots(figsize=(8, 3.6))
    bars = (("ok_share", "status ok"), ("both_speeds_3pct", "both speeds within 3 %"),
            ("confident_wrong_share", "confident wrong (> 3 sigma)"))
    for j, (key, label) in enumerate(bars):
        ax.bar(x + (j - 1) * 0.27, [summary[k][key] or 0.0 for k in kinds], 0.27, label=label)
    ax.set_xticks(x, kinds)
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("share of scenes")
    ax.legend(fontsize=7)
    ax.set_title("default fit per texture kind (16 s, oblique slips, a 0.8-3 mm, 40-50 dB)", fontsize=9)
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    save_figure(fig, path)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kinds", default=",".join(KINDS), help=f"comma-separated subset of {','.join(KINDS)}")
    ap.add_argument("--scenes", type=int, default=20, help="scenes per kind")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/out"))
    ap.add_argument("--cache", type=Path, default=None, help="folder to keep the simulated recordings in (reused)")
    ap.add_argument("--summarize", type=Path, default=None,
                    help="re-table a saved textures.json (lines heard by both pairs recomputed from --cache)")
    args = ap.parse_args(argv)
    use_cache(args.cache)
    kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
    bad = [k for k in kinds if k not in KINDS]
    if bad or args.scenes < 1:
        raise SystemExit(f"error: unknown kinds {bad} (expected {', '.join(KINDS)}) or --scenes < 1")
    args.out.mkdir(parents=True, exist_ok=True)
    import jaxlib

    machine = (f"{platform.machine()}, {platform.system()}, Python {platform.python_version()}, jax {jax.__version__} "
               f"(jaxlib {jaxlib.__version__}), numpy {np.__version__}")
    if args.summarize is not None:
        saved = json.loads(args.summarize.read_text())
        machine, rows = saved["machine"], saved["rows"]
        for kind, kind_rows in rows.items():
            for row, scene in zip(kind_rows, scenes(kind, len(kind_rows))):
                row["heard_2d"] = heard_by_both_pairs(_simulate(scene), scene)
    else:
        rows = {k: run_kind(k, args.scenes) for k in kinds}
    summary = {k: summarize(r) for k, r in rows.items()}
    text = table(summary)
    print(f"\nmachine: {machine}\n\n{text}")
    (args.out / "textures.json").write_text(json.dumps({"machine": machine, "summary": summary, "rows": rows},
                                                       indent=1, default=str))
    figure(summary, args.out / "textures.png")
    print(f"\nwrote {args.out / 'textures.json'} and {args.out / 'textures.png'}")


if __name__ == "__main__":
    main()
