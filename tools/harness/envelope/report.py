"""The envelope's tables: the run table, the baseline diff, and the README block.

Every figure a reader sees is printed from results (a flight or a committed file) by the
functions here, so the README and the closing notes cannot drift from what was flown.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from tfl_mav.tools.harness.envelope.regression import Verdict
from tfl_mav.tools.harness.envelope.results import NOT_AVAILABLE, CaseResult, ResultsFile
from tfl_mav.tools.harness.envelope.spec import Case, EnvelopeSpec

__all__ = ["README_BEGIN", "README_END", "columns_table", "detection_text", "diff_table",
           "fmt_distance", "fmt_mm",
           "markdown", "replace_readme_block", "result_text", "run_table"]

README_BEGIN = "<!-- envelope:begin -->"
README_END = "<!-- envelope:end -->"


def fmt_mm(distance_m: float | None) -> str:
    """A distance in mm, to a precision that reads (0.088, 1.34, 192, 3020 m)."""
    if distance_m is None or not math.isfinite(distance_m):
        return "∞"
    mm = 1000.0 * distance_m
    if mm < 10:
        return f"{mm:.3f}"
    if mm < 100:
        return f"{mm:.2f}"
    if mm < 10000:
        return f"{mm:.0f}"
    return f"{distance_m:.0f} m"


def fmt_distance(distance_m: float | None) -> str:
    """:func:`fmt_mm` with its unit: ``0.088 mm``, ``3020 m``, ``∞``."""
    text = fmt_mm(distance_m)
    return text if text.endswith(" m") or text == "∞" else f"{text} mm"


def result_text(r: CaseResult | None) -> str:
    """``0.088 mm converged`` / ``crashed at 2.3 s`` / ``n/a``."""
    if r is None:
        return "—"
    if r.outcome == NOT_AVAILABLE:
        return NOT_AVAILABLE
    if r.outcome == "crashed":
        at = f" at {r.sim_time_s:.1f} s" if r.sim_time_s is not None else ""
        return f"crashed{at}"
    if r.outcome == "error":
        return "error"
    return f"{fmt_distance(r.max_distance_m)} {r.outcome}"


def detection_text(r: CaseResult | None) -> str:
    """``r2 3 ms`` (rotor, latency), ``missed``, ``none`` (no attack, no alarm), ``?``."""
    if r is None or r.detected_rotor is None:
        return "?"
    fa = f" +{r.false_alarms}fa" if r.false_alarms else ""
    if not r.detected_rotor:
        return ("missed" if r.attack_rotor else "none") + fa
    lat = r.detection_latency_s
    when = f" {1000 * lat:.0f} ms" if lat is not None else ""
    wrong = "" if r.detected_rotor == r.attack_rotor else "!"
    return f"r{r.detected_rotor}{wrong}{when}{fa}"


def _verdict_text(v: Verdict | None) -> str:
    if v is None:
        return ""
    if v.status == "same":
        return "same"
    head = {"regressed": "WORSE", "improved": "better", "new": "NEW"}[v.status]
    return f"{head}: {'; '.join(v.reasons)}"


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A plain-text table, columns padded (the last column is not)."""
    widths = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h)
              for i, h in enumerate(header)]
    lines = []
    for cells in (list(header), ["-" * w for w in widths], *rows):
        padded = [c.ljust(w) for c, w in zip(cells[:-1], widths[:-1], strict=True)]
        lines.append("  ".join([*padded, cells[-1]]).rstrip())
    return "\n".join(lines)


def run_table(cases: Sequence[Case], now: dict[str, CaseResult],
              verdicts: dict[str, Verdict], references: Sequence[ResultsFile] = ()) -> str:
    """case, outcome, mm, detection, [reference trees], vs baseline — one row a case."""
    header = ["case", "now", "detection", *(f"{rf.tree}" for rf in references),
              "vs baseline"]
    rows = []
    for c in cases:
        r = now.get(c.name)
        rows.append([c.name, result_text(r), detection_text(r),
                     *(result_text(rf.get(c.name)) for rf in references),
                     _verdict_text(verdicts.get(c.name))])
    return _table(header, rows)


def columns_table(cases: Sequence[Case], columns: Sequence[ResultsFile]) -> str:
    """case, then each file's result (oldest tree first, as given): no flights. With the
    reference and the baseline it is the table of targets: what used to fly, what flies."""
    header = ["case", *(f"{rf.tree or '?'}" for rf in columns), "note"]
    rows = []
    for c in cases:
        note = c.note + (f" (target ≤ {fmt_mm(c.bound_m)} mm)" if c.bound_m else "")
        rows.append([c.name, *(result_text(rf.get(c.name)) for rf in columns), note])
    return _table(header, rows)


def _outcome_change(old: CaseResult | None, new: CaseResult) -> str:
    if old is None:
        return "new case"
    parts = []
    if old.outcome != new.outcome:
        parts.append(f"{old.outcome} → {new.outcome}")
    if old.detected_rotor != new.detected_rotor:
        parts.append(f"detection {detection_text(old)} → {detection_text(new)}")
    return ", ".join(parts)


def diff_table(cases: Sequence[Case], old: ResultsFile, new: dict[str, CaseResult],
               spec_names: set[str] | None = None) -> str:
    """The before/after of a baseline rewrite, every case flown (for a note or commit
    message); ``spec_names``: every case of the spec (default: ``cases``), so that a
    baseline entry is called removed only when the spec no longer has it."""
    header = ["case", "old mm → new mm", "outcome"]
    rows = []
    changed = 0
    for c in cases:
        n = new.get(c.name)
        if n is None:
            continue
        o = old.get(c.name)
        change = _outcome_change(o, n)
        old_mm = fmt_mm(o.max_distance_m) if o else "—"
        rows.append([c.name, f"{old_mm} → {fmt_mm(n.max_distance_m)}",
                     change or n.outcome])
        changed += bool(change) or o is None or o.max_distance_m != n.max_distance_m
    names = spec_names if spec_names is not None else {c.name for c in cases}
    gone = sorted(set(old.results) - names)
    text = _table(header, rows)
    if gone:
        text += f"\nremoved from the spec: {', '.join(gone)}"
    return text + f"\n{changed} of {len(rows)} cases changed"


def _range_mm(results: Sequence[CaseResult]) -> str:
    flown = [r.max_distance_m for r in results
             if r.outcome in ("converged", "off-path")]
    if not flown:
        return "—"
    finite = [d for d in flown if d is not None and math.isfinite(d)]
    if not finite:
        return "∞"
    lo, hi = min(finite), max(finite)
    if len(finite) < len(flown):
        hi = math.inf
    return fmt_mm(lo) if lo == hi else f"{fmt_mm(lo)} – {fmt_mm(hi)}"


def _outcomes(results: Sequence[CaseResult]) -> str:
    counts: dict[str, int] = {}
    for r in results:
        counts[r.outcome] = counts.get(r.outcome, 0) + 1
    order = ["converged", "off-path", "crashed", NOT_AVAILABLE, "error"]
    return ", ".join(f"{counts[k]} {k}" for k in order if k in counts)


def _md_row(cells: Sequence[str]) -> str:
    return "| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |"


def markdown(spec: EnvelopeSpec, baseline: ResultsFile,
             references: Sequence[ResultsFile] = (), *, every_case: bool = True) -> str:
    """The envelope block: one row per family, then (``every_case``) every case. The
    README holds the families, docs/envelope.md both."""
    ref_cols = [f"{rf.tree} (mm)" for rf in references]
    lines = [
        f"{len(spec.cases)} offline flights (`tools/harness/envelope/cases.toml`), the attack "
        "found from ESC rpm; max distance to the path over the last 10 s; *converged* ≤ 20 mm. "
        "Generated by `tfl-mav envelope --markdown` from the committed baseline"
        + (" and the reference flights of " + ", ".join(f"`{rf.tree}`" for rf in references)
           + " (the same cases flown by that tree's own CLI)" if references else "")
        + "; the test tier (`python -m pytest -m envelope`) fails a case that crashes, "
        "detects another rotor or ends more than max(10 %, 0.05 mm) further off than here.",
        "",
        _md_row(["family", "cases", "outcomes", "max distance (mm)", *ref_cols]),
        _md_row(["---", "---:", "---", "---", *("---" for _ in references)]),
    ]
    for fam in spec.families:
        cases = [c for c in spec.cases if c.family == fam.name]
        base = [baseline.results[c.name] for c in cases if c.name in baseline.results]
        refs = []
        for rf in references:
            got = [rf.results[c.name] for c in cases if c.name in rf.results]
            refs.append(f"{_range_mm(got)} ({_outcomes(got)})" if got else "—")
        lines.append(_md_row([fam.title, str(len(cases)), _outcomes(base) or "—",
                              _range_mm(base), *refs]))
    if not every_case:
        lines += ["", "Every case, with its overrides: [docs/envelope.md](docs/envelope.md)."]
        return "\n".join(lines) + "\n"
    lines += ["", "### Every case", "",
              _md_row(["case", "family", "overrides", "baseline", "detection",
                       *(rf.tree for rf in references)]),
              _md_row(["---", "---", "---", "---", "---", *("---" for _ in references)])]
    for c in spec.cases:
        b = baseline.get(c.name)
        sets = " ".join(f"`{s}`" for s in c.settings) or "—"
        base = c.base if c.base == "paper" else f"{c.base}:"
        overrides = sets if c.base == "paper" else f"{base} {sets}"
        lines.append(_md_row([c.name, c.family, overrides, result_text(b), detection_text(b),
                              *(result_text(rf.get(c.name)) for rf in references)]))
    return "\n".join(lines) + "\n"


def replace_readme_block(readme: Path, block: str,
                         markers: tuple[str, str] = (README_BEGIN, README_END)) -> bool:
    """Put ``block`` between the file's ``markers`` (default: the envelope's); True if the
    file changed. Raises ValueError when the markers are missing or out of order."""
    text = readme.read_text(encoding="utf-8")
    new = readme_with_block(text, block, markers)
    if new == text:
        return False
    readme.write_text(new, encoding="utf-8")
    return True


def readme_block(text: str, markers: tuple[str, str] = (README_BEGIN, README_END)) -> str:
    """What the text holds between its ``markers`` (without them)."""
    start, end = _markers(text, markers)
    return text[start + len(markers[0]):end].strip("\n") + "\n"


def readme_with_block(text: str, block: str,
                      markers: tuple[str, str] = (README_BEGIN, README_END)) -> str:
    start, end = _markers(text, markers)
    return text[:start + len(markers[0])] + "\n" + block.rstrip("\n") + "\n" + text[end:]


def _markers(text: str, markers: tuple[str, str]) -> tuple[int, int]:
    begin, end_marker = markers
    start, end = text.find(begin), text.find(end_marker)
    if start < 0 or end < start:
        raise ValueError(f"no {begin} … {end_marker} block")
    return start, end
