"""Peer death under ``tfl-mav demo``: one child SIGKILLed mid-flight, how the demo ends.

``tfl-mav demo`` runs ``tfl-mav sim`` and ``tfl-mav fly`` (each with its recorder child).
Each trial starts a demo (``--duration 60 --no-plots``, lockstep or ``--realtime``), waits
until the controller is flying (its ``ctl.mcap`` grows), waits a random 0.5-3 s more, and
SIGKILLs one child, the vehicle or the controller. Measured per trial: wall seconds from
the kill to the demo's exit, its exit code, how many lines it printed on stderr after the
kill (the one line), and which of the processes of the demo's tree (children and their
recorders, listed from ``/proc`` before the kill) were still alive right after the demo
exited (orphans).

Usage: ``python bench/bench_peer_death.py [--trials N] [--seed S] [--json FILE]`` from the
repository root (Linux: reads ``/proc``). Exit status 1 if any trial took over 15 s, printed
other than one line, exited other than 3 or left a process behind.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tfl_mav.tools.harness.processes import CLI

LIMIT_S = 15.0


def _children_of(pid: int) -> list[int]:
    """Every live process whose parent is ``pid`` (from /proc)."""
    out = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as fh:
                stat = fh.read()
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        if ppid == pid:
            out.append(int(entry))
    return out


def _tree(pid: int) -> list[int]:
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        kids = _children_of(p)
        out += kids
        todo += kids
    return out


def _cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as fh:
            return fh.read().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def trial(victim: str, realtime: bool, rng: random.Random) -> dict:
    with tempfile.TemporaryDirectory(prefix="peer-death-") as tmp:
        out = Path(tmp) / "demo"
        cmd = [*CLI, "demo", "paper", "--duration", "60", "--no-plots", "--out", str(out)]
        if realtime:
            cmd.append("--realtime")
        demo = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 60
        ctl = out / "ctl.mcap"
        while time.monotonic() < deadline and not (ctl.exists() and ctl.stat().st_size > 50_000):
            time.sleep(0.05)
        time.sleep(rng.uniform(0.5, 3.0))
        tree = _tree(demo.pid)
        word = "sim" if victim == "vehicle" else "fly"
        target = [p for p in _children_of(demo.pid) if f"tfl_mav.tools.cli {word} " in _cmdline(p)]
        if not target:          # the flight ended (crashed) before the kill: not a trial
            _, err = demo.communicate(timeout=120)
            return {"victim": victim, "realtime": realtime, "skipped": True,
                    "code": demo.returncode, "stderr_lines": err.splitlines()[-2:]}
        t_kill = time.monotonic()
        os.kill(target[0], signal.SIGKILL)
        try:
            _, err = demo.communicate(timeout=120)
        except subprocess.TimeoutExpired:
            demo.kill()
            _, err = demo.communicate()
        t_exit = time.monotonic()
        left = [p for p in tree if _alive(p)]
        for p in left:          # leave the machine clean whatever the result
            os.kill(p, signal.SIGKILL)
        lines = [line for line in err.splitlines() if line.strip()
                 and not line.startswith("  [")            # progress (every 5 s)
                 and not line.startswith("tfl-mav demo: warning:")]   # before the flight
        return {"victim": victim, "realtime": realtime, "exit_s": round(t_exit - t_kill, 2),
                "code": demo.returncode, "stderr_lines": lines, "tree": len(tree),
                "orphans": [_cmdline(p) for p in left]}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=3, help="per (victim, mode) (default 3)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    args = parser.parse_args()
    rng = random.Random(args.seed)
    rows = []
    skipped = []
    for realtime in (False, True):
        for victim in ("vehicle", "controller"):
            for _ in range(args.trials):
                for _attempt in range(3):
                    r = trial(victim, realtime, rng)
                    if not r.get("skipped"):
                        break
                    skipped.append(r)
                    print(f"  (the flight ended before the kill, exit {r['code']}: "
                          f"{r['stderr_lines'][-1] if r['stderr_lines'] else ''}; again)")
                else:
                    continue
                rows.append(r)
                print(f"{'realtime' if realtime else 'lockstep':8s}  {victim:10s}  exit "
                      f"{r['exit_s']:5.2f} s  code {r['code']}  lines {len(r['stderr_lines'])}"
                      f"  processes {r['tree']}  orphans {len(r['orphans'])}", flush=True)
    print(f"\nbench_peer_death (python {platform.python_version()}, {os.cpu_count()} cpus): "
          f"{len(rows)} trials ({len(skipped)} flights ended before their kill, flown "
          f"again), exit after the kill: max "
          f"{max(r['exit_s'] for r in rows):.2f} s; orphans "
          f"{sum(len(r['orphans']) for r in rows)}")
    for r in rows[:1] + [r for r in rows if r["victim"] == "controller"][:1]:
        last = r["stderr_lines"][-1] if r["stderr_lines"] else ""
        print(f"  e.g. ({r['victim']} killed): {last}")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))
    ok = all(r["exit_s"] <= LIMIT_S and r["code"] == 3 and len(r["stderr_lines"]) == 1
             and not r["orphans"] for r in rows)
    print("all trials within the limits" if ok else "LIMIT VIOLATED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
