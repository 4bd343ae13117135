"""Peak memory and time of reading a long flight back: ``tfl-mav report`` and ``inspect``.

Flies (or reuses, ``--logs DIR``) a lockstep flight of ``--duration`` sim seconds as
``tfl-mav demo`` does (``sim --mcap run.mcap`` + ``fly --mcap ctl.mcap``; the paper
scenario without its attack, ``--set attack.rotor=0``: with it the paper flight runs away
after ~2 minutes), then runs, each in a fresh process whose peak RSS is the kernel's
(``getrusage(RUSAGE_CHILDREN).ru_maxrss`` of a wrapper that runs only that command):

* ``tfl-mav report RUN.mcap --out DIR`` (the flight rebuilt from both logs, six PNGs,
  ``summary.json``): what the demo's report phase does too;
* ``tfl-mav inspect RUN.mcap --json`` and ``tfl-mav inspect CTL.mcap --json``.

``--tree DIR``: run the commands with checkout DIR's ``tfl_mav`` (e.g. a worktree of the
commit before a change) as well, side by side.

Usage: ``python bench/bench_report_memory.py [--duration 1200] [--logs DIR] [--keep DIR]
[--tree DIR] [--json FILE]`` from the repository root (a 20-minute flight takes ~5 min of
wall time on 2 cores and ~0.9 GB of disk).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from tfl_mav.tools.harness.processes import LISTEN_RE, Proc

_PEAK = ("import resource, subprocess, sys, time; t = time.perf_counter(); "
         "r = subprocess.run(sys.argv[1:], capture_output=True, text=True); "
         "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, "
         "time.perf_counter() - t, r.returncode)")


def fly(duration_s: float, out: Path) -> float:
    """A lockstep flight into ``out``/run.mcap and ctl.mcap; its wall time."""
    common = ["--duration", f"{duration_s:g}", "--set", "attack.rotor=0"]
    t0 = time.perf_counter()
    sim = Proc(["sim", "paper", "--listen", "127.0.0.1:0", "--gcs", "none", "--legacy-ports",
                "--mcap", str(out / "run.mcap"), *common])
    try:
        _, m = sim.wait_for(LISTEN_RE.pattern, 60.0)
        fly_p = Proc(["fly", "paper", "--vehicle", f"127.0.0.1:{m.group(2)}", "--mcap",
                      str(out / "ctl.mcap"), "--quiet", *common])
        fly_p.wait(duration_s * 10 + 600)
        sim.wait(120)
    finally:
        sim.close()
    return time.perf_counter() - t0


def measure(cmd: list[str], tree: Path | None) -> dict[str, Any]:
    """Peak RSS (MB) and wall time (s) of ``python -m tfl_mav.tools.cli CMD`` in a fresh process."""
    env = dict(os.environ)
    if tree is not None:
        env["PYTHONPATH"] = str(tree) + os.pathsep + env.get("PYTHONPATH", "")
    out = subprocess.run([sys.executable, "-c", _PEAK, sys.executable, "-m", "tfl_mav.tools.cli",
                          *cmd], capture_output=True, text=True, env=env,
                         cwd=tree or Path.cwd())
    kb, wall, code = out.stdout.split()
    return {"peak_rss_mb": round(int(kb) / 1024, 1), "wall_s": round(float(wall), 1),
            "exit_code": int(code)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=1200.0, help="sim seconds")
    parser.add_argument("--logs", metavar="DIR", help="use run.mcap/ctl.mcap in DIR, no flight")
    parser.add_argument("--keep", metavar="DIR", help="fly into DIR (kept) instead of a temp dir")
    parser.add_argument("--tree", metavar="DIR", help="also measure checkout DIR's tfl_mav")
    parser.add_argument("--json", metavar="FILE")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        logs = Path(args.logs or args.keep or tmp)
        logs.mkdir(parents=True, exist_ok=True)
        flight_s = None if args.logs else fly(args.duration, logs)
        run, ctl = logs / "run.mcap", logs / "ctl.mcap"
        sizes = {p.name: round(p.stat().st_size / 2**20, 1) for p in (run, ctl)}
        trees: list[tuple[str, Path | None]] = [("this tree", None)]
        if args.tree:
            trees.append((args.tree, Path(args.tree).resolve()))
        rows = []
        for name, tree in trees:
            for label, cmd in (("report", ["report", str(run), "--out", str(Path(tmp) / "rep")]),
                               ("inspect run.mcap", ["inspect", str(run), "--json"]),
                               ("inspect ctl.mcap", ["inspect", str(ctl), "--json"])):
                rows.append({"tree": name, "command": label, **measure(cmd, tree)})
                print(f"  {name:24s} {label:18s} {rows[-1]}", flush=True)
    print(f"\nbench_report_memory: {args.duration:g} s lockstep flight"
          + (f" (flown in {flight_s:.0f} s wall)" if flight_s else f" ({args.logs})")
          + f", files {sizes} MiB, python {platform.python_version()}, "
            f"{os.cpu_count()} cpus")
    for r in rows:
        print(f"  {r['tree']:24s} {r['command']:18s} peak RSS {r['peak_rss_mb']:8.1f} MB, "
              f"{r['wall_s']:6.1f} s, exit {r['exit_code']}")
    if args.json:
        Path(args.json).write_text(json.dumps({"sizes_mib": sizes, "rows": rows}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
