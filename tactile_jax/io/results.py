"""Result tables of ``tactile-jax fit`` / ``batch``: JSON, CSV or Parquet, one row per record.

The format follows the suffix of the path. Rows are flat dicts (``FitResult.to_record()``);
the data contract's fields (``contract.RESULT_FIELDS``, docs/data-format.md) come first, extra keys after
them in first-seen order. Writes are atomic: a temporary file in the target's folder is
renamed over the target, so a failed write leaves any existing file untouched.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from .atomic import atomic_write
from ..contract import RESULT_FIELDS
from ..errors import TactileInputError

__all__ = ["RESULT_SUFFIXES", "read_results", "result_columns", "write_results"]

#: Suffixes ``write_results`` accepts (``read_results``: the first two).
RESULT_SUFFIXES = (".json", ".csv", ".parquet")


def _contract_fields() -> tuple[str, ...]:
    return tuple(RESULT_FIELDS)


#: columns every results file has after the data contract's fields, whether or not a row fills them
LEADING_EXTRAS = ("sensor",)


def result_columns(rows: list[dict]) -> list[str]:
    """Column order: the data contract's fields, ``LEADING_EXTRAS``, then any other keys in first-seen order."""
    cols = list(_contract_fields()) + list(LEADING_EXTRAS)
    seen = set(cols)
    for row in rows:
        for key in row:
            if key not in seen:
                seen.add(key)
                cols.append(key)
    return cols


def _plain(value: Any) -> Any:
    """JSON/CSV-ready scalar: numpy scalars to Python, NaN/inf to None, arrays to lists."""
    if isinstance(value, np.ndarray):
        return [_plain(v) for v in value.tolist()]
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, (np.integer, np.floating)):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Path):
        return str(value)
    return value


def _suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in RESULT_SUFFIXES:
        got = f"'{path.suffix}'" if path.suffix else "no suffix"
        raise TactileInputError(f"unsupported results file type ({got}); use {', '.join(RESULT_SUFFIXES)}",
                                source=str(path), code="bad_setting")
    return suffix


def write_results(path, rows: list[dict]) -> Path:
    """Write result rows to ``path``: ``.json`` (a list of objects), ``.csv`` or ``.parquet``.

    rows: flat dicts (values: float, int, bool, str or None; numpy scalars and NaN/inf are
        accepted: NaN/inf become null). Every row gets every column (missing keys: null).
    JSON: NaN/inf -> null. CSV: header = ``fit.RESULT_FIELDS`` then the extra keys in
    first-seen order; None -> empty cell. Parquet needs pyarrow. Raises
    ``TactileInputError`` (code ``bad_setting``) for another suffix or a missing pyarrow,
    ``OSError`` when the file cannot be written. Returns the path.
    """
    path = Path(os.fspath(path))
    suffix = _suffix(path)
    cols = result_columns(rows)
    table = [{c: _plain(row.get(c)) for c in cols} for row in rows]
    if suffix == ".json":
        payload = (json.dumps(table, indent=1, allow_nan=False) + "\n").encode("utf-8")
        return _atomic_bytes(path, payload)
    if suffix == ".csv":
        buf = io.StringIO(newline="")
        writer = csv.DictWriter(buf, fieldnames=cols, lineterminator="\n")
        writer.writeheader()
        for row in table:
            writer.writerow({c: _csv_cell(v) for c, v in row.items()})
        return _atomic_bytes(path, buf.getvalue().encode("utf-8"))
    return _write_parquet(path, cols, table)


def _csv_cell(value):
    if value is None:
        return ""
    if isinstance(value, float):
        return repr(value)                       # round-trips exactly
    if isinstance(value, (list, dict)):
        return json.dumps(value)
    return value


def _write_parquet(path: Path, cols: list[str], table: list[dict]) -> Path:
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        raise TactileInputError("writing .parquet needs pyarrow: pip install pyarrow (or use .json / .csv)",
                                source=str(path), code="bad_setting") from None
    arrow = pa.table({c: pa.array([row[c] for row in table]) for c in cols})

    def write(tmp):
        pq.write_table(arrow, tmp)

    return atomic_write(path, write)


def _atomic_bytes(path: Path, payload: bytes) -> Path:
    def write(tmp):
        with open(tmp, "wb") as fh:
            fh.write(payload)

    return atomic_write(path, write)


def read_results(path) -> list[dict]:
    """Read rows written by ``write_results`` from ``.json`` or ``.csv``.

    CSV cells come back typed: numbers as float (``index`` and ``n_bins`` too), empty
    cells as None, ``True``/``False`` as bool, anything else as str. Raises
    ``TactileInputError`` (code ``unreadable``) for a missing or malformed file,
    ``bad_setting`` for another suffix.
    """
    path = Path(os.fspath(path))
    suffix = _suffix(path)
    if suffix == ".parquet":
        raise TactileInputError("read_results reads .json and .csv (read .parquet with pyarrow or pandas)",
                                source=str(path), code="bad_setting")
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as err:
        raise TactileInputError(f"cannot read results: {err.strerror or err}", source=str(path),
                                code="unreadable") from None
    if suffix == ".json":
        try:
            rows = json.loads(text)
        except ValueError as err:
            raise TactileInputError(f"not valid JSON ({err})", source=str(path), code="unreadable") from None
        if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
            raise TactileInputError("a results JSON file must hold a list of objects", source=str(path),
                                    code="unreadable")
        return rows
    return [{k: _csv_value(v) for k, v in row.items()} for row in csv.DictReader(io.StringIO(text, newline=""))]


def _csv_value(text: str | None):
    if text is None or text == "":
        return None
    if text in ("True", "False"):
        return text == "True"
    try:
        return float(text)
    except ValueError:
        return text
