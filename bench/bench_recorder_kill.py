"""What a SIGKILL mid-run costs the MCAP log of ``tfl-mav sim --mcap``.

``tfl-mav sim --mcap`` records in a child process (``RecorderProcess``,
``tfl_mav/flightlog/recorder_process.py``). A bare lockstep client (raw socket + pymavlink,
hover commands) flies it; at tick ``--kill-at`` it sends SIGKILL to

1. **the recorder child** only: the flight goes on to the end; the file is read back with
   ``tfl_mav.flightlog.logread`` and compared with the frame counts the sim's control link
   reports in ``--json`` (every frame in either direction should be one ``/mavlink/raw``
   message);
2. **the whole process group** (sim and recorder): nothing gets to finish the file; it is
   read up to the damage, rewritten by ``tfl-mav inspect --recover``, and compared with the
   frames the client itself exchanged with the sim before the kill.

Reported per case: frames the link handled, frames recorded on ``/mavlink/raw``, frames
and wire bytes lost, the wall time between the last recorded frame and the kill, whether
the file was complete (footer) and what ``--recover`` wrote.

Usage: ``python bench/bench_recorder_kill.py [--ticks N] [--kill-at K] [--json FILE]``
from the repository root.
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import json
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tfl_mav.flightlog.logread import LogReader
from tfl_mav.tools.harness.pilot import NoStateError, Pilot, hover_controls
from tfl_mav.tools.harness.processes import CLI, popen_sim


def _recorder_child(sim_pid: int) -> int:
    """The pid of the sim's recorder child (multiprocessing spawn, not its tracker)."""
    children = Path(f"/proc/{sim_pid}/task/{sim_pid}/children").read_text().split()
    for pid in children:
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ")
        if b"spawn_main" in cmdline and b"resource_tracker" not in cmdline:
            return int(pid)
    raise RuntimeError(f"no recorder child among {children}")


def _read(path: Path) -> dict[str, object]:
    """Count /mavlink/raw messages and wire bytes, and the last one's log time."""
    reader = LogReader(path)
    frames = wire_bytes = messages = 0
    last_log_ns = 0
    for m in reader.messages():
        messages += 1
        if m.topic == "/mavlink/raw":
            frames += 1
            wire_bytes += len(base64.b64decode(m.json()["data"]))
            last_log_ns = max(last_log_ns, m.log_time_ns)
    return {"raw_frames": frames, "raw_bytes": wire_bytes, "messages": messages,
            "last_raw_log_time_s": last_log_ns * 1e-9, "complete": reader.complete,
            "error": reader.error, "file_bytes": path.stat().st_size}


def run(n_ticks: int, kill_at: int, target: str, tmp: Path) -> dict[str, object]:
    """Fly ``n_ticks``; at ``kill_at`` SIGKILL ``target`` ("recorder" or "group")."""
    from tfl_mav.scenario import load_scenario

    sc = load_scenario("paper")
    mcap = tmp / f"{target}.mcap"
    out_json = tmp / f"{target}.json"
    proc, address = popen_sim(["--set", "attack.rotor=0", "--set",
                               "initial.position_m=[0, 0, 5]", "--duration",
                               f"{n_ticks / 1000.0:g}", "--mcap", str(mcap), "--json",
                               str(out_json)], "paper", start_new_session=True)
    pilot = Pilot(address)
    stats = pilot.link.stats

    def traffic() -> dict[str, int]:
        return {"tx_frames": stats.tx_frames, "tx_bytes": stats.tx_bytes,
                "rx_frames": stats.rx_frames, "rx_bytes": stats.rx_bytes}

    kill_wall_s = 0.0
    at_kill = traffic()
    ticks = 0
    output = ""

    def on_tick(k: int, _odom: object, _esc: object) -> bool:
        nonlocal kill_wall_s, at_kill, ticks
        ticks = k + 1
        if ticks != kill_at:
            return False
        kill_wall_s = time.time()
        at_kill = traffic()
        if target == "recorder":
            os.kill(_recorder_child(proc.pid), signal.SIGKILL)
            return False
        os.killpg(proc.pid, signal.SIGKILL)
        return True                         # the sim is gone: stop flying

    try:
        pilot.hello()
        # Fly until the vehicle's last word (HEARTBEAT POWEROFF), or the group kill.
        with contextlib.suppress(NoStateError):
            pilot.fly(None, hover_controls(sc), timeout_s=5.0, keep=False, on_tick=on_tick)
        client = traffic()
        out, err = proc.communicate(timeout=60)
        output = out + err
    finally:
        if proc.poll() is None:
            proc.kill()
        pilot.close()
    time.sleep(0.2)   # let the killed processes' file descriptors close
    result: dict[str, object] = {"target": target, "ticks": ticks, "kill_at": kill_at,
                                 "exit_code": proc.returncode, "client": client}
    read = _read(mcap)
    result["file"] = read
    if target == "recorder":
        sim = json.loads(out_json.read_text())
        link = sim["stats"]["control_link"]
        handled = link["rx_frames"] + link["tx_frames"] + sum(
            link[k] for k in ("garbage", "mavlink1", "truncated", "bad_flags", "bad_crc",
                              "bad_signature", "malformed", "unknown_id", "foreign",
                              "wrong_sysid", "no_peer"))
        handled_bytes = link["rx_bytes"] + link["tx_bytes"]
        result["reference"] = "sim --json control_link counters"
    else:
        # The sim died: what it exchanged is what the client sent and received (the last
        # reply may still have been in flight; it is counted as handled, a loss of ≤ 1).
        handled = client["tx_frames"] + client["rx_frames"]
        handled_bytes = client["tx_bytes"] + client["rx_bytes"]
        result["reference"] = "frames the client exchanged before the kill"
    before = at_kill["tx_frames"] + at_kill["rx_frames"]
    result["frames_before_kill"] = before
    result["lost_before_kill"] = before - int(read["raw_frames"])
    result["sim_says"] = [ln for ln in output.splitlines() if "record" in ln.lower()
                          or "mcap" in ln.lower()][:3]
    result["handled_frames"] = handled
    result["handled_bytes"] = handled_bytes
    result["lost_frames"] = handled - int(read["raw_frames"])
    result["lost_bytes"] = handled_bytes - int(read["raw_bytes"])
    result["gap_before_kill_s"] = kill_wall_s - float(read["last_raw_log_time_s"]) \
        if read["raw_frames"] else None
    recovered = tmp / f"{target}.recovered.mcap"
    rec = subprocess.run([*CLI, "inspect", str(mcap), "--recover", str(recovered), "--json"],
                         capture_output=True, text=True, timeout=120)
    result["recover_exit_code"] = rec.returncode
    result["recover_says"] = rec.stderr.strip().splitlines()[-1] if rec.stderr.strip() else ""
    if recovered.exists():
        result["recovered"] = _read(recovered)
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ticks", type=int, default=6000, help="lockstep ticks (1 kHz)")
    parser.add_argument("--kill-at", type=int, default=3000, help="tick of the SIGKILL")
    parser.add_argument("--json", metavar="FILE", help="also write the numbers as JSON")
    args = parser.parse_args()
    if not 0 < args.kill_at < args.ticks:
        parser.error("--kill-at: must be between 0 and --ticks")
    with tempfile.TemporaryDirectory() as tmp:
        runs = [run(args.ticks, args.kill_at, "recorder", Path(tmp)),
                run(args.ticks, args.kill_at, "group", Path(tmp))]
    print(f"bench_recorder_kill ({args.ticks} ticks, SIGKILL at tick {args.kill_at}, "
          f"python {platform.python_version()}, {os.cpu_count()} cpus)")
    names = {"recorder": "SIGKILL recorder child", "group": "SIGKILL sim process group"}
    for r in runs:
        f = r["file"]
        rec = r.get("recovered", {})
        gap = r["gap_before_kill_s"]
        print(f"\n  {names[r['target']]} (sim exit {r['exit_code']}, flew {r['ticks']} ticks)")
        print(f"    frames handled ({r['reference']}): {r['handled_frames']} "
              f"({r['handled_bytes']} wire bytes)")
        print(f"    recorded on /mavlink/raw: {f['raw_frames']} ({f['raw_bytes']} wire bytes), "
              f"{f['messages']} messages in all, file {f['file_bytes']} bytes, footer "
              f"{'present' if f['complete'] else 'missing'}"
              + (f" ({f['error']})" if f["error"] else ""))
        print(f"    frames exchanged before the kill (client's count): "
              f"{r['frames_before_kill']}; of those not recorded: {r['lost_before_kill']}")
        for ln in r["sim_says"]:
            print(f"    sim says: {ln[:150]}")
        print(f"    lost: {r['lost_frames']} frames, {r['lost_bytes']} wire bytes"
              + (f"; last recorded frame {gap:.3f} s before the kill" if gap is not None
                 else ""))
        print(f"    inspect --recover: exit {r['recover_exit_code']}, {r['recover_says']}; "
              f"recovered file: {rec.get('messages', 0)} messages, footer "
              f"{'present' if rec.get('complete') else 'missing'}")
    if args.json:
        Path(args.json).write_text(json.dumps(runs, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
