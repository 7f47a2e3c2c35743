"""Batch reprocessing of datasets: walk, chunk, fit, resume, write atomically, optionally on Dask.

``run_batch(inputs, out)`` fits every record of every recording under
``inputs`` (files, folders searched recursively, multi-record files with
``signals`` of shape (n, 4, N)) and writes one data-contract row per record
to ``out`` (.json, .csv or .parquet). Records are fitted in chunks of
``chunk_size`` by the analysis program that ``fit`` runs on one record
(``inference.analysis``). On a CPU a chunk runs record after record and the
chunks are spread over one process per core; on an accelerator a chunk's
spectra are one jnp program (``spectral.welch_many``) and its records run
side by side, in blocks of ``run.VMAP_BLOCK`` (the last chunk is padded with
copies that are dropped). The program's inputs have one shape whatever the
record's length, segment length or band, so a batch compiles it once, not
per file.

Nothing is lost: a bad record (NaN samples, wrong shape, missing fs/depths,
an unreadable file) becomes a row with its ``status`` (the
``TactileInputError`` code) and ``message``; the others go on. The results
file is rewritten atomically (``results.write_results``: temporary file then
``os.replace``) after every chunk, so an interruption loses at most the
chunks in flight, and a rerun with the same ``out`` skips the rows already
there (``resume``). Rows whose status is transient (``worker_error``) are redone.

With ``workers=N`` (a ``dask.distributed.LocalCluster`` of N spawned
processes; JAX does not survive ``fork``) or ``scheduler=ADDRESS`` the chunks
run as Dask tasks, partitioned by file and chunk exactly as locally, so the
rows are the same.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from .._cores import usable_cores
from ..errors import TactileInputError
from ..status import FIT_RAN as STATUS_FIT_RAN, TRANSIENT
from ..inference.options import FitOptions
from ..inference.result import RESULT_FIELDS

__all__ = ["BatchSummary", "run_batch", "scan_inputs", "TRANSIENT_STATUSES", "DEFAULT_MODEL"]

#: statuses of rows that a resumed batch computes again (failures of the machinery, not of the data)
TRANSIENT_STATUSES = tuple(s.value for s in TRANSIENT)
#: statuses of a fit that ran and produced values (the others count as failed)
FIT_RAN = tuple(s.value for s in STATUS_FIT_RAN)
#: the model a batch fits: the joint pipeline of ``fit`` (each row names the scene model it fitted)
DEFAULT_MODEL = "joint"
#: fewest records per process worth spawning one for (its start and program load cost about as much)
MIN_PER_PROCESS = 8
#: the environment of the spawned worker processes where the user has not set these: one BLAS thread each, as
#: Dask's nanny gives its workers (``distributed.nanny.pre-spawn-environ``): threaded BLAS calls of two workers
#: contend for the same cores. Made with numpy's BLAS dot products on 16,000-sample vectors, two workers' spectra
#: took 440 ms a record with OpenBLAS's own threads against 9.5 ms with one each (benchmarks/throughput.py's
#: oblique records); ``segments.burg_ar`` sums with einsum, and its spectra take 11 ms either way
#: each spawned worker runs on a core of its own, where there are enough: XLA then sizes its thread pool to one,
#: and two workers on two cores no longer share four threads (256 oblique records, `benchmarks/throughput.py`:
#: 8.95 rec/s against 7.34 unpinned). Its reductions are then split differently from a process that
#: sees every core, so rows agree with `fit`'s to about 1e-9 relative, not in every digit
PIN_WORKERS = True
WORKER_ENVIRON = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}


@dataclasses.dataclass
class BatchSummary:
    """What a batch did. ``timings`` in seconds: scan, read, spectra, fit, write, total."""

    n_rows: int
    n_failed: int
    n_skipped: int
    out: Path
    timings: dict
    n_fitted: int = 0
    model: str = DEFAULT_MODEL


@dataclasses.dataclass
class _FileInfo:
    """A recording file's metadata (signals not read) or the error that makes it unusable."""

    path: str
    kind: str = ""
    n_records: int = 0
    n_samples: int = 0
    multi: bool = False
    fs: float = float("nan")
    depths: tuple = (float("nan"), float("nan"))
    curvature_radius: float | None = None
    velocity: tuple | None = None
    gain_ratio: object = None
    sensor: str | None = None             # ``Recording.sensor``: where the depths and radius come from
    spec: object = None                   # the batch's ``SensorSpec`` (an audio file's channel map), or None
    error: TactileInputError | None = None


# --------------------------------------------------------------------------- inputs


#: records per chunk by default: on a CPU each chunk runs record after record in one of the processes; on an
#: accelerator a chunk runs side by side in blocks of ``run.VMAP_BLOCK`` (device memory about 20 GiB)
CHUNK_SIZE = {"cpu": 32, "accelerator": 1024}
#: the chunk's Welch spectra in one compiled program (``fit.records_of``) rather than numpy record by record
#: (``fit.record_of``); None: on an accelerator only
DEVICE_SPECTRA: bool | None = None


def _walk(inputs, out: Path | None = None) -> tuple[list[str], dict[str, str]]:
    """Every file to give a row, in order, and why a folder entry is not a recording (file -> reason).

    Explicit files are always taken. In a folder every file is taken except hidden ones (names
    starting with ".", such as the results' own temporary files) and ``out`` itself; a folder that
    holds no recording at all is an error.
    """
    from ..io.files import AUDIO_SUFFIXES, RECORDING_SUFFIXES, STORE_SUFFIXES, is_recording_file

    files, not_recordings = [], {}
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    skip = None if out is None else os.path.realpath(out)
    for item in inputs:
        p = Path(os.fspath(item))
        if not p.is_dir():
            files.append(os.fspath(item))
            continue
        found = 0
        for root, dirs, names in os.walk(p):
            dirs[:] = sorted(d for d in dirs if not d.startswith("."))
            for name in sorted(names):
                q = os.path.join(root, name)
                if name.startswith(".") or os.path.realpath(q) == skip:
                    continue
                files.append(q)
                if is_recording_file(q):
                    found += 1
                else:
                    suffix = Path(name).suffix.lower()
                    not_recordings[q] = (f"not a recording: not a readable {suffix} audio file"
                                         if suffix in AUDIO_SUFFIXES else
                                         f"not a recording: no 'signals' in this {suffix} file, or unreadable"
                                         if suffix in RECORDING_SUFFIXES else
                                         f"not a recording file type ({suffix or 'no suffix'}; "
                                         f"recordings are {', '.join(RECORDING_SUFFIXES)})")
        if not found:
            raise TactileInputError(f"no recording files ({', '.join(STORE_SUFFIXES)} with 'signals') in "
                                    "this folder or below", source=str(p), code="bad_setting")
    seen, unique = set(), []
    for f in files:
        if f not in seen:
            seen.add(f)
            unique.append(f)
    return unique, not_recordings


def _scan(path: str, spec=None) -> _FileInfo:
    """Read a recording file's metadata and the shape of ``signals`` without reading the samples.

    spec: the batch's ``SensorSpec`` or None (``io.files.read_recording``). A FLAC file without
    soundfile installed ends the batch (``MissingExtra``) before anything is fitted."""
    from .._optional import MissingExtra
    from ..io import files as tio
    from ..io.recording import Recording, validate_recording

    info = _FileInfo(path, spec=spec)
    try:
        shape, dtype, meta = tio.read_recording_header(path, sensor=spec)
        info.kind = tio.file_kind(Path(path), path)
        if np.dtype(dtype).kind not in "fiu":
            raise TactileInputError("signals must be a real numeric array", source=path, code="bad_shape")
        if len(shape) not in (2, 3) or shape[-2] != 4:
            raise TactileInputError(
                f"signals must have shape (4, N) or (n, 4, N) with channels x1, x2, y1, y2; got {tuple(shape)}",
                source=path, code="bad_shape")
        if shape[-1] < 2 or (len(shape) == 3 and shape[0] == 0):
            raise TactileInputError(f"signals hold no samples (shape {tuple(shape)})", source=path, code="too_short")
        # fs and depths by the contract's own checks, on a placeholder signal
        validate_recording(Recording(np.zeros((4, 2)), meta["fs"], meta["depths"], source=path))
        info.multi = len(shape) == 3
        info.n_records = shape[0] if info.multi else 1
        info.n_samples = int(shape[-1])
        info.fs, info.depths = float(meta["fs"]), tuple(float(d) for d in meta["depths"])
        info.curvature_radius, info.velocity, info.gain_ratio = (meta["curvature_radius"], meta["velocity"],
                                                                 meta["gain_ratio"])
        info.sensor = meta["sensor"]
    except TactileInputError as err:
        info.error = err.with_source(path)
    except MissingExtra:
        raise
    except Exception as exc:  # noqa: BLE001 - a file the readers did not foresee
        info.error = TactileInputError(f"cannot read file: {type(exc).__name__}: {exc}", source=path, code="unreadable")
    return info


def scan_inputs(inputs, out: Path | None = None, sensor=None) -> list[_FileInfo]:
    """Walk ``inputs`` (see ``_walk``) and scan every file; a file that is not a recording carries its error.

    sensor: None, a sensor file's path or a ``SensorSpec``, for every file (``io.files.read_recording``)."""
    from ..io.sensor_file import as_sensor

    spec = as_sensor(sensor)
    files, not_recordings = _walk(inputs, out)
    infos = []
    for f in files:
        if f in not_recordings:
            infos.append(_FileInfo(f, error=TactileInputError(not_recordings[f], source=f, code="not_recording")))
        else:
            infos.append(_scan(f, spec))
    return infos


# --------------------------------------------------------------------------- reading records


_NPZ_CACHE: dict = {}


def _read_records(info: _FileInfo, start: int, stop: int) -> np.ndarray:
    """Records ``start:stop`` of a file as (n, 4, N); HDF5 is sliced lazily, NPZ loaded once per process, an
    audio file (one record) read whole under the batch's sensor file."""
    if info.kind in ("wav", "flac"):
        from ..io.files import read_recording

        return read_recording(info.path, sensor=info.spec).signals[None]
    if info.kind == "hdf5":
        import h5py

        with h5py.File(info.path, "r") as f:
            ds = f["signals"] if "signals" in f else None
            if ds is None:
                sig = np.asarray(f.attrs["signals"])
                return sig[None] if sig.ndim == 2 else sig[start:stop]
            return ds[start:stop] if info.multi else ds[()][None]
    key = (info.path, os.path.getmtime(info.path))
    if key not in _NPZ_CACHE:
        _NPZ_CACHE.clear()                              # one file at a time: memory stays bounded
        with np.load(info.path, allow_pickle=False) as z:
            _NPZ_CACHE[key] = z["signals"]
    sig = _NPZ_CACHE[key]
    return sig[None] if not info.multi else sig[start:stop]


def _error_row(src: str, index: int, code: str, message: str, model: str, tag: str) -> dict:
    row = dict.fromkeys(RESULT_FIELDS)
    row.update(file=src, index=int(index), converged=False, status=code, message=message, model=model, options=tag)
    return row


def options_tag(options: FitOptions) -> str:
    """The options a row was fitted with, as ``name=value; ...`` (those that differ from the defaults)."""
    default = FitOptions()
    parts = [f"{f.name}={getattr(options, f.name)!r}" for f in dataclasses.fields(FitOptions)
             if getattr(options, f.name) != getattr(default, f.name)]
    return "; ".join(parts) or "defaults"


def _tag_items(tag) -> dict:
    if tag in (None, "") or (isinstance(tag, float) and math.isnan(tag)):
        return {"options": "not recorded"}
    return dict(part.split("=", 1) for part in str(tag).split("; ") if "=" in part)


def _check_options(out: Path, kept: list[dict], tag: str) -> None:
    """Refuse to resume rows fitted with other options, naming the first difference."""
    new = _tag_items(tag)
    for row in kept:
        old = _tag_items(row.get("options"))
        if old != new:
            name = sorted(k for k in set(old) | set(new) if old.get(k) != new.get(k))[0]

            def value(items):
                return items.get(name, repr(getattr(FitOptions(), name, None)))

            raise TactileInputError(
                f"holds rows fitted with {name}={value(old)}, this run has {name}={value(new)}: rerun with --no-resume to refit every row, or write to "
                "another --out", source=str(out), code="bad_setting")


def _check_sensors(out: Path, kept: list[dict], infos: list[_FileInfo]) -> None:
    """Refuse to resume a row whose ``sensor`` differs from the one this run gives its file."""
    now = {info.path: info.sensor for info in infos if info.sensor is not None}
    for row in kept:
        old, new = row.get("sensor"), now.get(str(row.get("file")))
        if old not in (None, "") and new is not None and old != new:
            raise TactileInputError(
                f"holds rows of {row.get('file')} fitted with sensor {old!r}, this run has sensor {new!r}: rerun "
                "with --no-resume to refit every row, or write to another --out", source=str(out), code="bad_setting")


# --------------------------------------------------------------------------- chunks


def _plan(infos: list[_FileInfo], done: set, chunk_size: int):
    """Chunks of (file index, start, stop) segments in file order; every chunk has one size (one program)."""
    items = []
    total = 0
    for fi, info in enumerate(infos):
        if info.error is not None:
            continue
        total += info.n_records
        items.extend((fi, i) for i in range(info.n_records) if (info.path, i) not in done)
    # a tiny dataset gets a small program; the size depends on the dataset, not on what is left to do
    size = min(chunk_size, 1 << max(total - 1, 0).bit_length())
    chunks = []
    for c in range(0, len(items), size):
        segments = []
        for fi, i in items[c:c + size]:
            if segments and segments[-1][0] == fi and segments[-1][2] == i:
                segments[-1][2] = i + 1
            else:
                segments.append([fi, i, i + 1])
        chunks.append((size, [tuple(s) for s in segments]))
    return chunks


def _run_chunk(infos_part: list[_FileInfo], segments, size: int, options: FitOptions, model: str,
               x64: bool = True, cache_dir: str | None = None) -> tuple[list[dict], dict]:
    """Read, check and fit one chunk; return its rows (in segment order) and stage timings. Never raises."""
    import jax

    if x64 and not jax.config.jax_enable_x64:
        jax.config.update("jax_enable_x64", True)
    if cache_dir and not jax.config.jax_compilation_cache_dir:
        jax.config.update("jax_compilation_cache_dir", cache_dir)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    from ..inference.options import analysis_settings, choices_of, options_from_file
    from ..inference.select import options_for
    from ..inference.fit import record_of, records_of, result_of, with_line_model
    from ..inference import run
    from ..io.recording import Recording, validate_recording

    t0 = time.perf_counter()
    tag = options_tag(options)
    rows: dict[int, dict] = {}
    good, recs, metas, jobs = [], [], [], []
    info_of: dict[int, _FileInfo] = {}                 # the file of each good record (its sensor)
    pos = 0
    options = options_for(options)
    settings, choices = analysis_settings(options), choices_of(options)
    timings = {"read": 0.0, "spectra": 0.0, "fit": 0.0}
    for info, (_, start, stop) in zip(infos_part, segments):
        try:
            block = _read_records(info, start, stop)
        except TactileInputError as err:                   # an audio file's samples (NaN, ...): its own code
            for k, i in enumerate(range(start, stop)):
                rows[pos + k] = _error_row(info.path, i, err.code, str(err.with_source(info.path)), model, tag)
            pos += stop - start
            continue
        except Exception as exc:  # noqa: BLE001 - a file that changed or broke since the scan
            for k, i in enumerate(range(start, stop)):
                rows[pos + k] = _error_row(info.path, i, "unreadable",
                                           f"{info.path}: cannot read record {i}: {type(exc).__name__}: {exc}", model, tag)
            pos += stop - start
            continue
        timings["read"] += time.perf_counter() - t0
        file_options = options_from_file(options, info)          # the file's known velocity and gains
        for k, i in enumerate(range(start, stop)):
            src = f"{info.path} [record {i}]" if info.multi else info.path
            jobs.append((pos + k, info, i, src, block[k], file_options))
        pos += stop - start
        t0 = time.perf_counter()

    t1 = time.perf_counter()
    made: list = [None] * len(jobs)                # each record's Record, or its error
    for j, (p, info, i, src, signals, file_options) in enumerate(jobs):
        try:
            validate_recording(Recording(signals, info.fs, info.depths, source=src))
        except TactileInputError as err:
            made[j] = err.with_source(src)
    device = jax.default_backend() != "cpu" if DEVICE_SPECTRA is None else DEVICE_SPECTRA
    if device and options.method == "welch":
        # on an accelerator the chunk's spectra are one program per record length (``records_of``); on a CPU
        # numpy's are as fast per record, and a batch spreads its chunks over one process per core
        same: dict[int, list[int]] = {}
        for j, r in enumerate(made):
            if r is None:
                same.setdefault(np.shape(jobs[j][4])[-1], []).append(j)
        for idx in same.values():
            try:
                recs_n = records_of(np.stack([jobs[j][4] for j in idx]), [jobs[j][1].fs for j in idx],
                                    [jobs[j][1].depths for j in idx], [jobs[j][5] for j in idx])
                for j, r in zip(idx, recs_n):
                    made[j] = r
            except TactileInputError:           # a setting these records cannot meet: each its own error below
                pass
    for j, (p, info, i, src, signals, file_options) in enumerate(jobs):
        if made[j] is None:
            try:
                made[j] = record_of(signals, info.fs, info.depths, file_options, source=src)
            except TactileInputError as err:
                made[j] = err.with_source(src)
    for (p, info, i, src, signals, file_options), r in zip(jobs, made):
        if isinstance(r, TactileInputError):
            rows[p] = _error_row(info.path, i, r.code, str(r), model, tag)
            continue
        recs.append(r)
        good.append((p, info.path, i))
        info_of[p] = info
        metas.append((file_options.velocity, info.curvature_radius, signals, info.fs, file_options))
    timings["spectra"] += time.perf_counter() - t1
    if good:
        t1 = time.perf_counter()
        try:
            analyses = run.analyse_many(recs, settings, choices, size)
        except Exception as exc:  # noqa: BLE001 - a failure of the machinery: transient, redone on resume
            text = " ".join(f"{type(exc).__name__}: {exc}".split())[:300]
            for p, src, i in good:
                rows[p] = _error_row(src, i, "worker_error", f"{src}: the chunk failed: {text}", model, tag)
            analyses = []
        for (p, src, i), r, a, (vel, radius, signals, fs, opts) in zip(good, recs, analyses, metas):
            try:        # one record's failure stays its row
                res = result_of(a, r, opts, curvature_radius=radius, file=src, index=i)
                res = with_line_model(res, signals, fs, np.asarray(r.depths), opts, curvature_radius=radius,
                                      source=src)
                res.precision = "float64" if jax.config.jax_enable_x64 else "float32"
                res.sensor = info_of[p].sensor
                rows[p] = {**res.to_record(), "options": tag}
            except Exception as exc:  # noqa: BLE001
                text = " ".join(f"{type(exc).__name__}: {exc}".split())[:300]
                rows[p] = _error_row(src, i, "fit_error", f"{src}: {text}", model, tag)
        timings["fit"] += time.perf_counter() - t1
    return [rows[k] for k in sorted(rows)], timings


# --------------------------------------------------------------------------- resume and output


def _existing_rows(out: Path) -> list[dict]:
    if not out.exists():
        return []
    if out.suffix.lower() == ".parquet":
        try:
            import pyarrow.parquet as pq
        except ImportError:
            raise TactileInputError("resuming a .parquet batch needs pyarrow", source=str(out),
                                    code="bad_setting") from None
        return pq.read_table(out).to_pylist()
    from ..io.results import read_results

    return read_results(out)


def _key(row: dict):
    try:
        return str(row.get("file")), int(row.get("index") or 0)
    except (TypeError, ValueError):
        return None


def run_batch(inputs, out, *, options: FitOptions = FitOptions(), chunk_size: int | None = None,
              workers: int | None = None,
              scheduler: str | None = None, progress: bool = True, resume: bool = True,
              processes: int | None = None, sensor=None) -> BatchSummary:
    """Fit every record under ``inputs`` and write one row each to ``out``; return a :class:`BatchSummary`.

    inputs: a path or paths: recording files (.h5/.hdf5/.npz, (4, N) or (n, 4, N); .wav/.flac, one
        record each) or folders (searched recursively; files that are not recordings are skipped with a note).
    out: results file, .json / .csv / .parquet (the format follows the suffix).
    options: ``fit.FitOptions`` (spectral settings, band selection, known velocity, gains, chain): the
        same pipeline and model as ``fit_recording``, without its single-record extras (profile
        bounds, model selection; ``options.model`` must be None).
    chunk_size: records per compiled call (memory grows with it, not with the batch); None: ``CHUNK_SIZE``
        for the default backend (on an accelerator, blocks of ``run.VMAP_BLOCK`` run one after another).
    workers: start a ``dask.distributed.LocalCluster`` with this many spawned worker processes.
    scheduler: address of a running Dask scheduler (``tcp://host:8786``) to use instead.
    processes: without Dask, the chunks run on this many spawned processes (None: one per CPU core where
        a persistent compilation cache is set, from which each loads the compiled program, as the CLI
        sets one; else 1); 1: in this process. A batch of fewer than ``2 * MIN_PER_PROCESS`` records
        runs here, and the chunks are made small enough that every process gets one. A script that
        runs more than one needs the ``if __name__ == "__main__":`` guard of spawned processes.
    progress: a progress line on stderr. resume: skip rows already in ``out`` (same file and index,
        status not transient); False: start afresh (``out`` is replaced when the first chunk is done).
    sensor: None, a sensor file's path or a ``SensorSpec`` for every file (``io.files.read_recording``):
        an audio file's depths, radius, gains and channel map; checked against, and filling, an HDF5/NPZ
        file's metadata. Every row's ``sensor`` says where its sensor came from; resuming rows whose
        ``sensor`` differs from this run's is refused.

    Raises ``TactileInputError`` only for bad settings (``out`` suffix, chunk size, model, sensor file);
    bad recordings become rows. ``n_failed`` counts rows whose status is not one of ``FIT_RAN``.
    """
    from ..io.results import RESULT_SUFFIXES, write_results

    t_start = time.perf_counter()
    out = Path(os.fspath(out))
    model = DEFAULT_MODEL
    if options.model is not None:
        raise TactileInputError(f"the batch fits the default model; model={options.model!r} is for fit_recording",
                                code="bad_setting")
    if out.suffix.lower() not in RESULT_SUFFIXES:
        raise TactileInputError(f"--out must end in {', '.join(RESULT_SUFFIXES)}", source=str(out), code="bad_setting")
    import jax

    on_cpu = jax.default_backend() == "cpu"
    if chunk_size is None:
        chunk_size = CHUNK_SIZE["cpu" if on_cpu else "accelerator"]
    if isinstance(chunk_size, bool) or not isinstance(chunk_size, (int, np.integer)) or chunk_size < 1:
        raise TactileInputError(f"chunk_size must be an int >= 1; got {chunk_size!r}", code="bad_setting")
    if processes is not None and (isinstance(processes, bool) or int(processes) < 1):
        raise TactileInputError(f"processes must be >= 1; got {processes!r}", code="bad_setting")
    if workers is not None and (isinstance(workers, bool) or int(workers) < 1):
        raise TactileInputError(f"workers must be >= 1; got {workers!r}", code="bad_setting")
    if workers is not None or scheduler is not None:
        from .._optional import need

        need("dask.distributed", "batch", "a Dask run (--workers, --scheduler)")    # before any file is read
    options = _hashable(options)
    tag = options_tag(options)
    from ..io.sensor_file import as_sensor

    spec = as_sensor(sensor)                              # a bad sensor file ends the batch here

    infos = scan_inputs(inputs, out, spec)
    t_scan = time.perf_counter() - t_start
    kept = []
    if resume:
        kept = [r for r in _existing_rows(out) if r.get("status") not in TRANSIENT_STATUSES and _key(r) is not None]
        for r in kept:
            r["index"] = int(r["index"] or 0)               # CSV reads numbers back as float
        _check_options(out, kept, tag)
        _check_sensors(out, kept, infos)
    done = {_key(r) for r in kept}
    rows = list(kept)
    n_skipped = 0
    for info in infos:
        n_skipped += sum((info.path, i) in done for i in range(max(info.n_records, 1)))
        if info.error is not None and (info.path, 0) not in done:
            rows.append(_error_row(info.path, 0, info.error.code, str(info.error), model, tag))
    chunks = _plan(infos, done, int(chunk_size))
    total = sum(stop - start for _, segs in chunks for _, start, stop in segs)
    x64 = bool(jax.config.jax_enable_x64)
    cache_dir = jax.config.jax_compilation_cache_dir or None
    local = workers is None and scheduler is None
    # by default, on a CPU, one process per core where a persistent cache lets them load the compiled program
    # (without one, each would compile it again); an accelerator runs each chunk vmapped in this process
    wanted = int(processes or ((os.cpu_count() or 1) if cache_dir and on_cpu else 1))
    n_proc = min(wanted, max(total // MIN_PER_PROCESS, 1)) if local else 1
    if n_proc > 1 and len(chunks) < n_proc:           # every process a chunk
        chunks = _plan(infos, done, max(1, math.ceil(total / n_proc)))
    timings = {"scan": t_scan, "read": 0.0, "spectra": 0.0, "fit": 0.0, "write": 0.0}
    from tqdm.auto import tqdm

    bar = tqdm(total=total, unit="rec", desc="batch", disable=not progress or total == 0, file=sys.stderr)

    def consume(new_rows, t):
        rows.extend(new_rows)
        for k in ("read", "spectra", "fit"):
            timings[k] += t[k]
        write()
        bar.update(len(new_rows))

    def write():
        t0 = time.perf_counter()
        rows.sort(key=lambda r: _key(r) or ("", 0))      # the same order however the chunks finished
        write_results(out, rows)
        timings["write"] += time.perf_counter() - t0

    if len(rows) != len(kept):
        write()                                           # rows of unreadable files: saved before any fit
    try:
        if local and n_proc <= 1:
            for size, segs in chunks:
                consume(*_run_chunk([infos[fi] for fi, _, _ in segs], segs, size, options, model, x64, cache_dir))
        else:
            if cache_dir and scheduler is None and chunks:     # workers on this machine, sharing its cache
                bar.set_postfix_str("loading or compiling the analysis program", refresh=True)
                _compile_here(options, cache_dir)
                bar.set_postfix_str("", refresh=False)
            if local:
                _run_processes(chunks, infos, options, model, n_proc, consume, x64, cache_dir)
            else:
                _run_dask(chunks, infos, options, model, workers, scheduler, consume, x64, cache_dir)
    finally:
        bar.close()
    if not chunks:
        write()
    n_failed = sum(1 for r in rows if r.get("status") not in FIT_RAN)
    timings["total"] = time.perf_counter() - t_start
    return BatchSummary(n_rows=len(rows), n_failed=n_failed, n_skipped=n_skipped, out=out, timings=timings,
                        n_fitted=total, model=model)


def _hashable(options: FitOptions) -> FitOptions:
    """FitOptions with tuples where a user gave lists (the compiled program is keyed on them)."""
    g = options.gain_ratio
    if g is not None and not isinstance(g, (int, float)):
        g = tuple(float(v) for v in np.atleast_1d(np.asarray(g, float)))
    v = None if options.velocity is None else tuple(float(x) for x in options.velocity)
    return dataclasses.replace(options, gain_ratio=g, velocity=v)


def _collect(futures: dict, as_completed, consume, model, tag) -> None:
    """Consume the rows of each chunk's future (-> (part, segs)) as it completes; a chunk whose worker failed
    gets rows of status ``worker_error`` (transient: redone on resume)."""
    for fut in as_completed(futures):
        part, segs = futures[fut]
        try:
            consume(*fut.result())
        except Exception as exc:  # noqa: BLE001 - a lost worker: the chunk's rows say so
            text = " ".join(f"{type(exc).__name__}: {exc}".split())[:300]
            consume([_error_row(info.path, i, "worker_error", f"{info.path}: the chunk failed: {text}", model, tag)
                     for info, (_, start, stop) in zip(part, segs) for i in range(start, stop)],
                    {"read": 0.0, "spectra": 0.0, "fit": 0.0})


def _run_processes(chunks, infos, options, model, n_proc, consume, x64, cache_dir):
    """The chunks on ``n_proc`` spawned processes (JAX does not survive ``fork``), each loading the compiled
    program from the persistent cache where one is set. Processes, not threads: two executions of the
    program at once in one process deadlock jaxlib's CPU runtime on a 2-core machine."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    tag = options_tag(options)
    context = multiprocessing.get_context("spawn")
    with _worker_environ(), ProcessPoolExecutor(n_proc, mp_context=context, **_pinning(context, n_proc)) as pool:
        futures = {}
        for size, segs in chunks:
            part = [infos[fi] for fi, _, _ in segs]
            futures[pool.submit(_run_chunk, part, segs, size, options, model, x64, cache_dir)] = (part, segs)
        _collect(futures, as_completed, consume, model, tag)


def _pinning(context, n_proc: int) -> dict:
    """``ProcessPoolExecutor``'s arguments that pin each of ``n_proc`` workers to a core of its own
    (``PIN_WORKERS``), where this process may run on that many; else none."""
    cores = usable_cores() if hasattr(os, "sched_setaffinity") else []
    if not PIN_WORKERS or len(cores) < n_proc:
        return {}
    queue = context.Queue()
    for core in cores[:n_proc]:
        queue.put(core)
    return {"initializer": _pin_to_core, "initargs": (queue,)}


def _pin_to_core(queue) -> None:
    """A worker's initializer: run on the next core of ``queue`` alone."""
    os.sched_setaffinity(0, {queue.get()})


def _compile_here(options: FitOptions, cache_dir: str) -> None:
    """Compile the analysis program in this process, into the persistent cache ``cache_dir``, before the workers
    start: they then load it, where with a fresh cache each compiled it at the same time, on the same cores (its
    inputs have one shape whatever the recording, so a noise record stands for every file). Once done for these
    sources and this program (both windows, or the Gaussian one), a marker beside the cache says so, and later
    batches start their workers at once. A failure leaves the compilation to the workers."""
    import jax

    from ..inference import run
    from ..inference.fit import warm_up
    from ..inference.select import options_for

    opts = options_for(options)
    program = "gaussian" if opts.window == "gaussian" else "default"
    marker = (Path(cache_dir).parent / "export"
              / f"compiled-analyse-{program}-x64{int(jax.config.jax_enable_x64)}-{run._source_key()}")
    if marker.exists():
        return
    warm = run._programs.cache_info().currsize > 0     # programs this process holds already stay
    try:
        warm_up(opts)
        marker.parent.mkdir(parents=True, exist_ok=True)
        marker.touch()
    except Exception:  # noqa: BLE001 - the workers compile it then
        pass
    finally:            # this process runs no chunk: its copy of the compiled programs is not kept
        if not warm:
            run._programs.cache_clear()


@contextlib.contextmanager
def _worker_environ():
    """``WORKER_ENVIRON`` in ``os.environ`` (which spawned processes inherit) while the pool lives, where the
    user has not set those variables; restored after."""
    added = {k: v for k, v in WORKER_ENVIRON.items() if k not in os.environ}
    os.environ.update(added)
    try:
        yield
    finally:
        for k in added:
            os.environ.pop(k, None)


def _run_dask(chunks, infos, options, model, workers, scheduler, consume, x64, cache_dir):
    from .._optional import need

    dask = need("dask", "batch", "a Dask run (--workers, --scheduler)")
    distributed = need("dask.distributed", "batch", "a Dask run (--workers, --scheduler)")
    Client, LocalCluster, as_completed = distributed.Client, distributed.LocalCluster, distributed.as_completed
    tag = options_tag(options)

    cluster = None
    with dask.config.set({"distributed.worker.multiprocessing-method": "spawn"}):
        if scheduler is None:
            cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True,
                                   dashboard_address=None)
            client = Client(cluster)
        else:
            client = Client(scheduler)
        try:
            futures = {}
            for n, (size, segs) in enumerate(chunks):
                part = [infos[fi] for fi, _, _ in segs]
                fut = client.submit(_run_chunk, part, segs, size, options, model, x64, cache_dir, pure=False,
                                    key=f"tactile-chunk-{n}-{os.getpid()}-{time.time_ns()}")
                futures[fut] = (part, segs)
            _collect(futures, as_completed, consume, model, tag)
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
