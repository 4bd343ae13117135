"""Check output paths before a flight, so a typo costs a second, not a whole run.

Every ``tfl-mav`` command that writes files (``--out``, ``--plot``, ``--mcap``, ``--json``,
``report --out``) calls these first: a one-line error naming the option, exit code 3 (I/O),
never a traceback and never after the flight.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from tfl_mav.flightlog.atomic import write_text_atomic

__all__ = ["EXIT_IO", "dir_problem", "file_problem", "write_text_atomic"]

EXIT_IO = 3


def dir_problem(path: str | Path, option: str) -> str | None:
    """Why files cannot be written into directory ``path`` (created if missing), or None."""
    p = Path(path)
    try:
        p.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=p, prefix=".tfl-mav-probe-"):
            pass
    except OSError as exc:
        return f"{option} {path}: cannot write there ({exc.strerror or exc})"
    return None


def file_problem(path: str | Path, option: str) -> str | None:
    """Why ``path`` cannot be written (its directory is missing or read-only, or it is a
    directory or read-only itself), or None. Leaves an existing file untouched."""
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    if p.is_dir():
        return f"{option} {path}: is a directory"
    if not parent.is_dir():
        return f"{option} {path}: directory {parent} does not exist"
    if p.exists():
        ok = os.access(p, os.W_OK)
    else:
        try:
            with tempfile.NamedTemporaryFile(dir=parent, prefix=".tfl-mav-probe-"):
                pass
            ok = True
        except OSError:
            ok = False
    return None if ok else f"{option} {path}: not writable"
