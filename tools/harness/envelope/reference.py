"""The reference column: the same spec flown by another tree's own ``tfl-mav offline``.

An older tree shares no code with this one at run time: each case is its CLI,
``TREE/.venv/bin/tfl-mav offline BASE --set ... --attack-info detector --json``, as a
subprocess, so what it measured is what a user of that tree would have seen. A case whose
key, path kind or signal that tree does not know (its CLI exits 2) is ``n/a``, with its
one-line error as the reason. Its JSON may lack keys this tree has (detection): those stay
None, shown as unknown.
"""

from __future__ import annotations

import json
import os
import subprocess
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

from tfl_mav.tools.harness.envelope.results import NOT_AVAILABLE, CaseResult, outcome_of
from tfl_mav.tools.harness.envelope.spec import Case

__all__ = ["fly_reference", "reference_command"]

OnResult = Callable[[int, int, CaseResult], None]


def reference_command(tree: Path) -> list[str]:
    """How to start ``tfl-mav`` in ``tree`` (its own venv)."""
    exe = tree / ".venv" / "bin" / "tfl-mav"
    if exe.exists():
        return [str(exe)]
    python = tree / ".venv" / "bin" / "python"
    if not python.exists():
        raise FileNotFoundError(f"{tree}: no .venv (make one: cd {tree} && python3 -m venv "
                                f".venv && . .venv/bin/activate && pip install -e '.[test]')")
    # the CLI's import name by the tree's layout: tools/ installed as tfl_mav.tools (today),
    # tfl_mav/cli/ (before the tools moved to the top), or a top-level ``tools`` (before that)
    if (tree / "tfl_mav" / "cli").is_dir():
        module = "tfl_mav.cli"
    elif '"tfl_mav.tools"' in (tree / "pyproject.toml").read_text():
        module = "tfl_mav.tools.cli"
    else:
        module = "tools.cli"
    return [str(python), "-m", module]


def _fly_one(cmd: list[str], tree: Path, case: Case, timeout_s: float) -> CaseResult:
    t0 = time.perf_counter()
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    base = CaseResult(name=case.name, outcome=NOT_AVAILABLE, attack_rotor=case.attack_rotor,
                      base=case.base, settings=case.settings)
    try:
        proc = subprocess.run([*cmd, "offline", *case.offline_args()], cwd=tree, env=env,
                              capture_output=True, text=True, timeout=timeout_s, check=False)
    except subprocess.TimeoutExpired:
        base.outcome, base.reason = "error", f"timed out after {timeout_s:g} s"
        return base
    base.wall_time_s = round(time.perf_counter() - t0, 3)
    if proc.returncode == 2:
        lines = proc.stderr.strip().splitlines()
        base.reason = lines[-1] if lines else "exit 2"
        return base
    try:
        m = json.loads(proc.stdout)
    except json.JSONDecodeError:
        lines = proc.stderr.strip().splitlines()
        base.outcome = "error"
        base.reason = f"exit {proc.returncode}: {lines[-1] if lines else 'no output'}"
        return base
    dist = m.get("max_path_distance_last_10s_m")
    base.outcome = outcome_of(bool(m.get("crashed")), dist)
    base.max_distance_m = dist
    base.rms_distance_m = m.get("rms_path_distance_last_10s_m")
    base.detected_rotor = m.get("detected_rotor")
    base.detection_latency_s = m.get("detection_latency_s")
    base.false_alarms = m.get("false_alarms")
    base.thrust_req_min_n = m.get("thrust_min_n")
    base.thrust_req_max_n = m.get("thrust_max_n")
    base.sim_time_s = m.get("sim_time_s")
    base.reason = m.get("crash_reason") or ""
    return base


def fly_reference(tree: Path, cases: Sequence[Case], *, jobs: int = 2,
                  timeout_s: float = 3600.0,
                  on_result: OnResult | None = None) -> dict[str, CaseResult]:
    """Fly ``cases`` with ``tree``'s CLI, ``jobs`` at a time (longest first)."""
    cmd = reference_command(tree)
    order = sorted(cases, key=lambda c: -c.duration_s)
    out: dict[str, CaseResult] = {}
    with ThreadPoolExecutor(max(1, jobs)) as pool:
        futures = [pool.submit(_fly_one, cmd, tree, c, timeout_s) for c in order]
        for i, fut in enumerate(as_completed(futures), 1):
            r = fut.result()
            out[r.name] = r
            if on_result:
                on_result(i, len(order), r)
    return out

