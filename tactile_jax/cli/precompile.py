"""Compile the analysis program's optimised form into the persistent cache, at low priority: what
``common.optimise_later`` starts in the background after a command that compiled the program quickly.

    python -m tactile_jax.cli.precompile [default|gaussian]

One such process at a time per cache: a second one started while a lock younger than ``LOCK_AGE`` seconds stands
beside the cache exits at once.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

#: a lock older than this (s) is taken for one left by a process that died
LOCK_AGE = 600.0


def main(argv=None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    window = argv[0] if argv and argv[0] != "default" else None
    from . import common                                    # float64 and the cache, as the commands have them
    from ..inference.fit import warm_up
    from ..inference.options import FitOptions

    if not common.CACHE:
        return
    lock = Path(common.CACHE).parent / "export" / f"precompile-{window or 'default'}.lock"
    lock.parent.mkdir(parents=True, exist_ok=True)
    try:
        fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        try:
            if time.time() - lock.stat().st_mtime < LOCK_AGE:
                return
            lock.unlink()
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except OSError:         # another process took it meanwhile
            return
    os.close(fd)
    try:
        warm_up(FitOptions(window=window))
    finally:
        lock.unlink(missing_ok=True)


if __name__ == "__main__":
    try:
        os.nice(10)             # behind whatever the user runs next
    except (OSError, AttributeError):
        pass
    main()
