"""The results table: ``results.csv``, one row per run, appended as runs finish.

Written one whole line at a time and flushed, so a killed campaign leaves every finished run
in the file (at worst a torn last line, dropped on the next read); a resumed campaign reads
it to know what is left to fly. Values round-trip exactly (floats by ``repr``), so the
table — not the process that wrote it — is what the report and comparisons read.
"""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path
from typing import Any

from tfl_mav.tools.harness.campaign.run import RESULT_COLUMNS

__all__ = ["ResultsWriter", "format_value", "parse_value", "read_results", "summarize_rows",
           "swept_columns"]


def format_value(value: Any) -> str:
    """A cell: '' for None, true/false, floats by repr (exact), lists as [a, b]."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else str(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(format_value(v) for v in value) + "]"
    return str(value)


def parse_value(text: str) -> Any:
    """The inverse of :func:`format_value` for scalars (lists stay text)."""
    if text == "":
        return None
    if text in ("true", "false"):
        return text == "true"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def read_results(path: Path) -> tuple[list[str], list[dict[str, Any]]]:
    """Header and complete rows of ``path`` (a torn last line is dropped)."""
    if not path.exists():
        return [], []
    text = path.read_text(encoding="utf-8")
    lines = text.splitlines(keepends=True)
    if lines and not lines[-1].endswith("\n"):
        lines = lines[:-1]                      # the campaign was killed mid-write
    reader = csv.reader(io.StringIO("".join(lines)))
    header = next(reader, [])
    rows = [{h: (c if h == "run_id" else parse_value(c)) for h, c in zip(header, cells,
                                                                          strict=True)}
            for cells in reader if len(cells) == len(header)]
    return header, rows


def swept_columns(header: list[str]) -> list[str]:
    """The swept keys of a results header: the columns between run_id and seed."""
    return header[1:header.index("seed")] if "seed" in header else []


class ResultsWriter:
    """Appends rows to results.csv; rewrites it first if the last line is torn."""

    def __init__(self, path: Path, header: list[str]) -> None:
        self.path = path
        self.header = header
        old_header, rows = read_results(path)
        if old_header and old_header != header:
            raise ValueError(f"{path}: its columns differ from this campaign's; use another "
                             f"--out")
        fresh = not old_header
        if path.exists() and not fresh:
            expected = self._render(old_header) + "".join(
                self._render([format_value(r[c]) for c in header]) for r in rows)
            if path.read_text(encoding="utf-8") != expected:
                path.write_text(expected, encoding="utf-8")   # drop the torn line
        self._f = path.open("a", encoding="utf-8", newline="")
        if fresh:
            self._f.write(self._render(header))
            self._f.flush()

    @staticmethod
    def _render(cells: list[str]) -> str:
        buf = io.StringIO()
        csv.writer(buf, lineterminator="\n").writerow(cells)
        return buf.getvalue()

    def write(self, row: dict[str, Any]) -> None:
        self._f.write(self._render([format_value(row.get(c)) for c in self.header]))
        self._f.flush()

    def close(self) -> None:
        self._f.close()


def header_for(columns: list[str]) -> list[str]:
    return ["run_id", *columns, "seed", *RESULT_COLUMNS]


def summarize_rows(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Counts over a table: runs, succeeded, failed, success rate."""
    n = len(rows)
    ok = sum(1 for r in rows if r.get("success") is True)
    return {"runs": n, "succeeded": ok, "failed": n - ok,
            "success_rate": round(ok / n, 4) if n else None}


def write_json(path: Path, data: dict[str, Any]) -> None:
    path.write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
