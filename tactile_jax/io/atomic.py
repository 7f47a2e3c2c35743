"""One atomic file writer for every output (recordings, spectra, results, posteriors).

``atomic_write(path, write)`` calls ``write(tmp)`` on a fresh hidden file next to
``path`` (mode from the umask, as a plain ``open`` would give, unlike ``mkstemp``'s
0600), fsyncs it, renames it over ``path`` and fsyncs the folder. A failed write
leaves ``path`` as it was and no temporary file behind. No maintained library does
this with h5py and numpy writers that want a path, so it is kept here, once.
"""

from __future__ import annotations

import os
import secrets
from pathlib import Path
from typing import Callable

from ..errors import TactileInputError

__all__ = ["atomic_write", "check_folder"]


def check_folder(path) -> Path:
    """``path`` as a Path whose folder exists; ``TactileInputError`` naming the folder otherwise."""
    path = Path(os.fspath(path))
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        what = "is not a folder" if folder.exists() else "does not exist"
        raise TactileInputError(f"cannot write {path.name}: the folder {folder} {what}", source=str(path),
                                code="bad_setting")
    return path


def atomic_write(path, write: Callable[[str], None]) -> Path:
    """``write(tmp)`` into a temporary file next to ``path``, then rename it over ``path``; returns ``path``."""
    path = check_folder(path)
    tmp = _new_temp(path)
    try:
        write(tmp)
        _fsync(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    _fsync(path.parent if str(path.parent) else Path("."), folder=True)
    return path


def _new_temp(path: Path) -> str:
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)
    while True:
        tmp = path.with_name(f".{path.name}.{secrets.token_hex(6)}.tmp")
        try:
            os.close(os.open(tmp, flags, 0o666))
            return str(tmp)
        except FileExistsError:  # pragma: no cover - 48 random bits
            continue


def _fsync(p, folder: bool = False) -> None:
    """Make the data (or, for a folder, the rename) durable where the platform allows it."""
    try:
        fd = os.open(p, os.O_RDONLY | (0 if folder else getattr(os, "O_BINARY", 0)))
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
