"""The campaign report, drawn from ``results.csv`` alone: success by key, envelope maps.

``report.md`` tabulates, for every swept key and each of its values, how many runs succeeded
and how far off the path they were; then why runs failed. Each envelope map
(``map_<x>__<y>.png``) shows two swept keys against each other, every other key and seed
pooled: left, the success rate of each cell (n succeeded / n runs); right, the *worst* max
path distance over the last 10 s in the cell (log scale, crashes marked). Keys with many
distinct values (random samples) are drawn as scatter plots instead of cells.
"""

from __future__ import annotations

import json
import math
import re
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

from tfl_mav.tools.harness.campaign.results import read_results, swept_columns

__all__ = ["default_maps", "success_table", "write_report"]

MAX_CELLS = 12          # more distinct values than this on an axis → scatter plot
DIST = "max_path_distance_last_10s_m"


def _key(v: Any) -> tuple[int, Any]:
    return (0, v) if isinstance(v, (int, float)) and not isinstance(v, bool) else (1, str(v))


def _fmt(v: Any) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def default_maps(keys: list[str], rows: list[dict[str, Any]]) -> list[tuple[str, str]]:
    """Pairs of swept keys that vary: (1st, 2nd), (3rd, 4th); (key, seed) if only one."""
    varying = [k for k in keys if len({str(r[k]) for r in rows}) > 1]
    if len(varying) == 1:
        return [(varying[0], "seed")]
    return [(varying[i], varying[i + 1]) for i in range(0, min(len(varying), 4) - 1, 2)]


def success_table(keys: list[str], rows: list[dict[str, Any]], threshold_m: float | None = None
                  ) -> str:
    """Markdown: success by each swept key's values, then failures by reason."""
    n_ok = sum(r["success"] is True for r in rows)
    lines = [f"{len(rows)} runs, {n_ok} succeeded "
             f"({100 * n_ok / len(rows):.1f} %)" if rows else "no runs", ""]
    if threshold_m is not None:
        lines += [f"Success: not crashed, max path distance over the last 10 s ≤ "
                  f"{threshold_m:g} m, and (rpm detection) the attacked rotor found with no "
                  "false alarm.", ""]
    for key in keys:
        groups: dict[Any, list[dict[str, Any]]] = defaultdict(list)
        for r in rows:
            groups[r[key]].append(r)
        lines += [f"### {key}", "", "| value | runs | succeeded | rate | median dist (m) "
                  "| worst dist (m) | crashed |", "|---|---|---|---|---|---|---|"]
        for value in sorted(groups, key=_key):
            g = groups[value]
            ok = sum(r["success"] is True for r in g)
            d = sorted(r[DIST] for r in g if isinstance(r[DIST], float) and math.isfinite(r[DIST]))
            med = f"{d[len(d) // 2]:.3g}" if d else "-"
            worst = f"{d[-1]:.3g}" if d else "-"
            crashed = sum(r["crashed"] is True for r in g)
            lines.append(f"| {_fmt(value)} | {len(g)} | {ok} | {100 * ok / len(g):.0f} % | "
                         f"{med} | {worst} | {crashed} |")
        lines.append("")
    reasons = Counter(_reason_kind(r["reason"]) for r in rows if r["success"] is not True)
    if reasons:
        lines += ["### failures by reason", "", "| reason | runs |", "|---|---|"]
        lines += [f"| {k} | {n} |" for k, n in reasons.most_common()]
        lines.append("")
    return "\n".join(lines)


def _reason_kind(reason: Any) -> str:
    """The reason without its numbers, so alike failures count together."""
    text = str(reason or "unknown")
    text = re.sub(r"-?\d+(\.\d+)?(e-?\d+)?", "#", text)
    # Flight software failures say what went wrong after their time ("NAME failed at t = #
    # s: raised ..."): keep the what; a crash's time is its tail, cut below.
    text = re.sub(r" at t = # s(?=: )", "", text)
    return text.split(" at t = ")[0]


def write_report(out: Path, not_flown: int = 0) -> list[Path]:
    """Write ``report.md`` and the envelope maps into ``out``; returns the files.
    ``not_flown``: runs of the campaign not in the table (an interrupted campaign: the
    report says it covers only what finished)."""
    header, rows = read_results(out / "results.csv")
    keys = swept_columns(header)
    meta_path = out / "campaign.json"
    meta = json.loads(meta_path.read_text(encoding="utf-8")) if meta_path.exists() else {}
    name = meta.get("name") or out.name
    maps = [tuple(m) for m in meta.get("maps", []) if all(k in header for k in m)]
    maps = maps or default_maps(keys, rows)
    files = []
    md = out / "report.md"
    partial = (f"**Incomplete:** {len(rows)} of {len(rows) + not_flown} runs flown (the "
               "campaign was interrupted; the same command resumes it).\n\n"
               if not_flown else "")
    md.write_text(f"# Campaign {name}\n\n" + partial
                  + success_table(keys, rows, meta.get("success_max_distance_m")) + "\n",
                  encoding="utf-8")
    files.append(md)
    if rows:
        for kx, ky in maps:
            files.append(_draw_map(out, name, rows, kx, ky))
    return files


def _slug(key: str) -> str:
    return re.sub(r"[^A-Za-z0-9_]+", "_", key.split(".")[-1])


def _draw_map(out: Path, name: str, rows: list[dict[str, Any]], kx: str, ky: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    xs = sorted({r[kx] for r in rows}, key=_key)
    ys = sorted({r[ky] for r in rows}, key=_key)
    fig, (ax_ok, ax_d) = plt.subplots(1, 2, figsize=(12, 5), constrained_layout=True)
    dists = [r[DIST] for r in rows if isinstance(r[DIST], float) and r[DIST] > 0]
    lo = max(min(dists), 1e-6) if dists else 1e-6
    hi = max(max(dists), lo * 10) if dists else 1.0
    norm = LogNorm(vmin=lo, vmax=hi)
    if len(xs) <= MAX_CELLS and len(ys) <= MAX_CELLS:
        cells: dict[tuple[int, int], list[dict[str, Any]]] = defaultdict(list)
        for r in rows:
            cells[(xs.index(r[kx]), ys.index(r[ky]))].append(r)
        rate = [[math.nan] * len(xs) for _ in ys]
        worst = [[math.nan] * len(xs) for _ in ys]
        for (i, j), g in cells.items():
            ok = sum(r["success"] is True for r in g)
            rate[j][i] = ok / len(g)
            d = [r[DIST] for r in g if isinstance(r[DIST], float) and r[DIST] > 0]
            crashed = sum(r["crashed"] is not False for r in g)
            worst[j][i] = max(d) if d and not crashed else math.nan
            ax_ok.text(i, j, f"{ok}/{len(g)}", ha="center", va="center", fontsize=8)
            label = (f"{max(d):.2g}" if d else "") if not crashed else f"{crashed} failed\nto fly"
            ax_d.text(i, j, label, ha="center", va="center", fontsize=7,
                      color="black" if crashed else "white")
        im = ax_ok.imshow(rate, origin="lower", cmap="RdYlGn", vmin=0, vmax=1, aspect="auto")
        im2 = ax_d.imshow(worst, origin="lower", cmap="viridis", norm=norm, aspect="auto")
        for ax in (ax_ok, ax_d):
            ax.set_facecolor("#d0d0d0")
            ax.set_xticks(range(len(xs)), [_fmt(x) for x in xs], rotation=30)
            ax.set_yticks(range(len(ys)), [_fmt(y) for y in ys])
    else:
        x = [r[kx] for r in rows]
        y = [r[ky] for r in rows]
        ok = [1.0 if r["success"] is True else 0.0 for r in rows]
        im = ax_ok.scatter(x, y, c=ok, cmap="RdYlGn", vmin=0, vmax=1, s=30, edgecolors="k")
        d = [r[DIST] if isinstance(r[DIST], float) and r[DIST] > 0 and r["crashed"] is False
             else math.nan for r in rows]
        im2 = ax_d.scatter(x, y, c=d, cmap="viridis", norm=norm, s=30, plotnonfinite=True,
                           edgecolors="k")
    fig.colorbar(im, ax=ax_ok, label="success rate (runs pooled over other keys, seeds)")
    fig.colorbar(im2, ax=ax_d, label="worst max path distance, last 10 s (m)")
    for ax in (ax_ok, ax_d):
        ax.set_xlabel(kx)
        ax.set_ylabel(ky)
    ax_ok.set_title(f"{name}: success")
    ax_d.set_title(f"{name}: distance to the path (grey: crashed/failed)")
    path = out / f"map_{_slug(kx)}__{_slug(ky)}.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
