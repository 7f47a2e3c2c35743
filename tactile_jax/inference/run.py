"""Running the analysis: records from signals or spectra, the compiled programs, one or many at a time.

Every program here is compiled once per process (and kept in the persistent
cache where the caller enables one), whatever the recordings' lengths, segment
lengths or band widths: their inputs have fixed shapes (``segments``). ``fit``
and ``batch`` run one program, ``analysis.analyse``: ``analyse_one`` on one
record, ``analyse_many`` on a chunk (vmapped on an accelerator, record after
record on a CPU, where ``batch`` spreads the chunks over processes);
``refit_analysis`` runs it from a given point with every choice held, for
``fit``'s extras (profiles, ``model="auto"``). ``fit_one`` runs one window's
single solve (``core.core``), for studies of that step alone.
"""

from __future__ import annotations

import functools
import math
import os

import jax
import jax.numpy as jnp
import numpy as np

from ..spectral import band as band_mod
from .analysis import Analysis, Choices, Stages, summary_of
from .analysis import analyse as _analyse
from .core import (HERTZ_PER_GAUSS, ITERATIONS as ITERATIONS, INDEX, Errors, Located, Record, Settings, Start, Summary,
                   candidates, core, no_start, scouting, start_at)
from .data import JointData, Measured
from .forward import ModelSpectra
from ..spectral.segments import Segments, from_spectra, segments

__all__ = ["record", "record_many", "record_from_spectra", "analyse_one", "analyse_many", "refit_analysis", "fit_one",
           "resolution_want"]

#: the log ratio may fall by at most this much across one bin (resolution of slow slips)
MAX_LOG_STEP_PER_BIN = 0.15
#: fewest half-overlapping segments a longer segment may leave
MIN_SEGMENTS = 6
#: the fit's Welch segment is lengthened until the faster pair's band holds this many usable bins
MIN_BAND_BINS = 8


def _locate(rec: Record, settings: Settings):
    spec = band_mod.spectra(rec.seg)
    b = band_mod.select(spec, rec.depths, jnp.log(rec.gains), min_snr=settings.min_snr, max_err=settings.max_err,
                        fmin=settings.fmin, fmax=settings.fmax, leakage_db=settings.leakage_db)
    return b.speed0, b.n_band


#: records a vmapped chunk runs side by side; a larger chunk runs in blocks of this many, one after another
#: (``jax.lax.map``). The program's working memory is about 96 MB a record on a GPU (its Jacobians by forward
#: differentiation through the Hertz quadrature), so a block of 128 needs about 12 GiB, and each block iterates
#: until its own slowest record stops rather than the chunk's.
VMAP_BLOCK = 128


def _analyse_many(recs: Record, settings: Settings, choices: Choices, starts: Start) -> Analysis:
    n = jax.tree.leaves(starts)[0].shape[0]
    if n <= VMAP_BLOCK:
        return jax.vmap(_analyse, in_axes=(0, None, None, 0))(recs, settings, choices, starts)
    return jax.lax.map(lambda x: _analyse(x[0], settings, choices, x[1]), (recs, starts), batch_size=VMAP_BLOCK)


@functools.cache
def _programs():
    """The compiled programs, built on first use (one set per process)."""
    return {"locate": jax.jit(_locate), "locate_many": jax.jit(jax.vmap(_locate, in_axes=(0, None))),
            "core": _single_core(),
            "analyse": _exported(_analyse, "analyse"), "analyse_many": jax.jit(_analyse_many)}


# the pytree types of the programs' arguments and results, for jax.export's serialisation
_TYPES = (Segments, Record, Settings, Start, Summary, Located, ModelSpectra, JointData, Measured, Choices, Analysis,
          Stages, Errors)


def _source_key() -> str:
    """A hash of the sources the compiled pipeline is traced from, JAX's version and the precision."""
    import hashlib
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    h = hashlib.sha1(f"{jax.__version__} {jax.config.jax_enable_x64}".encode())
    # every module the core can import: the physics, the spectra and the inference
    paths = [p for sub in ("model", "spectral", "inference", "track") for p in (root / sub).glob("*.py")]
    for path in sorted(paths + [root / "_numerics.py", root / "_quadrature.py", root / "status.py"]):
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def _single_core():
    """``core`` for one record, jit-compiled, kept in the persistent cache where one is set (``_exported``)."""
    return _exported(core, "core")


#: XLA options of a program compiled quickly for a first run on the CPU (``quick_first``): XLA's loop emitters,
#: LLVM optimisation off. The analysis program of both windows then compiles in 10.8 s against 28.1 s (a first
#: ``tactile-jax fit``: 19.1-20.1 s against 38.6 s) and runs about 3 times slower, 0.4-0.6 s a record (at level 1:
#: 15.6 s, 23.7 s, 20-27 % slower; docs/speed.md): what a first command's few records can afford
QUICK_COMPILE = {"xla_cpu_use_fusion_emitters": False, "xla_backend_optimization_level": 0}
_QUICK = {"first": False, "used": False}


def quick_first(on: bool = True) -> None:
    """Where the optimised form of a program kept by ``_exported`` is not in the persistent cache yet (a first run),
    compile it with ``QUICK_COMPILE`` on the CPU instead: a command that fits a few records answers sooner, and
    ``optimise_later`` compiles the optimised form for the runs that follow. Off by default: a batch or a tracker
    compiles the optimised form at once."""
    _QUICK["first"] = bool(on)


def quick_used() -> bool:
    """Whether this process compiled a program with ``QUICK_COMPILE`` (its optimised form is still to compile)."""
    return _QUICK["used"]


def _exported(fn, name: str, types=()):
    """``fn`` jit-compiled; where a persistent compilation cache is set (the CLI sets one), its traced program is
    also kept there with ``jax.export``, so that a later process deserialises it instead of tracing ``fn`` again
    and finds its compiled form in the cache. A marker beside the export says that the optimised form was compiled
    into the cache; until one does, ``quick_first`` compiles it with ``QUICK_COMPILE``."""
    from pathlib import Path

    jitted = jax.jit(fn)
    cache = jax.config.jax_compilation_cache_dir
    if not cache:
        return jitted
    try:
        from jax import export
    except ImportError:                 # pragma: no cover - jax.export's serialisation needs flatbuffers
        return jitted
    for t in _TYPES + tuple(types):
        try:
            export.register_namedtuple_serialization(t, serialized_name=f"tactile_jax.{t.__name__}")
        except ValueError:              # registered already
            pass
    states = {}

    def call(*args):
        # one export per structure of the arguments (the analysis of both windows, or of the Gaussian alone)
        tree = jax.tree.structure(args)
        if tree not in states:
            import hashlib

            shape = hashlib.sha1(str(tree).encode()).hexdigest()[:8]
            path = Path(cache).parent / "export" / f"{name}-{shape}-{_source_key()}.bin"
            if path.exists():
                exp = export.deserialize(bytearray(path.read_bytes()))
            else:
                exp = export.export(jitted)(*args)
                path.parent.mkdir(parents=True, exist_ok=True)
                tmp = path.with_suffix(f".{os.getpid()}.tmp")
                tmp.write_bytes(exp.serialize())
                tmp.replace(path)
            optimised = path.with_suffix(".optimised")
            states[tree] = (jax.jit(exp.call), optimised)
            if _QUICK["first"] and not optimised.exists() and jax.default_backend() == "cpu":
                try:
                    states[tree] = (states[tree][0].lower(*args).compile(compiler_options=QUICK_COMPILE), None)
                    _QUICK["used"] = True
                except Exception:   # noqa: BLE001 - an XLA without these options: the optimised form
                    pass
        program, optimised = states[tree]
        out = program(*args)
        if optimised is not None:       # the optimised form is in the cache now
            try:
                optimised.touch()
            except OSError:             # a cache this process cannot write to: later runs compile it again
                pass
            states[tree] = (program, None)
        return out

    return call


#: device arrays of at least this many elements converted to the compute precision are kept (at most
#: ``_CONVERT_MAX_KEPT``, the oldest dropped first): id(source) -> (source, converted). The Hertz table's
#: coefficients (52 MB in float32) come in every call's settings; converted afresh (through the host) they cost
#: each analysis about 100 ms
_CONVERT_MIN_SIZE = 1 << 16
_CONVERT_MAX_KEPT = 4
_CONVERTED: dict = {}


def _as_jnp(tree):
    dtype = jnp.float64 if jax.config.jax_enable_x64 else jnp.float32

    def target(kind):
        """The compute dtype of a floating or complex kind; None (jax's default) for the others."""
        return dtype if kind == "f" else (jnp.complex128 if dtype == jnp.float64 else jnp.complex64) if kind == "c" \
            else None

    def on_device(x):
        want = target(x.dtype.kind) or x.dtype
        if x.dtype == want:
            return x
        if x.size < _CONVERT_MIN_SIZE:
            return x.astype(want)
        hit = _CONVERTED.get(id(x))
        if hit is None or hit[0] is not x or hit[1].dtype != want:
            while len(_CONVERTED) >= _CONVERT_MAX_KEPT:
                _CONVERTED.pop(next(iter(_CONVERTED)))
            hit = _CONVERTED[id(x)] = (x, x.astype(want))
        return hit[1]

    def conv(x):
        if isinstance(x, jax.Array):
            return on_device(x)
        x = np.asarray(x)
        return jnp.asarray(x, target(x.dtype.kind))

    return jax.tree.map(conv, tree)


def _record(seg: Segments, depths, gains, velocity) -> Record:
    known = velocity is not None
    vel = np.zeros(2) if velocity is None else np.abs(np.asarray(velocity, float))
    return Record(seg, np.asarray(depths, float), np.asarray(gains, float), vel, np.asarray(known))


def resolution_want(speed0, n_band, fs, depths, n_samples: int, nperseg: int) -> int:
    """The Welch segment (samples) that resolves a record's band, or ``nperseg`` when that one does.

    Two rules, the longer wins, rounded up to a power of two and capped so that at least
    ``MIN_SEGMENTS`` half-overlapping segments remain: the ratio falls as exp(-(d2 - d1) omega / v),
    so nperseg >= 2 pi fs (d2 - d1) / (0.15 v) keeps its fall below 0.15 per bin at the faster pair's
    Eq. 6 speed v; and a band of n usable bins is stretched to at least ``MIN_BAND_BINS``. A record
    with no Eq. 6 speed but some usable bins (a slow slip at low SNR) goes by its bin count alone.
    """
    speed0 = np.asarray(speed0, float)
    n_band = np.asarray(n_band)
    have = np.isfinite(speed0)
    want = 0.0
    if have.any():
        fast = int(np.argmax(np.where(have, speed0, -np.inf)))
        eps = float(depths[1] - depths[0])
        want = 2 * math.pi * fs * eps / (MAX_LOG_STEP_PER_BIN * speed0[fast])
        count = n_band[fast]
    else:
        count = n_band.max()
    if count > 0 and count < MIN_BAND_BINS:
        want = max(want, nperseg * MIN_BAND_BINS / count)
    if want <= nperseg:
        return nperseg
    cap = 1 << ((2 * int(n_samples) // (MIN_SEGMENTS + 1)).bit_length() - 1)
    return int(min(2 ** math.ceil(math.log2(want)), max(cap, nperseg)))


def record(signals, fs: float, depths, *, gains=(1.0, 1.0), velocity=None, method: str = "welch",
           nperseg: int | None = None, prewhiten: int | None = 8, settings: Settings = Settings(),
           source: str | None = None) -> Record:
    """A ``Record`` of one recording (4, N): its segments, lengthened for slow slips unless ``nperseg`` is given."""
    seg = segments(signals, fs, method=method, nperseg=nperseg, prewhiten=prewhiten, source=source)
    if method == "welch" and not nperseg:
        rec = _record(seg, depths, gains, velocity)
        speed0, n_band = _programs()["locate"](_as_jnp(rec), settings)
        n0 = int(seg.nperseg)
        want = resolution_want(np.asarray(speed0), np.asarray(n_band), fs, np.asarray(depths, float),
                               np.shape(signals)[-1] - (prewhiten or 0), n0)
        if want > n0:
            seg = segments(signals, fs, method=method, nperseg=want, prewhiten=prewhiten, source=source)
    return _record(seg, depths, gains, velocity)


def record_many(signals, fs, depths, *, gains, velocity, nperseg: int | None = None, prewhiten: int | None = 8,
                settings: Settings = Settings()) -> list[Record]:
    """``record`` (Welch) of each of many records of one length at once: their spectra in jnp
    (``welch_many``), their bands located side by side, and the segments of those that need a longer one
    remade together. signals: (B, 4, N); fs: (B,) Hz; depths, gains: (B, 2); velocity: B known velocities
    or None. Raises ``TactileInputError`` for settings no record can meet (as ``record``)."""
    from ..spectral.welch_many import welch_many

    b, n = len(signals), np.shape(signals)[-1]
    fs = np.broadcast_to(np.asarray(fs, float), (b,))
    seg = jax.tree.map(np.asarray, welch_many(signals, fs, nperseg=nperseg, prewhiten=prewhiten))
    recs = [_record(s, depths[i], gains[i], velocity[i]) for i, s in enumerate(_unstack(seg, b))]
    if nperseg:
        return recs
    speed0, n_band = jax.tree.map(np.asarray, _programs()["locate_many"](_as_jnp(_stack(recs)), settings))
    n0 = int(seg.nperseg[0])
    want = np.array([resolution_want(speed0[i], n_band[i], fs[i], np.asarray(depths[i], float),
                                     n - (prewhiten or 0), n0) for i in range(b)])
    for length in np.unique(want[want > n0]):
        idx = np.flatnonzero(want == length)
        longer = jax.tree.map(np.asarray, welch_many(np.asarray(signals)[idx], fs[idx], nperseg=int(length),
                                                     prewhiten=prewhiten))
        for i, s in zip(idx, _unstack(longer, len(idx))):
            recs[i] = _record(s, depths[i], gains[i], velocity[i])
    return recs


def record_from_spectra(omega, psd, csd, depths, *, n_segments: float, xy=None, groups=None, kernel=None,
                        bin_factor=None, whitening=None, fs=None, gains=(1.0, 1.0), velocity=None,
                        source=None) -> Record:
    """A ``Record`` of given spectra (``segments.from_spectra``): omega (M,) rad/s uniformly spaced from a
    multiple of the spacing, psd (4, M), csd (2, M) and xy (4, M) complex (None: no x-y spectra, no chain);
    groups: each group's (count, psd, csd, xy) for the jackknife (None: one group, no jackknife);
    n_segments: the effective number of independent segments. kernel: (offsets in bins, weights) of the
    estimator's spectral window (None: one bin)."""
    seg = from_spectra(omega, psd, csd, xy, dof=n_segments, groups=groups, kernel=kernel, bin_factor=bin_factor,
                       whitening=whitening, fs=fs, source=source)
    return _record(seg, depths, gains, velocity)


def _stack(trees):
    """Pytrees of one structure and shape -> one pytree with a leading axis (numpy)."""
    return jax.tree.map(lambda *x: np.stack(x), *trees)


def _hertz_start(scout: Summary) -> Start:
    """The Hertz program's ``Start`` from the Gaussian program's scouting (one record or a stack): its ends
    (..., ``N_STARTS``, P), each radius scaled to the Hertz disk of the same second moment, to go on from
    the one of lowest Hertz cost."""
    ends = np.array(scout.ends, float)
    ends[..., INDEX["log_a"]] += np.log(HERTZ_PER_GAUSS)
    return candidates(ends, np.asarray(scout.free))


def fit_one(rec: Record, settings: Settings, start: Start | None = None) -> Summary:
    """``core`` on one record (numpy in, a ``Summary`` of numpy arrays out); ``start``: refit from there.
    With no start, the Hertz window goes on from the Gaussian program's scouting of its starts (``core``)."""
    program, rec_j = _programs()["core"], _as_jnp(rec)
    if start is None and settings.hertz is not None:
        start = _hertz_start(program(rec_j, settings._replace(hertz=None), _as_jnp(scouting())))
    out = program(rec_j, settings, _as_jnp(no_start() if start is None else start))
    return jax.tree.map(np.asarray, out)


def _unstack(tree, n: int) -> list:
    return [jax.tree.map(lambda x, i=i: x[i], tree) for i in range(n)]


def analyse_one(rec: Record, settings: Settings, choices: Choices = Choices(), start: Start | None = None
                ) -> Analysis:
    """``analysis.analyse`` on one record (numpy in, an ``Analysis`` of numpy arrays out). settings: with the
    Hertz table (``options.analysis_settings``)."""
    out = _programs()["analyse"](_as_jnp(rec), _as_jnp(settings), _as_jnp(choices),
                                 _as_jnp(no_start() if start is None else start))
    return jax.tree.map(np.asarray, out)


def analyse_many(recs: list[Record], settings: Settings, choices: Choices = Choices(), size: int | None = None, *,
                 vmapped: bool | None = None) -> list[Analysis]:
    """``analysis.analyse`` on each record: one ``Analysis`` each (numpy).

    vmapped: the chunk side by side in one program (``jax.vmap``, padded to ``size`` with copies of the first;
    beyond ``VMAP_BLOCK`` records, in blocks of that many, and padded to whole blocks);
    None: on an accelerator only. On a CPU the single-record program (the one ``fit`` runs) one record after
    another is as fast per core; ``batch`` uses the other cores with processes."""
    if vmapped is None:
        vmapped = jax.default_backend() != "cpu"
    n = len(recs)
    if not n:
        return []
    if not vmapped:
        return [analyse_one(r, settings, choices) for r in recs]
    size = max(size or n, n)
    if size > VMAP_BLOCK:                       # whole blocks: a remainder would compile the program a second time
        size = VMAP_BLOCK * math.ceil(size / VMAP_BLOCK)
    stacked = _as_jnp(_stack(recs + [recs[0]] * (size - n)))
    out = _programs()["analyse_many"](stacked, _as_jnp(settings), _as_jnp(choices),
                                       _as_jnp(_stack([no_start()] * size)))
    return _unstack(jax.tree.map(np.asarray, out), n)


def refit_analysis(rec: Record, settings: Settings, theta, free, window: str, lumps=None, lump_rows=None) -> Summary:
    """The analysis program from ``theta`` over ``free`` under ``window`` with every choice held, the texture's
    random effects (``start_at``'s lumps and lump_rows) included: the kept fit's ``Summary`` (what ``fit``'s
    profiles and model selection refit)."""
    a = analyse_one(rec, settings, Choices(window=1 + ("gaussian", "hertz").index(window), texture=1, direction=1,
                                           test_window=False, refit=True),
                    start_at(theta, free, lumps, lump_rows))
    return summary_of(a)
