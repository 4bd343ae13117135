"""Fly a scenario end to end over MAVLink: simulator and controller daemon as two processes.

The library behind ``tfl-mav demo`` (and the golden lockstep tests): starts ``tfl-mav sim``
and ``tfl-mav fly`` on free loopback ports in lockstep (or real time), both recording MCAP,
then rebuilds the flight from the logs and returns the summary dict.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from tfl_mav.flightlog.atomic import write_text_atomic
from tfl_mav.flightlog.flight import summarize
from tfl_mav.flightlog.from_mcap import flight_log_from_mcap
from tfl_mav.flightlog.logread import raw_frames
from tfl_mav.flightlog.metrics import DEFAULT_BOUND_M, DEFAULT_WINDOW_S, flight_verdict
from tfl_mav.from_scenario import scenario_path
from tfl_mav.scenario import apply_overrides, load_scenario
from tfl_mav.tools.harness.processes import raise_priority

__all__ = ["DemoError", "run_demo"]

_LISTEN_RE = re.compile(r"listening on ([\d.]+):(\d+)")
_PROGRESS_RE = re.compile(r"^progress ([\d.]+) ([\d.]+) (\S+)")


def _cli() -> list[str]:
    return [sys.executable, "-m", "tfl_mav.tools.cli"]


class DemoError(RuntimeError):
    """The demo cannot give a flight report (a process did not start, died, or failed);
    the message is one line that says what happened and where the files are."""


class _Children:
    """The demo's child processes, stopped whatever happens to the demo.

    Each child runs in its own session (so a terminal's Ctrl-C reaches only the demo, which
    decides); SIGINT/SIGTERM to the demo, from a terminal or to its PID alone, are forwarded
    as SIGTERM (a clean stop: MCAP files finished), and :meth:`reap` waits a grace period
    and then SIGKILLs whatever is left, the children's own children (the recorders) too:
    their process groups are waited for until empty. No orphan either way.
    """

    GRACE_S = 10.0

    def __init__(self) -> None:
        self.procs: list[subprocess.Popen[str]] = []
        self.signals: list[int] = []
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> _Children:
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._previous[sig] = signal.signal(sig, self._on_signal)
        return self

    def __exit__(self, *exc: object) -> None:
        self.reap()
        for sig, old in self._previous.items():
            signal.signal(sig, old)

    def start(self, cmd: list[str], **kw: Any) -> subprocess.Popen[str]:
        p = subprocess.Popen(cmd, text=True, start_new_session=True, **kw)
        self.procs.append(p)
        if self.signals:      # a signal arrived while starting it
            p.terminate()
        return p

    def _on_signal(self, signum: int, _frame: Any) -> None:
        self.signals.append(signum)
        for p in self.procs:
            if p.poll() is None:
                (p.kill if len(self.signals) > 1 else p.terminate)()

    def reap(self) -> None:
        deadline = time.monotonic() + self.GRACE_S
        for p in self.procs:
            if p.poll() is None and self.signals:
                p.terminate()
            try:
                p.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=10)
        # A child's recorder finishes its file after the child is gone (it reads
        # end-of-file), in the child's process group: wait for the group to empty, then
        # kill what is left, so nothing outlives the demo.
        for p in self.procs:
            while _group_alive(p.pid) and time.monotonic() < deadline:
                time.sleep(0.05)
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(p.pid, signal.SIGKILL)


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except (ProcessLookupError, PermissionError):
        return False
    return True


# After one child ended as a flight ends (0 flown, 1 crashed), the other has this long to
# follow (it reads the goodbye at once, then finishes its files) before it is stopped
_PEER_GRACE_S = 5.0
# A child whose peer is alive but silent (hung, stopped) this long ends by itself (exit 3):
# far above any pause of a healthy lockstep peer, well inside the demo's 15 s promise
_CHILD_PEER_TIMEOUT_S = 10.0


def _exit_text(code: int) -> str:
    """How a child ended, in words: "exit 3" or "killed by SIGKILL"."""
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit {code}"


def _supervise(children: _Children, sim: subprocess.Popen[str],
               fly: subprocess.Popen[str], t0: float) -> str | None:
    """Wait until both children have ended; None if the flight ended as flights end, else
    one line saying which died how. Either ending first is watched (every 0.1 s): one
    killed by a signal or failing (exit other than 0 flown or 1 crashed) has its peer
    stopped at once (SIGTERM: a clean stop) and is reported; one that ended normally has
    its peer stopped if it has not followed within :data:`_PEER_GRACE_S` (lockstep peers
    would otherwise wait for a restart forever), and the flight is reported as flown."""
    names = {id(sim): "the vehicle (tfl-mav sim)", id(fly): "the controller (tfl-mav fly)"}
    first: tuple[subprocess.Popen[str], float] | None = None
    while True:
        if children.signals:
            return None                       # interrupted: the caller says so
        codes = sim.poll(), fly.poll()
        if None not in codes:
            break
        if first is None:
            for p, code in zip((sim, fly), codes, strict=True):
                if code is not None:
                    first = (p, time.monotonic())
                    break
        if first is not None:
            ended, when = first
            other = fly if ended is sim else sim
            code = ended.returncode
            died = code not in (0, 1)
            if died or time.monotonic() - when > _PEER_GRACE_S:
                other.terminate()             # a clean stop: its files are finished
                try:
                    other.wait(timeout=children.GRACE_S)
                except subprocess.TimeoutExpired:
                    other.kill()
                    other.wait(timeout=10)
                if not died:
                    return None               # flown; the other only lingered
                return (f"{names[id(ended)]} ended ({_exit_text(code)}) "
                        f"{when - t0:.1f} s into the run; "
                        f"{names[id(other)].split(' (')[0]} was stopped")
        time.sleep(0.1)
    # Both ended by themselves: a failure of either is still a failure to report.
    for p in (sim, fly):
        if p.returncode not in (0, 1):
            return f"{names[id(p)]} ended ({_exit_text(p.returncode)})"
    return None


class _Drain:
    """Read a child's pipe to its end on a thread (a full pipe would stall the child)."""

    def __init__(self, stream: Any, handle: Any = None, echo: bool = False) -> None:
        self.lines: list[str] = []
        self._handle = handle
        self._echo = echo           # show a "recording cut short" line when it comes
        self._thread = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._thread.start()

    def _read(self, stream: Any) -> None:
        if self._handle is not None:
            self.lines.append(self._handle(stream))
            return
        for line in stream:
            self.lines.append(line)
            if self._echo and "recording cut short" in line:
                print(("\n" if sys.stderr.isatty() else "") + line.rstrip(), file=sys.stderr,
                      flush=True)

    def text(self, timeout_s: float = 5.0) -> str:
        self._thread.join(timeout_s)
        return "".join(self.lines)


def _last_line(text: str) -> str:
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return lines[-1] if lines else "no output"


def run_demo(name: str, out: Path, *, settings: list[str] | None = None,
             duration_s: float | None = None, plots: bool = True, progress: bool = False,
             scenario: Any = None, key_file: str | None = None,
             foxglove: str | None = None, realtime: bool = False,
             bound_m: float = DEFAULT_BOUND_M, window_s: float = DEFAULT_WINDOW_S
             ) -> dict[str, Any]:
    """Fly ``name`` over MAVLink in two processes; returns the summary dict. ``key_file``:
    sign the link (both processes get ``--key-file``); ``foxglove``: the simulator serves
    the live view there (``--foxglove``); ``realtime``: both run with ``--realtime`` (paced
    by the wall clock, at raised priority when allowed) instead of lockstep. SIGINT/SIGTERM
    stop both children and the summary says ``interrupted`` (its ``signal`` key names the
    signal)."""
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
    with _Children() as children:
        sim = children.start(
            [*_cli(), "sim", name, "--listen", "127.0.0.1:0", "--gcs", "none",
             "--legacy-ports", "--duration", str(duration), "--mcap", str(run_mcap),
             "--peer-timeout", str(_CHILD_PEER_TIMEOUT_S), *shared,
             *(["--foxglove", foxglove] if foxglove else [])],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, preexec_fn=pre)
        port = _await_port(sim)
        sim_out, sim_err = _Drain(sim.stdout), _Drain(sim.stderr, echo=progress)
        fly = children.start(
            [*_cli(), "fly", name, "--vehicle", f"127.0.0.1:{port}", "--duration",
             str(duration), "--mcap", str(ctl_mcap), "--summary-json", str(fly_json),
             "--progress", "--peer-timeout", str(_CHILD_PEER_TIMEOUT_S), *shared],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, preexec_fn=pre)
        fly_err = _Drain(fly.stderr, lambda stream: _follow(stream, duration, progress))
        died = _supervise(children, sim, fly, time.monotonic())
    interrupted = bool(children.signals)
    wall = time.perf_counter() - t0
    if died is not None and not interrupted:
        raise DemoError(f"{died}: no flight report; what was recorded is in {out}/")
    say = _Say(progress)
    say.line(f"  flight: {duration:g} s of sim time in {wall:.1f} s wall")
    if not fly_json.exists() and not interrupted:
        raise DemoError(f"the controller did not finish (exit {fly.returncode}): "
                        f"{_last_line(fly_err.text())}")
    try:
        fly_summary = json.loads(fly_json.read_text()) if fly_json.exists() else {}
    except (OSError, ValueError) as exc:
        raise DemoError(f"{fly_json}: unreadable controller summary ({exc})") from None
    sim_out_text, sim_err_text = sim_out.text(), sim_err.text()
    t1 = time.perf_counter()
    size_mib = sum(f.stat().st_size for f in (run_mcap, ctl_mcap) if f.exists()) / 2**20
    say.start(f"  report: reading run.mcap and ctl.mcap ({size_mib:.0f} MiB) ...")
    log = flight_log_from_mcap(run_mcap, scenario, ctl_mcap)
    log.crashed = sim.returncode == 1
    log.crash_reason = _crash_reason(sim_out_text + sim_err_text) if log.crashed else ""
    log.wall_time_s = wall
    log.duration_s = duration
    log.interrupted = interrupted
    m = summarize(log)
    if len(log["t_s"]) == 0:      # no sample (a log cut before the flight): no number
        m.update({k: None for k in _NUMBERS if k not in m}, wall_time_s=round(wall, 3))
    m.update(flight_verdict(log, bound_m=bound_m, window_s=window_s))
    if interrupted:
        m["signal"] = signal.Signals(children.signals[0]).name
    m.update(_detection_extras(scenario, m, log))
    m.update(_traffic_metrics(run_mcap, ctl_mcap, fly_summary))
    if m.get("log_cut_short") and fly_summary.get("sim_time_s") is not None:
        # the flight went on past the end of its log: flown is the controller's account
        m["log_sim_time_s"], m["sim_time_s"] = m["sim_time_s"], fly_summary["sim_time_s"]
    m["real_time_factor"] = round(m["sim_time_s"] / wall, 2) if wall else None
    m["out_dir"] = str(out)
    phases = {"flight": round(wall, 3), "report": round(time.perf_counter() - t1, 3)}
    say.end(f" {phases['report']:.1f} s")
    if plots:
        t2 = time.perf_counter()
        say.start("  plots: drawing the six PNGs ...")
        from tfl_mav.flightlog.plots import write_report

        try:
            m["plots"] = [str(p) for p in write_report(log, out, title=scenario.name)]
        except OSError as exc:
            raise DemoError(f"cannot write the plots in {out}: "
                               f"{exc.strerror or exc}") from None
        phases["plots"] = round(time.perf_counter() - t2, 3)
        say.end(f" {phases['plots']:.1f} s")
    m["phase_wall_s"] = phases         # what the user waited for, phase by phase
    m["total_wall_s"] = round(time.perf_counter() - t0, 3)
    try:
        write_text_atomic(out / "summary.json", json.dumps(m, indent=2))
    except OSError as exc:
        raise DemoError(f"cannot write {out / 'summary.json'}: "
                           f"{exc.strerror or exc}") from None
    return m


_NUMBERS = ("final_path_distance_m", "max_path_distance_last_10s_m",
            "rms_path_distance_last_10s_m", "thrust_min_n", "thrust_max_n",
            "saturated_fraction", "max_yaw_rate_radps", "detected_rotor", "false_alarms")


class _Say:
    """The demo's phase lines on stderr as the user waits for them (nothing when quiet):
    a phase is announced when it starts and timed when it ends."""

    def __init__(self, on: bool) -> None:
        self.on = on

    def line(self, text: str) -> None:
        if self.on:
            print(text, file=sys.stderr, flush=True)

    def start(self, text: str) -> None:
        if self.on:
            print(text, end="", file=sys.stderr, flush=True)

    def end(self, text: str) -> None:
        self.line(text)


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
    raise DemoError("the simulator did not start: " + _last_line("".join(lines) + err))


def _follow(stream: Any, duration: float, show: bool) -> str:
    """Render the controller's progress lines (its stderr ``stream``); return its other
    stderr text."""
    other = []
    tty = sys.stderr.isatty()    # a terminal: one bar redrawn; a file or pipe: a line each 5 s
    drawn = False
    for line in stream:
        if match := _PROGRESS_RE.match(line):
            t, total, dist = float(match.group(1)), float(match.group(2)), float(match.group(3))
            if show and (tty or round(t) % 5 == 0):
                n = int(30 * min(1.0, t / total)) if total else 30
                print(f"{chr(13) if tty else ''}  [{'#' * n}{'.' * (30 - n)}] {t:5.1f}/"
                      f"{total:.0f} s sim, path distance {_length(dist)} ",
                      end="" if tty else "\n", file=sys.stderr, flush=True)
                drawn = tty
        else:
            other.append(line)
            if show and "recording cut short" in line:   # said at once, not at the end
                print(("\n" if drawn else "") + line.rstrip(), file=sys.stderr, flush=True)
                drawn = False
    if drawn:
        print(file=sys.stderr)
    return "".join(other)


def _length(x_m: float) -> str:
    """A distance in the unit that shows it: mm below a metre, µm below a millimetre."""
    if not math.isfinite(x_m):
        return "-"
    if abs(x_m) >= 1.0:
        return f"{x_m:.2f} m"
    if abs(x_m) >= 1e-3:
        return f"{x_m * 1e3:.1f} mm"
    return f"{x_m * 1e6:.1f} µm"


def _crash_reason(text: str) -> str:
    for line in text.splitlines():
        if "crash" in line.lower() or "flipped" in line.lower():
            return line.strip()
    return "crashed"


def _detection_extras(sc: Any, m: dict[str, Any], log: Any) -> dict[str, Any]:
    """What only the demo adds to the shared detection metrics (:mod:`..metrics`): the
    latency in ticks and the RMS error of the attack estimate."""
    rotor = m.get("detected_rotor") or 0
    attacked = sc.attack.rotor
    latency = m.get("detection_latency_s")
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
    return {"detection_latency_ticks": round(latency / dt) if latency is not None else None,
            "attack_estimate_rms_n": rms}


def _traffic_metrics(run_mcap: Path, ctl_mcap: Path, fly: dict[str, Any]) -> dict[str, Any]:
    logged = 0
    sent = 0
    for path in (run_mcap, ctl_mcap):
        if not path.exists():
            continue
        for _m, _raw, tx, _rejected in raw_frames(path):
            logged += 1
            sent += tx
    link = fly.get("stats", {}).get("link", {})
    return {"messages_logged": logged, "messages_sent": sent,
            "controller_rejected_frames": sum(v for k, v in link.items() if k not in
                                              ("rx_datagrams", "rx_bytes", "rx_frames",
                                               "tx_frames", "tx_bytes"))}
