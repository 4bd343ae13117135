"""Fly a scenario end to end over MAVLink: simulator and controller daemon as two processes.

The library behind ``tfl-mav demo`` (and the golden lockstep tests): starts ``tfl-mav sim``
and ``tfl-mav fly`` on free loopback ports in lockstep (or real time), both recording MCAP,
then rebuilds the flight from the logs and returns the summary dict.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from harness.processes import raise_priority
from tfl_mav.build import scenario_path
from tfl_mav.flightlog.flight import summarize
from tfl_mav.flightlog.from_mcap import flight_log_from_mcap
from tfl_mav.flightlog.logread import LogReader
from tfl_mav.scenario import apply_overrides, load_scenario

__all__ = ["run_demo"]

_LISTEN_RE = re.compile(r"listening on ([\d.]+):(\d+)")
_PROGRESS_RE = re.compile(r"^progress ([\d.]+) ([\d.]+) (\S+)")


def _cli() -> list[str]:
    return [sys.executable, "-m", "tools.cli"]


def run_demo(name: str, out: Path, *, settings: list[str] | None = None,
             duration_s: float | None = None, plots: bool = True, progress: bool = False,
             scenario: Any = None, key_file: str | None = None,
             foxglove: str | None = None, realtime: bool = False) -> dict[str, Any]:
    """Fly ``name`` over MAVLink in two processes; returns the summary dict. ``key_file``:
    sign the link (both processes get ``--key-file``); ``foxglove``: the simulator serves
    the live view there (``--foxglove``); ``realtime``: both run with ``--realtime`` (paced
    by the wall clock, at raised priority when allowed) instead of lockstep."""
    settings = list(settings or [])
    scenario = scenario or apply_overrides(load_scenario(name), settings)
    scenario_path(scenario)   # ScenarioError for a bad path now, before any process starts
    duration = duration_s if duration_s is not None else scenario.run.duration_s
    out.mkdir(parents=True, exist_ok=True)
    run_mcap, ctl_mcap, fly_json = out / "run.mcap", out / "ctl.mcap", out / "fly.json"
    for f in (run_mcap, ctl_mcap, fly_json):
        f.unlink(missing_ok=True)
    shared = [a for s in settings for a in ("--set", s)]
    if key_file:
        shared += ["--key-file", str(key_file)]
    if realtime:
        shared += ["--realtime"]
    pre = raise_priority if realtime else None
    t0 = time.perf_counter()
    sim = subprocess.Popen(
        [*_cli(), "sim", name, "--listen", "127.0.0.1:0", "--duration", str(duration),
         "--mcap", str(run_mcap), *shared, *(["--foxglove", foxglove] if foxglove else [])],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=pre)
    try:
        port = _await_port(sim)
        fly = subprocess.Popen(
            [*_cli(), "fly", name, "--vehicle", f"127.0.0.1:{port}", "--duration",
             str(duration), "--mcap", str(ctl_mcap), "--summary-json", str(fly_json),
             "--progress", *shared],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, preexec_fn=pre)
        fly_err = _follow(fly, duration, progress)
        fly_code = fly.wait(timeout=60)
        sim_out, sim_err = sim.communicate(timeout=60)
    finally:
        for p in (sim,):
            if p.poll() is None:
                p.kill()
    wall = time.perf_counter() - t0
    if not fly_json.exists():
        raise RuntimeError(f"the controller did not finish (exit {fly_code}):\n{fly_err}")
    fly_summary = json.loads(fly_json.read_text())
    log = flight_log_from_mcap(run_mcap, scenario, ctl_mcap)
    log.crashed = sim.returncode == 1
    log.crash_reason = _crash_reason(sim_out + sim_err) if log.crashed else ""
    log.wall_time_s = wall
    m = summarize(log)
    m.update(_detection_metrics(scenario, fly_summary, log, ctl_mcap))
    m.update(_traffic_metrics(run_mcap, ctl_mcap, fly_summary))
    m["real_time_factor"] = round(m["sim_time_s"] / wall, 2) if wall else None
    m["out_dir"] = str(out)
    if plots:
        from tfl_mav.flightlog.plots import write_report

        m["plots"] = [str(p) for p in write_report(log, out, title=scenario.name)]
    (out / "summary.json").write_text(json.dumps(m, indent=2))
    return m


def _await_port(sim: subprocess.Popen[str]) -> int:
    assert sim.stdout is not None
    deadline = time.monotonic() + 30.0
    lines = []
    while time.monotonic() < deadline:
        line = sim.stdout.readline()
        if not line:
            break
        lines.append(line)
        if match := _LISTEN_RE.search(line):
            return int(match.group(2))
    err = sim.stderr.read() if sim.stderr and sim.poll() is not None else ""
    raise RuntimeError("the simulator did not start: " + "".join(lines) + err)


def _follow(fly: subprocess.Popen[str], duration: float, show: bool) -> str:
    """Render the controller's progress lines; return its other stderr text."""
    assert fly.stderr is not None
    other = []
    for line in fly.stderr:
        if match := _PROGRESS_RE.match(line):
            if show:
                t, total, dist = float(match.group(1)), float(match.group(2)), match.group(3)
                n = int(30 * min(1.0, t / total)) if total else 30
                print(f"\r  [{'#' * n}{'.' * (30 - n)}] {t:5.1f}/{total:.0f} s sim, "
                      f"path distance {dist} m ", end="", file=sys.stderr, flush=True)
        else:
            other.append(line)
    if show:
        print(file=sys.stderr)
    return "".join(other)


def _crash_reason(text: str) -> str:
    for line in text.splitlines():
        if "crash" in line.lower() or "flipped" in line.lower():
            return line.strip()
    return "crashed"


def _detection_metrics(sc: Any, fly: dict[str, Any], log: Any,
                       ctl_mcap: Path) -> dict[str, Any]:
    rotor = int(fly.get("detected_rotor") or 0)
    det_t = fly.get("detection_time_s")
    attacked = sc.attack.rotor
    start = sc.attack.start_s
    latency = det_t - start if (rotor and det_t is not None and attacked) else None
    false_alarm = bool(rotor) and (not attacked or rotor != attacked or det_t < start - 1e-9)
    rms = None
    if rotor and rotor == attacked:
        est = log["attack_estimate_n"]
        ok = np.isfinite(est)
        if np.any(ok):
            # The detector estimates the rotor's *actual* thrust (from its rpm); with motor
            # lag that trails the attacker's command, so compare with the rotor's thrust.
            true_f = log["thrust_true_n"][:, rotor - 1]
            rms = float(np.sqrt(np.mean((est[ok] - true_f[ok]) ** 2)))
    dt = sc.run.control_dt_s
    return {"detected_rotor": rotor, "detection_time_s": det_t,
            "detection_latency_s": latency,
            "detection_latency_ticks": round(latency / dt) if latency is not None else None,
            "attack_estimate_rms_n": rms, "false_alarms": int(false_alarm),
            "missed_detection": bool(attacked) and rotor == 0}


def _traffic_metrics(run_mcap: Path, ctl_mcap: Path, fly: dict[str, Any]) -> dict[str, Any]:
    logged = 0
    sent = 0
    for path in (run_mcap, ctl_mcap):
        if not path.exists():
            continue
        for m in LogReader(path).messages({"/mavlink/raw"}):
            logged += 1
            if m.json().get("direction") == "tx":
                sent += 1
    link = fly.get("stats", {}).get("link", {})
    return {"messages_logged": logged, "messages_sent": sent,
            "controller_rejected_frames": sum(v for k, v in link.items() if k not in
                                              ("rx_datagrams", "rx_bytes", "rx_frames",
                                               "tx_frames", "tx_bytes"))}
