"""SIGKILL each of a flight's four processes at random moments: are the logs readable, how
much is lost, and does the run say so?

A lockstep flight as ``tfl-mav demo`` flies it: ``tfl-mav sim --mcap run.mcap --json`` and
``tfl-mav fly --mcap ctl.mcap --summary-json --progress``, each recording in a child
process (``RecorderProcess``). At a random moment of the flight (a random whole sim second
between 1 and the duration − 2, as the fly's progress line for it arrives, then a random
0 to ``--window`` wall seconds more) one of four processes gets SIGKILL:

* ``sim`` or ``fly`` (the flight process): its recorder child reads end-of-file and
  finishes the file, marking it cut short (``recording`` metadata). The survivor is
  stopped with SIGTERM a few seconds later (noticing a dead peer is not this bench's
  subject);
* ``sim-recorder`` or ``fly-recorder`` (the child): the flight goes on; the parent says so
  at once (one stderr line), repairs the file in place (``mcaprepair``) and puts the cut in
  its summary JSON.

Then both files are read back with the ``mcap`` library's own reader
(``mcap.reader.make_reader(...).iter_messages()``, CRCs checked): a file it cannot read to
the end is *unreadable*. Loss = the sim time at the kill − the sim time of the last record
the killed side's file keeps (``/sim/truth/state`` in run.mcap, ``/controller/state`` in
ctl.mcap). The sim time at the kill: for a flight process, where its peer's file ends (in
lockstep the peer stops there); for a recorder child, the parent's account (the sim time of
the last call the child took before its pipe broke, ``recording.died_at_sim_s``), and as a
check independent of our code, interpolated between the fly's ``progress`` lines around
the kill (one each sim second, stamped on arrival: late when the machine is loaded, which
reads as more loss, not less). "Says so":
a recorder kill → the parent's "recording cut short" line (and its delay after the kill)
and ``recording.complete`` false in its JSON; a flight-process kill → the file's
``recording`` metadata says ``complete: false``.

Usage: ``python bench/bench_kill_logs.py [--n 20] [--duration 8] [--seed 1] [--json F]``
from the repository root (each run ~4 s wall; 4 × 20 runs ~6 min on 2 cores).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import random
import signal
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from tfl_mav.flightlog.from_mcap import log_metadata
from tfl_mav.flightlog.logread import LogMessage
from tfl_mav.flightlog.mcaprepair import cut_short
from tfl_mav.tools.harness.processes import LISTEN_RE, Proc

TARGETS = ("sim", "fly", "sim-recorder", "fly-recorder")
_PROGRESS = r"^progress ([\d.]+) "


def recorder_child(pid: int) -> int | None:
    """The pid of process ``pid``'s recorder child (multiprocessing spawn, not its
    resource tracker), or None."""
    try:
        children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    except OSError:
        return None
    for child in children:
        try:
            cmdline = Path(f"/proc/{child}/cmdline").read_bytes()
        except OSError:
            continue
        if b"spawn_main" in cmdline and b"resource_tracker" not in cmdline:
            return int(child)
    return None


def read_back(path: Path, topic: str) -> dict[str, Any]:
    """Every message through ``mcap.reader.make_reader``: readable or not, the count, and
    the sim time of the last ``topic`` record."""
    from mcap.reader import make_reader

    out: dict[str, Any] = {"readable": False, "messages": 0, "last_t_s": None,
                           "error": None, "bytes": path.stat().st_size if path.exists() else 0}
    if not path.exists():
        out["error"] = "no file"
        return out
    last = None
    try:
        with open(path, "rb") as f:
            for schema, channel, message in make_reader(f, validate_crcs=True).iter_messages(
                    log_time_order=False):
                out["messages"] += 1
                if channel.topic == topic:
                    last = (schema, message.data)
        out["readable"] = True
    except Exception as exc:
        out["error"] = f"{type(exc).__name__}: {exc}"[:200]
    if last is not None:
        out["last_t_s"] = LogMessage(topic, last[0].name, 0, 0, last[1], last[0]).decode()["t_s"]
    return out


def _wait_gone(pid: int | None, timeout_s: float) -> bool:
    """Wait for a process we did not start (a recorder child) to end."""
    if pid is None:
        return True
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        stat = Path(f"/proc/{pid}/stat")
        try:
            if stat.read_text().split(") ", 1)[1].startswith("Z"):
                return True      # exited, waiting for its parent to reap it
        except (OSError, IndexError):
            return True
        time.sleep(0.05)
    return False


def one_run(target: str, at_s: int, delay_s: float, duration_s: float,
            tmp: Path) -> dict[str, Any]:
    """Fly, SIGKILL ``target`` ``delay_s`` wall seconds after the progress line of sim
    second ``at_s``."""
    run_mcap, ctl_mcap = tmp / "run.mcap", tmp / "ctl.mcap"
    sim_json, fly_json = tmp / "sim.json", tmp / "fly.json"
    for f in (run_mcap, ctl_mcap, sim_json, fly_json):
        f.unlink(missing_ok=True)
    common = ["--duration", f"{duration_s:g}", "--set", "attack.rotor=0"]
    sim = Proc(["sim", "paper", "--listen", "127.0.0.1:0", "--gcs", "none", "--legacy-ports",
                "--mcap", str(run_mcap), "--json", str(sim_json), *common], new_session=True)
    fly = None
    try:
        _, m = sim.wait_for(LISTEN_RE.pattern, 30.0)
        fly = Proc(["fly", "paper", "--vehicle", f"127.0.0.1:{m.group(2)}", "--mcap",
                    str(ctl_mcap), "--summary-json", str(fly_json), "--progress", *common],
                   new_session=True)
        t_line, _ = fly.wait_for(rf"^progress {at_s}\.", 120.0)
        time.sleep(max(0.0, t_line + delay_s - time.monotonic()))
        parent = sim if target.startswith("sim") else fly
        victim = recorder_child(parent.pid) if target.endswith("recorder") else parent.pid
        children = {p.pid: recorder_child(p.pid) for p in (sim, fly)}
        if victim is None:
            return {"target": target, "skipped": "no recorder child found"}
        t_kill = time.monotonic()
        os.kill(victim, signal.SIGKILL)
        said_s = None
        if target.endswith("recorder"):
            try:
                t_said, _ = parent.wait_for("recording cut short", 10.0, after=t_kill)
                said_s = t_said - t_kill
            except TimeoutError:
                pass
            codes = {"sim": sim.wait(120.0), "fly": fly.wait(120.0)}
        else:
            time.sleep(3.0)     # the survivor: given a moment, then stopped cleanly
            survivor = fly if target == "sim" else sim
            survivor.stop(20.0)
            codes = {"sim": sim.popen.wait(30), "fly": fly.popen.wait(30)}
        for child in children.values():       # the orphaned recorder finishes the file
            _wait_gone(child, 60.0)
        progress = [(t, float(x.split()[1])) for t, x in fly.lines
                    if x.startswith("progress ")]
    finally:
        sim.close()
        if fly is not None:
            fly.close()
    run = read_back(run_mcap, "/sim/truth/state")
    ctl = read_back(ctl_mcap, "/controller/state")
    killed_file, peer_file = (run, ctl) if target.startswith("sim") else (ctl, run)
    summary_json = sim_json if target.startswith("sim") else fly_json
    try:
        recording = json.loads(summary_json.read_text()).get("recording")
    except (OSError, ValueError):
        recording = None
    progress_kill = _interpolate(progress, t_kill)
    if target in ("sim", "fly"):
        t_kill_sim = peer_file["last_t_s"]
        how = "peer's file ends"
    else:
        # the parent's account: the sim time of the last call its child took before the
        # pipe broke (the progress lines, stamped on arrival, lag under load: kept aside)
        t_kill_sim = (recording or {}).get("died_at_sim_s")
        how = "parent's account"
    # a readable file with no record yet (killed before its first chunk): lost from 0
    kept = killed_file["last_t_s"] if killed_file["last_t_s"] is not None else (
        0.0 if killed_file["readable"] else None)
    lost = t_kill_sim - kept if t_kill_sim is not None and kept is not None else None
    lost_progress = progress_kill - kept if progress_kill is not None and kept is not None \
        else None
    meta_cut = None
    killed_path = run_mcap if target.startswith("sim") else ctl_mcap
    if killed_file["readable"]:
        meta_cut = cut_short(log_metadata(killed_path))
    if target.endswith("recorder"):
        says = (said_s is not None and recording is not None
                and recording.get("complete") is False)
    else:
        says = meta_cut is not None
    return {"target": target, "at_s": at_s, "delay_s": round(delay_s, 3),
            "exit_codes": codes,
            "run": run, "ctl": ctl, "kill_sim_time_s": t_kill_sim, "kill_time_from": how,
            "lost_s": lost, "lost_by_progress_s": lost_progress, "said_after_s": said_s,
            "summary_recording": recording,
            "file_says_cut": meta_cut, "says_so": says}


def _interpolate(progress: list[tuple[float, float]], t_wall: float) -> float | None:
    """Sim time at monotonic ``t_wall`` from (arrival, sim time) progress lines."""
    before = [p for p in progress if p[0] <= t_wall]
    after = [p for p in progress if p[0] > t_wall]
    if not before:
        return progress[0][1] if progress else None
    if not after:
        return before[-1][1]
    (w0, s0), (w1, s1) = before[-1], after[0]
    return s0 + (s1 - s0) * (t_wall - w0) / (w1 - w0) if w1 > w0 else s0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, default=20, help="kills per process (default 20)")
    parser.add_argument("--duration", type=float, default=8.0,
                        help="sim seconds per flight (default 8)")
    parser.add_argument("--window", type=float, default=0.25,
                        help="kill up to this many wall seconds after a sim second's "
                             "progress line (default 0.25)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--targets", default=",".join(TARGETS))
    parser.add_argument("--json", metavar="FILE", help="also write every run as JSON")
    args = parser.parse_args()
    rng = random.Random(args.seed)
    targets = args.targets.split(",")
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.n):
            for target in targets:
                at = rng.randrange(1, max(2, int(args.duration) - 1))
                r = one_run(target, at, rng.uniform(0.0, args.window), args.duration,
                            Path(tmp))
                runs.append(r)
                print(f"  {i + 1:2d} {target:13s} " + (
                    r.get("skipped") or
                    f"kill at sim {_fmt(r['kill_sim_time_s'])} s, files readable "
                    f"run={r['run']['readable']} ctl={r['ctl']['readable']}, lost "
                    f"{_fmt(r['lost_s'])} s, says so {r['says_so']}"
                    + (f" ({r['said_after_s']:.2f} s after)" if r["said_after_s"] else "")),
                      flush=True)
    print(f"\nbench_kill_logs: {args.n} SIGKILLs per process, {args.duration:g} s lockstep "
          f"flights, seed {args.seed}, python {platform.python_version()}, "
          f"{os.cpu_count()} cpus")
    print(f"  {'process':13s} {'runs':>4s} {'unreadable':>10s} {'lost max s':>10s} "
          f"{'lost median s':>13s} {'said so':>7s} {'said after max s':>16s} "
          f"{'lost max s (progress lines)':>27s}")
    for target in targets:
        rs = [r for r in runs if r["target"] == target and "skipped" not in r]
        unreadable = sum((not r["run"]["readable"]) + (not r["ctl"]["readable"]) for r in rs)
        lost = [r["lost_s"] for r in rs if r["lost_s"] is not None]
        said = [r["said_after_s"] for r in rs if r["said_after_s"] is not None]
        by_progress = [r["lost_by_progress_s"] for r in rs
                       if r["lost_by_progress_s"] is not None]
        print(f"  {target:13s} {len(rs):4d} {unreadable:10d} "
              f"{_fmt(max(lost) if lost else None):>10s} "
              f"{_fmt(statistics.median(lost) if lost else None):>13s} "
              f"{sum(r['says_so'] for r in rs):4d}/{len(rs):<2d} "
              f"{_fmt(max(said) if said else None):>16s} "
              f"{_fmt(max(by_progress) if by_progress else None):>27s}")
    if args.json:
        Path(args.json).write_text(json.dumps(runs, indent=2))
    return 0


def _fmt(x: float | None) -> str:
    return "-" if x is None else f"{x:.3f}"


if __name__ == "__main__":
    sys.exit(main())
