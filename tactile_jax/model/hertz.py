"""Hertz-window line response of a line probe: a fast, differentiable table evaluator (JAX).

Physics.  An x-probe (the line x = 0 along y) at depth d under a Hertz contact of radius a responds
to the surface mode exp(i (ks x + kp y)) with

    H(ks, kp; d, a) = Int_{-a}^{a} K_d(x) cos(ks x) Y(x, kp) dx,      K_d = d / (pi (x^2 + d^2)),
    Y(x, kp) = pi b J1(kp b) / (a kp),  b = sqrt(a^2 - x^2).

We return Hn = H / (pi a / 2), a function of (kappa_s, kappa_p, delta) = (ks a, kp a, d / a) only:
even in ks and kp, real, band-limited in kappa (the 2-D Fourier transform of
(2/pi) P_delta(u) sqrt(1 - u^2 - v^2) on the unit disk), -> exp(-|ks| d) as a -> inf at kp = 0,
and it changes sign at large kappa (the disk's edge).  The y pair uses (ks, kp) = (ky, kx).

Design (the measured accuracy and cost are in docs/model.md and docs/validation.md).
* Table (|kappa_s|, |kappa_p| up to ``kmax`` = 160, delta in [0.01, 5]): Hn on a uniform grid in
  (kappa_s, kappa_p) (spacing ``h`` = 0.5) and in t = log(delta) (spacing ``dt`` = 0.07), as a
  tensor-product cubic B-spline (not-a-knot ends, the exact even mirror at kappa = 0).
  Built once with numpy/scipy (about 5 s), cached on disk in float32 (50 MB) under
  $TACTILE_JAX_CACHE or ~/.cache/tactile_jax.  Max error 2e-4 of the local amplitude, below the
  1e-3 of the line integrals' quadrature (``lines.N_NODES_HERTZ``): a degree-7 table (9e-8) cost 2.7x
  as much per lookup and moved no fitted value by more than 0.01 of its error (12 Hertz and 4
  Gaussian scenes of ``benchmarks/windows.py``).
* Per evaluation (one scalar a): for each probe depth, one small matrix product contracts the
  4 t-slices around delta = d / a into a 2-D coefficient slice of Hn (float64) and of
  dHn/d(delta); then each node gathers a 4 x 4 block of both and contracts it with the B-spline
  weights and their derivatives: value and the partials in (kappa_s, kappa_p, delta) from the
  same numbers.  A ``jax.custom_jvp`` maps them to tangents of (ks, kp, depths, a).
* Beyond the table (||kappa||_8 > kmax - 12, blended over 12 units): the leading large-kappa
  asymptote (exact pole term exp(-|kappa_s| delta) y(i delta, kappa_p) + the disk edge's
  stationary point; near the kappa_p axis the Poisson kernel against the Fresnel zone of the
  edge, via Faddeeva functions), about 1e-2 of the local amplitude at kappa ~ 150, 1e-3 median.
  Computed only when some node needs it (a conditional); ``far_field=False`` tapers Hn to 0
  there instead (a documented cut-off).  delta < delta_min: exact pole term + the rest scaled
  linearly in delta; delta > delta_max (unsupported): Hn(delta_max) delta_max / delta (~4% at
  delta = 2 delta_max).

Public API
----------
hertz_table(**params) -> HertzTable
    build or load the table (once per process; cached on disk).
table_of(coef) -> HertzTable
    the default table with given coefficients (a compiled program's data).
hertz_hn(k_s, k_p, depths, a, table=None, depth_index=None, far_field=True) -> Hn
    signed, dimensionless; k_s, k_p (C, ...) rad/m, depths (D,) m, a scalar m.
hertz_lookup(...same...) -> Lookup(val, d_s, d_p, d_d)
    Hn and its partials, looked up once as constants: ``hertz_factors(..., lookup=)`` then takes
    any number of tangents at those nodes for that one lookup (the joint model's Jacobian).
hertz_factors(...same...) -> (log_env, mant)
    Hn = mant * exp(log_env): log_env is the analytic envelope ``hertz_log_envelope`` (smooth,
    |Hn| / env < 1.6), mant is signed and O(1), smooth through the zeros of Hn.  For log-space
    line integrals: an entry is sum_n exp(base_n + log_env_i + log_env_j) mant_i mant_j.
hertz_reference(kappa_s, kappa_p, delta) -> numpy reference by composite quadrature (checks).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import os
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from .._numerics import any_in_batch

__all__ = [
    "DEFAULT_PARAMS",
    "HertzTable",
    "build_table",
    "hertz_table",
    "table_of",
    "corner",
    "hertz_hn",
    "hertz_factors",
    "hertz_lookup",
    "Lookup",
    "hertz_log_envelope",
    "hertz_reference",
]

TABLE_VERSION = 3
#: table parameters: B-spline degree (odd), kappa spacing h and range kmax (dimensionless),
#: log(delta) spacing dt and delta range, far-field blend width (kappa units)
DEFAULT_PARAMS = dict(degree=3, h=0.5, kmax=160.0, dt=0.07, delta_min=0.01, delta_max=5.0)

# Python scalars (weakly typed: float32 inputs stay float32)
_2_PI = float(2.0 / np.pi)
_4_PI = float(4.0 / np.pi)
_1_SQRT_PI = float(1.0 / np.sqrt(np.pi))
_C0 = float(2.0 * np.sqrt(2.0 / np.pi))
_E_3PI4 = complex(np.exp(-0.75j * np.pi))

_PAD_K = 14        # extra grid points beyond kmax (not-a-knot end effects decay as 0.43^n)
_PAD_T = 6         # extra slices beyond [log delta_min, log delta_max]
_MIRROR = 8        # mirrored grid points at kappa < 0 (exact: Hn is even)


# ----------------------------------------------------------------------------------------------
# numpy reference and table builder
# ----------------------------------------------------------------------------------------------

def _lam(z):
    """2 J1(z) / z (even, entire), numpy."""
    from scipy.special import j1
    z = np.asarray(z, float)
    small = np.abs(z) < 1e-3
    zs = np.where(small, 1.0, z)
    z2 = z * z
    return np.where(small, 1.0 - z2 / 8.0 + z2 * z2 / 192.0, 2.0 * j1(zs) / zs)


def _ywin(u, kp):
    """y(u, kappa_p) = 2 beta J1(kappa_p beta) / kappa_p, beta = sqrt(1 - u^2): the Hertz window's
    projection along the probe / (pi a / 2) (dimensionless)."""
    b2 = np.clip(1.0 - u * u, 0.0, None)
    return b2 * _lam(kp * np.sqrt(b2))


def _poisson(u, delta):
    return delta / (np.pi * (u * u + delta * delta))


def _u_rule(delta, kmax, per_panel=20, panel=8.0):
    """Composite Gauss-Legendre rule on [0, 1]: geometric panels near 0 (Poisson peak of width
    delta) and panels no longer than panel / kmax (oscillation of cos(kappa_s u), y(u, kappa_p))."""
    edges = [0.0]
    x = min(delta, 1.0) / 8.0
    while x < 1.0:
        edges.append(x)
        x *= 1.6
    edges.append(1.0)
    lmax = min(panel / max(kmax, 1.0), 0.25)
    fine = [0.0]
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = int(np.ceil((hi - lo) / lmax))
        fine.extend(np.linspace(lo, hi, m + 1)[1:])
    e = np.array(fine)
    g, w = np.polynomial.legendre.leggauss(per_panel)
    lo, hi = e[:-1, None], e[1:, None]
    return (lo + (hi - lo) * (g + 1.0) / 2.0).ravel(), ((hi - lo) / 2.0 * w).ravel()


def hertz_reference(kappa_s, kappa_p, delta, per_panel=24, chunk=4000):
    """Reference Hn(kappa_s, kappa_p, delta) by composite Gauss-Legendre quadrature (numpy).

    Arguments broadcast; all dimensionless (kappa = k a, delta = d / a). Accurate to about
    1e-15 absolute for |kappa| up to a few thousand (checked against
    ``tactile_jax.window.hertz_line_response`` and against itself with more nodes).
    """
    ks, kp, dl = np.broadcast_arrays(*(np.asarray(v, float) for v in (kappa_s, kappa_p, delta)))
    out = np.empty(ks.shape)
    fs, fp, fd, fo = ks.ravel(), kp.ravel(), dl.ravel(), out.reshape(-1)
    for d in np.unique(fd):
        idx = np.nonzero(fd == d)[0]
        kmax = max(np.abs(fs[idx]).max(), np.abs(fp[idx]).max(), 1.0)
        u, w = _u_rule(d, kmax, per_panel)
        g = 2.0 * w * _poisson(u, d)
        for c in range(0, idx.size, chunk):
            ii = idx[c:c + chunk]
            fo[ii] = np.sum(np.cos(np.outer(fs[ii], u)) * _ywin(u[None, :], fp[ii, None]) * g, axis=1)
    return out


def _hn_slice(delta, kap_s, kap_p, per_panel=24, panel=14.0):
    """Hn on the outer grid kap_s x kap_p at one delta (numpy, one matrix product; 24-point panels
    spanning 14 / kmax: 1e-15 absolute, checked against ``hertz_reference`` with 40-point panels)."""
    kmax = max(kap_s.max(), kap_p.max(), 1.0)
    u, w = _u_rule(delta, kmax, per_panel, panel)
    c = np.cos(np.outer(kap_s, u)) * (2.0 * w * _poisson(u, delta))
    return c @ _ywin(u[:, None], kap_p[None, :])


@functools.lru_cache(maxsize=None)
def _bspline_poly(p):
    """Exact polynomial coefficients P (p+1 taps x p+1 powers of t) of the degree-p cardinal
    B-spline weights: tap k at fractional position t in [0, 1) has weight sum_m P[k, m] t^m and
    multiplies the B-spline centred at floor(x) - (p - 1)/2 + k."""
    from fractions import Fraction
    from math import comb, factorial
    P = np.zeros((p + 1, p + 1))
    for k in range(p + 1):
        coeffs = [Fraction(0)] * (p + 1)
        for j in range(p - k + 1):          # (t + s)^p with s = p - k - j >= 0
            s = p - k - j
            c = Fraction((-1) ** j * comb(p + 1, j), factorial(p))
            for m in range(p + 1):
                coeffs[m] += c * comb(p, m) * Fraction(s) ** (p - m)
        P[k] = [float(v) for v in coeffs]
    return P


def _prefilter(y, p, axis):
    """B-spline coefficients (length n + p - 1 along ``axis``) of the degree-p uniform spline that
    interpolates y at 0..n-1 (coefficient j belongs to the B-spline centred at j - (p-1)/2); the
    (p-1)/2 extra conditions at each end set the (p+1)-th difference of the coefficients to zero
    (not-a-knot)."""
    from math import comb
    y = np.moveaxis(np.asarray(y, float), axis, 0)
    n = y.shape[0]
    q = (p - 1) // 2
    m = n + p - 1
    bint = _bspline_poly(p)[:p, 0]                         # taps 0..p-1 at t = 0
    diff = np.array([(-1) ** (p + 1 - j) * comb(p + 1, j) for j in range(p + 2)], float)
    A = np.zeros((m, m))
    for r in range(q):
        A[r, r:r + p + 2] = diff
    for i in range(n):
        A[q + i, i:i + p] = bint
    for r in range(q):
        s0 = m - (p + 2) - (q - 1 - r)
        A[q + n + r, s0:s0 + p + 2] = diff
    op = np.linalg.inv(A)[:, q:q + n]                      # (m, n) solution operator
    c = np.tensordot(op, y, axes=(1, 0))                   # BLAS
    return np.moveaxis(c, 0, axis)


def build_table(degree=7, h=0.6, kmax=160.0, dt=0.07, delta_min=0.01, delta_max=5.0, verbose=False):
    """Build the B-spline coefficient table of Hn (numpy; see the module docstring).

    degree: odd B-spline degree. h: kappa spacing; kmax: table reach in |kappa_s| and |kappa_p|
    (dimensionless, kappa = k a). dt: spacing in log(delta); [delta_min, delta_max]: supported
    delta = d / a. Returns a dict of numpy arrays and floats (``coef``: (T, S, S) float64).
    """
    t0 = time.perf_counter()
    p = int(degree)
    assert p % 2 == 1
    n = int(np.ceil(kmax / h)) + 1 + _PAD_K
    kap = np.arange(n) * h
    tl = np.log(delta_min) - _PAD_T * dt
    nt = int(np.ceil((np.log(delta_max) + _PAD_T * dt - tl) / dt)) + 1
    tg = tl + dt * np.arange(nt)
    hn = np.empty((nt, n + _MIRROR, n + _MIRROR))
    for j, t in enumerate(tg):
        s = _hn_slice(np.exp(t), kap, kap)
        s = np.concatenate([s[_MIRROR:0:-1], s], axis=0)
        hn[j] = np.concatenate([s[:, _MIRROR:0:-1], s], axis=1)
    t1 = time.perf_counter()
    c = _prefilter(hn, p, 1)
    c = _prefilter(c, p, 2)
    c = _prefilter(c, p, 0)
    t2 = time.perf_counter()
    if verbose:
        print(f"hertz table: quadrature {t1 - t0:.2f} s, prefilter {t2 - t1:.2f} s, {c.nbytes / 1e6:.1f} MB")
    return dict(coef=c, degree=p, h=float(h), kmax=float(kmax), dt=float(dt), t0=float(tl),
                nt=int(nt), n=int(n), mirror=_MIRROR, delta_min=float(delta_min),
                delta_max=float(delta_max), version=TABLE_VERSION,
                build_seconds=float(t2 - t0))


def _cache_dir():
    d = os.environ.get("TACTILE_JAX_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "tactile_jax")
    os.makedirs(d, exist_ok=True)
    return d


# ----------------------------------------------------------------------------------------------
# JAX runtime
# ----------------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class _Meta:
    """Static (hashable) description of a table."""
    degree: int
    h: float
    kmax: float
    dt: float
    t0: float
    nt: int
    n: int
    mirror: int
    delta_min: float
    delta_max: float


class HertzTable(NamedTuple):
    """A built table: ``coef`` (T, S, S) B-spline coefficients (jax array) and static ``meta``."""
    coef: jax.Array
    meta: _Meta


_TABLES: dict = {}


def hertz_table(dtype=jnp.float32, cache=True, verbose=False, **params) -> HertzTable:
    """The table for ``params`` (defaults ``DEFAULT_PARAMS``): built once per process, cached on
    disk (float32) under $TACTILE_JAX_CACHE or ~/.cache/tactile_jax (``cache=False``: rebuild).

    dtype: storage dtype of the coefficients on the device (computation is in the inputs' dtype:
    float64 inputs give float64 slices and results; float32 storage adds ~1e-7 of the amplitude).
    """
    par = dict(DEFAULT_PARAMS)
    par.update(params)
    key = json.dumps(dict(par, version=TABLE_VERSION), sort_keys=True)
    mkey = (key, jnp.dtype(dtype).name)
    if cache and mkey in _TABLES:
        return _TABLES[mkey]
    tab = None
    path = os.path.join(_cache_dir(), f"hertz_{hashlib.sha1(key.encode()).hexdigest()[:16]}.npz") if cache else None
    if cache and os.path.exists(path):
        try:
            with np.load(path) as z:
                tab = {k: z[k] for k in z.files}
        except Exception:           # a damaged cache file is rebuilt
            tab = None
    if tab is None:
        tab = build_table(verbose=verbose, **par)
        if cache:       # stored in float32 (rounding 6e-8 relative)
            tmp = path + f".{os.getpid()}.tmp.npz"
            np.savez(tmp, **dict(tab, coef=tab["coef"].astype(np.float32)))
            os.replace(tmp, path)
    meta = _Meta(int(tab["degree"]), float(tab["h"]), float(tab["kmax"]), float(tab["dt"]), float(tab["t0"]),
                 int(tab["nt"]), int(tab["n"]), int(tab["mirror"]), float(tab["delta_min"]),
                 float(tab["delta_max"]))
    c = np.asarray(tab["coef"])
    out = HertzTable(jnp.asarray(c.reshape(c.shape[0], -1), dtype=dtype), meta)
    if cache:
        _TABLES[mkey] = out
    return out


def table_of(coef) -> HertzTable:
    """The default table with ``coef`` as its coefficients: how a compiled program, which takes the
    coefficients as data (``inference.core.Settings.hertz``), rebuilds the table with its static ``meta``."""
    return HertzTable(coef, hertz_table().meta)


def _side(coef) -> int:
    """S of coefficients ``coef`` (T, S * S): the grid positions along each axis of the table, or of its corner."""
    return int(round(np.sqrt(coef.shape[1])))


def corner(coef, kappa: float):
    """The default table's coefficients ``coef`` (T, S * S) cut to the corner that serves |kappa_s|, |kappa_p| <= kappa
    (T, n * n): lookups at such nodes read a slice n^2 / S^2 the size (``table_of`` takes them as they are). A kappa that
    reaches the far field's blend gets the whole table back."""
    meta = hertz_table().meta
    s = _side(coef)
    if kappa >= meta.kmax - _BLEND:
        return coef
    n = min(s, meta.mirror + int(np.ceil(kappa / meta.h)) + meta.degree + 2)
    return coef.reshape(coef.shape[0], s, s)[:, :n, :n].reshape(coef.shape[0], n * n)


def _weights(t, p):
    """B-spline weights at fractional positions t (lists of p+1 arrays shaped like t) and their
    t-derivatives (Horner with Python-float coefficients: fuses into one elementwise loop)."""
    P = _bspline_poly(p)
    w, dw = [], []
    for k in range(p + 1):
        c = P[k]
        v = float(c[p])
        d = float(c[p] * p)
        for m in range(p - 1, -1, -1):
            v = v * t + float(c[m])
            if m >= 1:
                d = d * t + float(c[m] * m)
        w.append(v)
        dw.append(d)
    return w, dw


def _slices(coef, meta: _Meta, delta):
    """Coefficient slices of Hn and dHn/d(delta) at the depths' delta (D,): (D, 2, S, S), in the
    compute dtype (that of delta; the stored table may be float32).

    coef: (T, S * S) table. One small matrix product per depth: a dot is never fused into the
    gather that reads the slices (an elementwise sum would be, and then recomputed for every
    gathered element), and it keeps the computations of repeated jvp's identical (CSE-able).
    Weights and accumulation are in the compute dtype, so that Hn is smooth in delta (float32
    weights would add rounding noise of 6e-8 |Hn| that finite differences in a see).
    """
    p = meta.degree
    dt = delta.dtype
    tt = jnp.log(jnp.clip(delta, meta.delta_min, meta.delta_max))
    x = (tt - meta.t0) / meta.dt
    i = jnp.clip(jnp.floor(x), 0, meta.nt - 2)
    w, dw = _weights(x - i, p)                                   # lists of (D,)
    inside = (delta > meta.delta_min) & (delta < meta.delta_max)
    scale = jnp.where(inside, 1.0 / (meta.dt * delta), 0.0)     # d t / d delta
    ii = i.astype(jnp.int32)
    s = _side(coef)
    vals, ders = [], []
    for k in range(delta.shape[0]):
        wk = jnp.stack([jnp.stack([w[m][k] for m in range(p + 1)]),
                        jnp.stack([dw[m][k] * scale[k] for m in range(p + 1)])])
        blk = lax.dynamic_slice_in_dim(coef, ii[k], p + 1, axis=0).astype(dt)   # (p+1, S*S)
        sl = jnp.dot(wk, blk, precision=lax.Precision.HIGHEST).reshape(2, s, s)
        # delta > delta_max (unsupported): the leading 1/delta law, Hn(delta) ~ Hn(delta_max) delta_max / delta
        big = delta[k] > meta.delta_max
        r = jnp.where(big, meta.delta_max / delta[k], 1.0)
        vals.append(sl[0] * r)
        ders.append(jnp.where(big, -sl[0] * r / delta[k], sl[1]))
    # the delta-derivative only feeds tangents: stored at the table's precision (cheaper gather)
    return jnp.stack(vals), jnp.stack(ders).astype(coef.dtype)


def _value_slices(coef, meta: _Meta, delta):
    """The coefficient slices of Hn alone at the depths' delta (D,), interleaved: (S, S, D), in the lower of the
    table's and delta's precisions."""
    # one contraction writes them in that order: on the whole table 0.10 ms a walker, against 0.19 ms for
    # ``_slices`` (with the delta-derivative's slices) and a transpose. A table kept in float32 (a sampler's corner)
    # gives float32 slices: half the bytes for each node's gather to read, which is most of a float64 walker's
    # lookup where the slices outgrow the cache (a 2.5 mm disk's: the whole table)
    p = meta.degree
    dt = coef.dtype if jnp.finfo(coef.dtype).bits < jnp.finfo(delta.dtype).bits else delta.dtype
    x = (jnp.log(jnp.clip(delta, meta.delta_min, meta.delta_max)) - meta.t0) / meta.dt
    i = jnp.clip(jnp.floor(x), 0, meta.nt - 2)
    w = jnp.stack(_weights(x - i, p)[0], axis=-1)                             # (D, p+1)
    # delta > delta_max (unsupported): the leading 1/delta law, as in ``_slices``
    w = (w * jnp.where(delta > meta.delta_max, meta.delta_max / delta, 1.0)[:, None]).astype(dt)
    blk = jnp.stack([lax.dynamic_slice_in_dim(coef, i[k].astype(jnp.int32), p + 1, axis=0)
                     for k in range(delta.shape[0])]).astype(dt)              # (D, p+1, S*S)
    s = _side(coef)
    return jnp.einsum("dm,dmn->nd", w, blk, precision=lax.Precision.HIGHEST).reshape(s, s, delta.shape[0])


#: nodes per chunk of the table lookup: each chunk's gathered blocks (value in float64, the delta-derivative in
#: the table's float32: 4 x 4 x 12 bytes a node, 1.5 MB) stay in cache until contracted, and a vmapped chunk of
#: 1,024 records holds 1.6 GB of them at a time (all of a record's 46,000 nodes at once: 9 GB); on the CPU
#: one chunk of all the nodes is 5 % faster (``python benchmarks/hertz_lookup.py``)
CHUNK = 8192


def _block_sums(meta: _Meta, sl_v, sl_d, dep, xs, xp, dt):
    """Hn and its partials in (kappa_s, kappa_p, delta) at flat nodes: dep (n,) depth index, xs, xp (n,)
    grid positions |kappa| / h (capped), from the coefficient slices (D, S, S) of Hn and dHn/d(delta).
    Four separate outputs (one loop computes them; stacked, each element would redo the shared sums)."""
    p = meta.degree
    off = meta.mirror                                             # coefficient index of tap 0 at kappa = 0
    i_s, i_p = jnp.floor(xs), jnp.floor(xp)
    ws, dws = _weights(xs - i_s, p)
    wp, dwp = _weights(xp - i_p, p)
    idx = jnp.stack([dep, i_s.astype(jnp.int32) + off, i_p.astype(jnp.int32) + off], axis=-1)
    dnums = lax.GatherDimensionNumbers(offset_dims=(0, 1), collapsed_slice_dims=(0,), start_index_map=(0, 1, 2))
    bv = lax.gather(sl_v, idx, dnums, slice_sizes=(1, p + 1, p + 1),
                    mode=lax.GatherScatterMode.PROMISE_IN_BOUNDS)    # (p+1, p+1, n)
    bd = lax.gather(sl_d, idx, dnums, slice_sizes=(1, p + 1, p + 1),
                    mode=lax.GatherScatterMode.PROMISE_IN_BOUNDS)
    r0 = [sum(wp[j] * bv[i, j] for j in range(p + 1)) for i in range(p + 1)]
    rp = [sum(dwp[j] * bv[i, j] for j in range(p + 1)) for i in range(p + 1)]
    r1 = [sum(wp[j] * bd[i, j].astype(dt) for j in range(p + 1)) for i in range(p + 1)]
    val = sum(ws[i] * r0[i] for i in range(p + 1))
    d_s = sum(dws[i] * r0[i] for i in range(p + 1)) / meta.h
    d_p = sum(ws[i] * rp[i] for i in range(p + 1)) / meta.h
    d_d = sum(ws[i] * r1[i] for i in range(p + 1))
    return val, d_s, d_p, d_d


def _cap(meta: _Meta, coef):
    """The largest grid position |kappa| / h the coefficients ``coef`` (T, S * S) serve: the table's kmax, or less
    for coefficients cut to a corner of the table (``corner``)."""
    s = _side(coef)
    return float(min(meta.kmax / meta.h, s - meta.mirror - meta.degree - 1))


def _off_corner(meta: _Meta, cap: float, kappa_s, kappa_p, values):
    """``values`` with NaN at the nodes beyond a corner of the table (|kappa_s| or |kappa_p| above what ``cap``
    serves): there they would read the corner's edge. On the whole table, ``values`` as they are."""
    if cap >= meta.kmax / meta.h:
        return values
    beyond = (kappa_s > cap * meta.h) | (kappa_p > cap * meta.h)
    return tuple(jnp.where(beyond, jnp.nan, v) for v in values)


def _chunked(fn, *flat):
    """``fn`` over the flat node arrays ``flat`` (n,), ``CHUNK`` nodes at a time (``lax.map`` over padded chunks):
    its outputs (..., size) back as (..., n)."""
    n = flat[0].shape[0]
    chunks = max(1, -(-n // CHUNK))
    size = -(-n // chunks)
    out = lax.map(lambda c: fn(*c), [jnp.pad(x, (0, chunks * size - n)).reshape(chunks, size) for x in flat])
    return jax.tree.map(lambda o: jnp.moveaxis(o, 0, -2).reshape(o.shape[1:-1] + (-1,))[..., :n], out)


def _core(meta: _Meta, depth_index, ks, kp, depths, a, coef):
    """Hn and its partials in (kappa_s, kappa_p, delta) at the nodes: 4 arrays shaped like ks
    (inside the table; the caller applies the cut-off). The nodes are looked up ``CHUNK`` at a time."""
    dt = jnp.result_type(ks, kp, depths, a, float)
    a = jnp.asarray(a, dt)
    kappa_s, kappa_p = jnp.abs(ks.astype(dt) * a), jnp.abs(kp.astype(dt) * a)
    delta = jnp.asarray(depths, dt) / a
    sl_v, sl_d = _slices(coef, meta, delta)                      # (D, S, S) each
    cap = _cap(meta, coef)
    xs = jnp.minimum(kappa_s / meta.h, cap).ravel()
    xp = jnp.minimum(kappa_p / meta.h, cap).ravel()
    dep = jnp.broadcast_to(jnp.asarray(depth_index, jnp.int32).reshape((-1,) + (1,) * (ks.ndim - 1)),
                           ks.shape).ravel()
    out = _chunked(lambda *c: _block_sums(meta, sl_v, sl_d, *c, dt), dep, xs, xp)
    return _off_corner(meta, cap, kappa_s, kappa_p, tuple(o.reshape(ks.shape) for o in out))


def hertz_hn_depths(k_s, k_p, depths, a, table: HertzTable):
    """Hn at every depth (D, G, ...) for the positions (k_s, k_p) (G, ...) rad/m: one gather a node serves all the
    depths (their slices interleaved), for the values alone (no tangents; the far field and delta below the table
    as in ``hertz_hn``). A corner of the table (``corner``) gives NaN beyond it."""
    meta, coef = table.meta, table.coef
    dt = jnp.result_type(k_s, k_p, depths, a, float)
    a = jnp.asarray(a, dt)
    depths = jnp.asarray(depths, dt)
    delta = depths / a
    p = meta.degree
    sl = _value_slices(coef, meta, delta)                                   # (S, S, D)
    cap = _cap(meta, coef)
    ks = jnp.abs(jnp.asarray(k_s, dt) * a)
    kp = jnp.abs(jnp.asarray(k_p, dt) * a)
    xs = jnp.minimum(ks / meta.h, cap).ravel()
    xp = jnp.minimum(kp / meta.h, cap).ravel()
    dnums = lax.GatherDimensionNumbers(offset_dims=(0, 1, 2), collapsed_slice_dims=(), start_index_map=(0, 1))

    def block(xs, xp):
        i_s, i_p = jnp.floor(xs), jnp.floor(xp)
        ws = _weights(xs - i_s, p)[0]
        wp = _weights(xp - i_p, p)[0]
        idx = jnp.stack([i_s.astype(jnp.int32) + meta.mirror, i_p.astype(jnp.int32) + meta.mirror], axis=-1)
        b = lax.gather(sl, idx, dnums, slice_sizes=(p + 1, p + 1, depths.shape[0]),
                       mode=lax.GatherScatterMode.PROMISE_IN_BOUNDS)            # (p+1, p+1, D, size)
        return sum(ws[i] * sum(wp[j] * b[i, j] for j in range(p + 1)) for i in range(p + 1))   # (D, size)

    val = _chunked(block, xs, xp).reshape((depths.shape[0],) + ks.shape)
    val = _off_corner(meta, cap, ks, kp, (val,))[0]
    depth_index = tuple(i for i in range(depths.shape[0]) for _ in range(ks.shape[0]))
    rep = lambda x: jnp.broadcast_to(x, (depths.shape[0],) + x.shape).reshape((-1,) + x.shape[1:])   # noqa: E731
    out = _finish(meta, depth_index, True, rep(jnp.asarray(k_s, dt)), rep(jnp.asarray(k_p, dt)), depths, a,
                  *(val.reshape((-1,) + ks.shape[1:]),) * 4, far_nodes=cap * meta.h > meta.kmax - _BLEND)[0]
    return out.reshape((depths.shape[0],) + ks.shape)


# ----------------------------------------------------------------------------------------------
# analytic pieces: the pole ("bulk") term and the large-kappa far field, with their partials
# ----------------------------------------------------------------------------------------------

class _D:
    """Forward-mode value: v and its partials d = (d/d kappa_s, d/d kappa_p, d/d delta)."""
    __slots__ = ("v", "d")
    __array_ufunc__ = None          # numpy scalars defer to our operators

    def __init__(self, v, d):
        self.v = v
        self.d = tuple(d)

    def __add__(self, o):
        if isinstance(o, _D):
            return _D(self.v + o.v, tuple(a + b for a, b in zip(self.d, o.d)))
        return _D(self.v + o, self.d)

    __radd__ = __add__

    def __neg__(self):
        return _D(-self.v, tuple(-a for a in self.d))

    def __sub__(self, o):
        return self + (-o)

    def __rsub__(self, o):
        return (-self) + o

    def __mul__(self, o):
        if isinstance(o, _D):
            return _D(self.v * o.v, tuple(a * o.v + self.v * b for a, b in zip(self.d, o.d)))
        return _D(self.v * o, tuple(a * o for a in self.d))

    __rmul__ = __mul__

    def __truediv__(self, o):
        if isinstance(o, _D):
            inv = 1.0 / o.v
            q = self.v * inv
            return _D(q, tuple((a - q * b) * inv for a, b in zip(self.d, o.d)))
        return _D(self.v / o, tuple(a / o for a in self.d))

    def __rtruediv__(self, o):
        inv = 1.0 / self.v
        q = o * inv
        return _D(q, tuple(-q * inv * a for a in self.d))

    def fn(self, f, df):
        """f(self) given f's value f and derivative df at self.v."""
        return _D(f, tuple(df * a for a in self.d))

    @property
    def real(self):
        return _D(self.v.real, tuple(a.real for a in self.d))


def _dsqrt(x: _D):
    r = jnp.sqrt(x.v)
    return x.fn(r, 0.5 / r)


def _dexp(x: _D):
    e = jnp.exp(x.v)
    return x.fn(e, e)


_PIO2 = (1.57079632673412561417e+00, 6.07710050650619224932e-11, 2.02226624879595063154e-21)


def _sincos(x):
    """sin and cos (elementwise arithmetic: vectorises on CPU, 4x faster than jnp.sin + jnp.cos)."""
    n = jnp.round(x * _2_PI)
    r = ((x - n * _PIO2[0]) - n * _PIO2[1]) - n * _PIO2[2]
    r2 = r * r
    s = r * (1 + r2 * (-1 / 6 + r2 * (1 / 120 + r2 * (-1 / 5040 + r2 * (1 / 362880 + r2 * (
        -1 / 39916800 + r2 * (1 / 6227020800 + r2 * (-1 / 1307674368000 + r2 * (1 / 355687428096000)))))))))
    c = 1 + r2 * (-0.5 + r2 * (1 / 24 + r2 * (-1 / 720 + r2 * (1 / 40320 + r2 * (
        -1 / 3628800 + r2 * (1 / 479001600 + r2 * (-1 / 87178291200 + r2 * (1 / 20922789888000))))))))
    q = n.astype(jnp.int32) & 3
    sin = jnp.where(q == 0, s, jnp.where(q == 1, c, jnp.where(q == 2, -s, -c)))
    cos = jnp.where(q == 0, c, jnp.where(q == 1, -s, jnp.where(q == 2, -c, s)))
    return sin, cos


def _dsincos(x: _D):
    s, c = _sincos(x.v)
    return x.fn(s, c), x.fn(c, -s)


def _dcis(x: _D):
    """exp(i x) for real x."""
    s, c = _sincos(x.v)
    e = c + 1j * s
    return x.fn(e, 1j * e)


_LAM_H = 0.25          # grid of the Lambda table (quintic B-spline): relative error ~1e-9
_LAM_ZMAX = 20000.0    # beyond: Lambda taken as 0 (|Lambda| < 6e-7 there)


@functools.lru_cache(maxsize=None)
def _lam_table():
    """Quintic B-spline coefficients of Lambda(z) = 2 J1(z) / z on z = 0, 0.25, ..., 20000 + pad
    (Lambda is even: mirrored below 0). Built once per process (numpy/scipy, ~0.05 s)."""
    from scipy.ndimage import spline_filter1d
    n = int(_LAM_ZMAX / _LAM_H) + 64
    z = np.arange(-16, n) * _LAM_H
    c = spline_filter1d(_lam(np.abs(z)), order=5, mode="mirror")
    return c                                                # coefficient of knot z_j at index j + 16


def _dlam(z: _D):
    """Lambda(z) = 2 J1(z) / z for z >= 0 with its derivative, from a 1-D quintic spline table."""
    c = jnp.asarray(_lam_table(), z.v.dtype)
    x = jnp.clip(z.v, 0.0, _LAM_ZMAX) / _LAM_H
    i = jnp.floor(x)
    w, dw = _weights(x - i, 5)
    j0 = i.astype(jnp.int32) + 16 - 2                       # taps: knots i-2 .. i+3
    vals = [jnp.take(c, j0 + k, mode="clip") for k in range(6)]
    v = sum(w[k] * vals[k] for k in range(6))
    dv = sum(dw[k] * vals[k] for k in range(6)) / _LAM_H
    out = z.v <= _LAM_ZMAX
    return z.fn(jnp.where(out, v, 0.0), jnp.where(out, dv, 0.0))


def _lam_j(z):
    return _dlam(_D(z, ())).v


def _dbulk(ks: _D, kp: _D, delta: _D):
    """Pole term exp(-kappa_s delta) (1 + delta^2) Lambda(kappa_p sqrt(1 + delta^2)), kappa >= 0."""
    bp2 = 1.0 + delta * delta
    return _dexp(-(ks * delta)) * bp2 * _dlam(kp * _dsqrt(bp2))


def _bulk(ks, kp, delta):
    z = ()
    return _dbulk(_D(ks, z), _D(kp, z), _D(jnp.asarray(delta), z)).v


@functools.lru_cache(maxsize=None)
def _weideman(n=12):
    m = 2 * n
    k = np.arange(-m + 1, m)
    ell = np.sqrt(n / np.sqrt(2.0))
    t = ell * np.tan(k * np.pi / m / 2.0)
    f = np.concatenate([[0.0], np.exp(-t ** 2) * (ell ** 2 + t ** 2)])
    a = np.real(np.fft.fft(np.fft.fftshift(f))) / (2 * m)
    return float(ell), tuple(float(v) for v in np.flipud(a[1:n + 1]))


def _faddeeva_upper(z, n=12, deriv=False):
    """w(z) = exp(-z^2) erfc(-i z) for Im z >= 0 (Weideman 1994; n = 12: relative error < 2e-5,
    ample for the leading-order far field); with deriv, also the exact derivative of this
    rational approximation (so that tangents match finite differences of it)."""
    ell, a = _weideman(n)
    den = ell - 1j * z
    inv = 1.0 / den
    zz = (ell + 1j * z) * inv
    p = jnp.zeros_like(zz)
    dp = jnp.zeros_like(zz)
    for ak in a:
        dp = dp * zz + p
        p = p * zz + ak
    inv2 = inv * inv
    w = 2.0 * p * inv2 + _1_SQRT_PI * inv
    if not deriv:
        return w
    # dZ/dz = 2 i ell / den^2, d(den)/dz = -i
    dw = 2.0 * dp * (2j * ell) * inv2 * inv2 + 4j * p * inv2 * inv + (1j * _1_SQRT_PI) * inv2
    return w, dw


def _dw(z: _D):
    w, dw = _faddeeva_upper(z.v, deriv=True)
    return z.fn(w, dw)


def _dsmoothstep(x: _D):
    xc = jnp.clip(x.v, 0.0, 1.0)
    inside = (x.v > 0.0) & (x.v < 1.0)
    return x.fn(xc * xc * xc * (10.0 + xc * (-15.0 + 6.0 * xc)),
                jnp.where(inside, 30.0 * xc * xc * (1.0 - xc) * (1.0 - xc), 0.0))


def _dfar(ks: _D, kp: _D, delta: _D):
    """Leading large-kappa form of Hn with partials (kappa_s, kappa_p >= 0, kappa >~ 100).

    Near the kappa_s axis: exact pole term + the disk edge's stationary point,
    bulk - 4 P_delta(u0) cos(kappa) / kappa^2, u0 = kappa_s / kappa.  Near the kappa_p axis: the
    probe's Poisson kernel against the Fresnel zone of the window's edge (Faddeeva functions
    w(z1), w(z2)), with the quadratic-phase pole term exchanged for the exact one across its
    Stokes line u0 = delta.  Blended across the diagonal.  About 1e-2 of the local amplitude at
    kappa ~ 130, 1e-3 (median) further out.
    """
    kap = _dsqrt(ks * ks + kp * kp + 1.0)                  # +1: no 0/0 where unused (kappa < 100)
    u0 = ks / kap
    bulk = _dbulk(ks, kp, delta)
    cis = _dcis(kap)
    cs = cis.real
    u2d2 = u0 * u0 + delta * delta
    f_a = bulk - _4_PI * delta * cs / (u2d2 * kap * kap)
    # kappa_p-dominated side
    kps = _D(jnp.maximum(kp.v, 1.0), kp.d)
    al = kap * kap * kap / (2.0 * kps * kps)
    sq = _dsqrt(al * 0.5)
    dm, dp = delta - u0, delta + u0
    lower = u0.v > delta.v
    sgn = jnp.where(lower, -1.0, 1.0)                      # evaluate w in the upper half plane
    z1u = (sq * (-dp) + (sq * dm) * 1j) * sgn
    w1u = _dw(z1u)
    m1 = -(sq * sq) * ((dm * 1j - dp) * (dm * 1j - dp))    # -z1^2: real part -2 al delta u0 <= 0
    er = _dexp(m1.real)
    ci = _dcis(_D(m1.v.imag, tuple(a.imag for a in m1.d)))
    e1 = er * ci
    w1 = _D(jnp.where(lower, 2.0 * e1.v - w1u.v, w1u.v),
            tuple(jnp.where(lower, 2.0 * a - b, b) for a, b in zip(e1.d, w1u.d)))
    w2 = _dw(sq * dm * (-1.0) + sq * dp * 1j)
    c0 = _C0 / (kps * _dsqrt(kap))
    ph = c0 * cis * _E_3PI4
    # Stokes switch (exact pole term beyond u0 = delta); width ~ 1 / sqrt(al) in u0
    chi = _dsmoothstep((u0 - delta) * _dsqrt(al) * (1.0 / 3.0) + 0.5)
    f_b = (ph * ((w1 + w2) * 0.5 - chi * e1)).real + chi * bulk
    wb = _dsmoothstep((kp / (ks + kp + 1e-30) - 0.4) * 5.0)
    return f_a + wb * (f_b - f_a)


def _far(ks, kp, delta):
    z = tuple(jnp.zeros_like(ks) for _ in range(3))
    return _dfar(_D(ks, z), _D(kp, z), _D(jnp.broadcast_to(jnp.asarray(delta, ks.dtype), ks.shape), z)).v


def _unit(x, i):
    z = jnp.zeros_like(x)
    return _D(x, tuple(jnp.ones_like(x) if j == i else z for j in range(3)))


def _far_and_partials(ks, kp, delta):
    delta = jnp.broadcast_to(delta, ks.shape)
    r = _dfar(_unit(ks, 0), _unit(kp, 1), _unit(delta, 2))
    return (r.v,) + tuple(r.d)


def _bulk_and_partials(ks, kp, delta):
    delta = jnp.broadcast_to(delta, ks.shape)
    r = _dbulk(_unit(ks, 0), _unit(kp, 1), _unit(delta, 2))
    return (r.v,) + tuple(r.d)


_BLEND = 12.0     # width (kappa units) of the table -> far-field blend at the table's edge


def _all(meta: _Meta, depth_index, far_field, ks, kp, depths, a, coef):
    """Hn and its partials (kappa_s, kappa_p, delta) at the nodes, everything included."""
    return _finish(meta, depth_index, far_field, ks, kp, depths, a, *_core(meta, depth_index, ks, kp, depths, a, coef))


def _finish(meta: _Meta, depth_index, far_field, ks, kp, depths, a, val, g_s, g_p, g_d, far_nodes=True):
    """The table's Hn and partials at the nodes with delta below the table and the far field beyond it applied
    (``far_nodes`` False: no node reaches the far field's blend, as on a corner of the table)."""
    dt = val.dtype
    a = jnp.asarray(a, dt)
    delta_d = jnp.asarray(depths, dt) / a
    shape1 = (-1,) + (1,) * (val.ndim - 1)
    delta = jnp.broadcast_to(delta_d[jnp.asarray(depth_index)].reshape(shape1), val.shape)
    ks_ = jnp.abs(ks.astype(dt) * a)
    kp_ = jnp.abs(kp.astype(dt) * a)
    # blend table -> far field over m in [kmax - _BLEND, kmax], m = || (kappa_s, kappa_p) ||_8
    ns, np_ = ks_ / meta.kmax, kp_ / meta.kmax
    n8 = jnp.square(jnp.square(jnp.square(ns))) + jnp.square(jnp.square(jnp.square(np_)))
    m = meta.kmax * jnp.sqrt(jnp.sqrt(jnp.sqrt(n8)))       # n8^(1/8): three roots cost less than a power
    lo = meta.kmax - _BLEND

    def small(val, g_s, g_p, g_d):
        # delta below the table: exact pole term, the rest scaled linearly in delta
        # (Hn - pole = delta R(delta^2) with R smooth in delta^2)
        dc = jnp.maximum(delta, meta.delta_min)
        b, b_s, b_p, b_d = _bulk_and_partials(ks_, kp_, delta)
        bc, bc_s, bc_p, _ = _bulk_and_partials(ks_, kp_, dc)
        r = delta / dc
        low = delta < meta.delta_min
        return (jnp.where(low, b + r * (val - bc), val), jnp.where(low, b_s + r * (g_s - bc_s), g_s),
                jnp.where(low, b_p + r * (g_p - bc_p), g_p), jnp.where(low, b_d + (val - bc) / dc, g_d))

    def far(val, g_s, g_p, g_d):
        # far field (or 0: the cut-off), blended in over the table's last _BLEND units
        if far_field:
            f, f_s, f_p, f_d = _far_and_partials(ks_, kp_, delta)
        else:
            f = f_s = f_p = f_d = jnp.zeros_like(val)
        x = jnp.clip((m - lo) / _BLEND, 0.0, 1.0)
        beta = x * x * x * (10.0 + x * (-15.0 + 6.0 * x))
        dbeta = 30.0 * x * x * (1.0 - x) * (1.0 - x) / _BLEND
        safe_m = jnp.maximum(m, 1e-30)
        dm_s = jnp.power(ks_ / safe_m, 7)
        dm_p = jnp.power(kp_ / safe_m, 7)
        diff = f - val
        keep = 1.0 - beta      # (1 - beta) v + beta f: no cancellation against the clamped table value
        return (keep * val + beta * f, keep * g_s + beta * f_s + diff * dbeta * dm_s,
                keep * g_p + beta * f_p + diff * dbeta * dm_p, keep * g_d + beta * f_d)

    # each evaluated only when some node needs it (conditionals: skipped at run time otherwise; under vmap
    # when some record of the chunk does: each branch changes only the nodes that need it)
    args = (val, g_s, g_p, g_d)
    args = lax.cond(any_in_batch(lax.stop_gradient(delta_d) < meta.delta_min), small, lambda *x: x, *args)
    if not far_nodes:
        return args
    return lax.cond(any_in_batch(lax.stop_gradient(m) > lo), far, lambda *x: x, *args)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 1, 2))
def _hn(meta, depth_index, far_field, ks, kp, depths, a, coef):
    return _all(meta, depth_index, far_field, ks, kp, depths, a, coef)[0]


@_hn.defjvp
def _hn_jvp(meta, depth_index, far_field, primals, tangents):
    ks, kp, depths, a, coef = primals
    dks, dkp, ddep, da, _ = tangents
    return _tangent(depth_index, ks, kp, depths, a, _all(meta, depth_index, far_field, ks, kp, depths, a, coef),
                    dks, dkp, ddep, da)


def _tangent(depth_index, ks, kp, depths, a, lookup, dks, dkp, ddep, da):
    """Hn and its tangent from the lookup's value and partials in (kappa_s, kappa_p, delta)."""
    val, d_s, d_p, d_d = lookup
    dt = val.dtype
    a = jnp.asarray(a, dt)
    shape1 = (-1,) + (1,) * (val.ndim - 1)
    di = jnp.asarray(depth_index)
    d = jnp.asarray(depths, dt)[di].reshape(shape1)
    dd = jnp.asarray(ddep, dt)[di].reshape(shape1)
    da = jnp.asarray(da, dt)
    g_s = d_s * jnp.sign(ks)
    g_p = d_p * jnp.sign(kp)
    tan = (g_s * (a * dks + ks * da) + g_p * (a * dkp + kp * da)
           + d_d * (dd / a - d * da / (a * a)))
    return val, tan.astype(val.dtype)


class Lookup(NamedTuple):
    """Hn at nodes and its partials in (kappa_s, kappa_p, delta), from one table lookup (``hertz_lookup``)."""

    val: jax.Array
    d_s: jax.Array
    d_p: jax.Array
    d_d: jax.Array


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def _hn_given(depth_index, ks, kp, depths, a, lookup):
    return lookup.val


@_hn_given.defjvp
def _hn_given_jvp(depth_index, primals, tangents):
    ks, kp, depths, a, lookup = primals
    dks, dkp, ddep, da, _ = tangents
    return _tangent(depth_index, ks, kp, depths, a, lookup, dks, dkp, ddep, da)


def _default_depth_index(k_s, depths):
    nd = np.shape(depths)[0]
    nc = np.shape(k_s)[0]
    if nc == nd:
        return tuple(range(nd))
    if nd == 2 and nc == 4:
        return (0, 1, 0, 1)
    raise ValueError("give depth_index (channel -> depth) for these shapes")


def hertz_hn(k_s, k_p, depths, a, table: HertzTable | None = None, depth_index=None,
             far_field: bool = True, lookup: Lookup | None = None):
    """Normalised Hertz line response Hn = H / (pi a / 2) (signed, dimensionless) at the nodes.

    k_s: (C, ...) wavenumber along each channel's sensitive axis, rad/m (x pair: kx, y pair: ky).
    k_p: (C, ...) wavenumber along the probe, rad/m (x pair: ky, y pair: kx).
    depths: (D,) probe depths, m. a: contact radius (scalar), m.
    depth_index: static tuple, channel -> depth (default: identity if C = D, (0, 1, 0, 1) if
    C = 4 and D = 2). far_field: static; False replaces the large-kappa asymptote beyond the table
    by a smooth cut-off to 0 (cheaper when nodes reach beyond kappa ~ 148).
    Differentiable (forward and reverse mode) in k_s, k_p, depths and a; the result has the
    floating dtype of the inputs (float32 in, float32 out). lookup: ``hertz_lookup`` at these nodes (None: looked
    up here); Hn and its tangents then come from it.
    """
    depth_index = _default_depth_index(k_s, depths) if depth_index is None else tuple(depth_index)
    k_s, k_p = jnp.broadcast_arrays(jnp.asarray(k_s), jnp.asarray(k_p))
    if lookup is not None:
        return _hn_given(depth_index, k_s, k_p, jnp.asarray(depths), jnp.asarray(a), lookup)
    table = hertz_table() if table is None else table
    return _hn(table.meta, depth_index, bool(far_field), k_s, k_p, jnp.asarray(depths), jnp.asarray(a),
               table.coef)


def _envelope(ks, kp, delta):
    """env (see ``hertz_log_envelope``) from dimensionless kappa_s, kappa_p, delta."""
    d2 = delta * delta
    h0 = (1.0 + d2) * _2_PI * jnp.arctan(1.0 / delta) - _2_PI * delta
    ks2, kp2 = ks * ks, kp * kp
    q = jnp.sqrt(jnp.sqrt(1.0 + kp2 * ((1.0 + d2) / 6.5)))
    bulk = jnp.exp(-delta * (jnp.sqrt(ks2 + 1.0) - 1.0)) * (h0 / (q * q * q))
    edge = _4_PI * delta / (ks2 + d2 * (ks2 + kp2) + (1.0 + d2))
    return bulk + edge


def hertz_log_envelope(k_s, k_p, depth, a):
    """log env, a smooth positive envelope of |Hn| (dimensionless).

    k_s, k_p: wavenumbers (rad/m); depth: probe depth (m); a: contact radius (m); broadcast
    (give depth per channel, shape (C, 1, ...), so that its constants are computed per channel).
    env = bulk + edge with
      bulk = exp(-delta (sqrt(kappa_s^2 + 1) - 1)) H0 (1 + kappa_p^2 (1 + delta^2) / 6.5)^(-3/4)
             (the pole term exp(-|kappa_s| delta) y(i delta, kappa_p), smoothed at kappa_s = 0, scaled
             to H0 = Hn(0, 0, delta) = (1 + delta^2) (2/pi) atan(1/delta) - 2 delta / pi),
      edge = 4 delta / (pi (kappa_s^2 + delta^2 kappa^2 + 1 + delta^2))
             (the disk edge's stationary point, 4 P_delta(kappa_s / kappa) / kappa^2, regularised).
    Measured: |Hn| / env < 1.6, local amplitude / env in [0.06, 1.9]. Cost per node: 3 sqrt,
    1 exp, 1 log.
    """
    k_s, k_p, depth, a = (jnp.asarray(v) for v in (k_s, k_p, depth, a))
    dt = jnp.result_type(k_s, k_p, depth, a, float)
    return jnp.log(_envelope((k_s * a).astype(dt), (k_p * a).astype(dt), (depth / a).astype(dt)))


def hertz_lookup(k_s, k_p, depths, a, table: HertzTable | None = None, depth_index=None,
                 far_field: bool = True) -> Lookup:
    """Hn and its partials at the nodes, looked up once, as constants (no tangents flow through them): give
    them to ``hertz_factors(..., lookup=)`` at the same nodes, so that several tangents of the factors
    (a forward-mode Jacobian) cost one lookup. Same arguments as ``hertz_hn``."""
    table = hertz_table() if table is None else table
    depth_index = _default_depth_index(k_s, depths) if depth_index is None else tuple(depth_index)
    k_s, k_p = jnp.broadcast_arrays(jnp.asarray(k_s), jnp.asarray(k_p))
    out = _all(table.meta, depth_index, bool(far_field), k_s, k_p, jnp.asarray(depths), jnp.asarray(a), table.coef)
    return Lookup(*(lax.stop_gradient(x) for x in out))


def hertz_factors(k_s, k_p, depths, a, table: HertzTable | None = None, depth_index=None,
                  far_field: bool = True, lookup: Lookup | None = None):
    """Channel factors for a log-space line integral: (log_env, mant) with Hn = mant * exp(log_env).

    Same arguments as ``hertz_hn``. log_env (C, ...) is the analytic envelope
    (``hertz_log_envelope``) at each channel's depth; mant = Hn / env is signed, |mant| < 1.6.
    An entry of the spectral matrix is then the signed sum
    sum_n exp(base_n + log_env_i + log_env_j) mant_i mant_j, whose tangents are finite everywhere
    (log|Hn| would have infinite tangents at the zeros of Hn).
    lookup: ``hertz_lookup`` at these nodes (None: looked up here); Hn and its tangents then come from it.
    """
    depth_index = _default_depth_index(k_s, depths) if depth_index is None else tuple(depth_index)
    if lookup is None:
        hn = hertz_hn(k_s, k_p, depths, a, table, depth_index, far_field)
    else:
        k_s, k_p = jnp.broadcast_arrays(jnp.asarray(k_s), jnp.asarray(k_p))
        hn = _hn_given(depth_index, k_s, k_p, jnp.asarray(depths), jnp.asarray(a), lookup)
    dt = hn.dtype
    a = jnp.asarray(a, dt)
    d = jnp.asarray(depths, dt)[jnp.asarray(depth_index)].reshape((-1,) + (1,) * (hn.ndim - 1))
    env = _envelope(jnp.asarray(k_s, dt) * a, jnp.asarray(k_p, dt) * a, d / a)
    return jnp.log(env), hn / env
