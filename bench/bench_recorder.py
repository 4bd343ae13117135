"""What recording costs the control loop, and what it leaves on disk.

Measures, on this machine, in one run:

1. **control path**: the ``tfl-mav fly`` daemon (in this process) flies ``tfl-mav sim`` (a
   subprocess, lockstep, not recording) with the controller's recorder hooked up the way
   ``tfl-mav fly --mcap`` does it. Every recorder hook (frame hook, per-tick controller
   record, events) is timed with ``perf_counter``: µs per control tick spent *in the
   daemon's thread* handing data to the recorder. Also the daemon's wall time per tick with
   and without recording (same run, alternating).
2. **file size**: a lockstep ``tfl-mav demo`` flight; ``run.mcap`` and ``ctl.mcap`` bytes,
   scaled to one minute of flight.
3. **live server**: the same demo without and with ``--foxglove`` (a WebSocket client
   subscribed to every channel), wall time ratio (only where ``--foxglove`` exists).
4. **recording children**: their CPU per tick on a real lockstep flight's hand-off batches
   (``bench/recorder_replay.py``, which also compares two checkouts and splits by piece),
   and on synthetic frames with and without the live server.

``--before FILE``: a JSON written by an earlier run (e.g. on the commit before the change)
printed side by side; ``--tree DIR``: measure checkout DIR's ``tfl_mav`` and commands with
this bench (its processes run in DIR, DIR first on their path), e.g. a worktree of the
commit before the change, so both columns come from one bench in one session. Usage:
``python bench/bench_recorder.py [--seconds S] [--repeats N] [--json FILE] [--before FILE]
[--tree DIR] [--skip control|files --merge FILE]`` from the repository root. The machine
is shared: compare ratios within one run, and read the load it prints.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]    # the subprocesses' working directory

_LISTEN_RE = re.compile(r"listening on ([\d.]+):(\d+)")


def _cli() -> str:
    """The command line's module in checkout REPO (tfl_mav/cli/ before the tools moved to
    tools/, imported as tfl_mav.tools)."""
    return "tfl_mav.cli" if (REPO / "tfl_mav" / "cli").is_dir() else "tfl_mav.tools.cli"


def _start_sim(seconds: float) -> tuple[subprocess.Popen[str], int]:
    sim = subprocess.Popen(
        [sys.executable, "-m", _cli(), "sim", "paper", "--listen", "127.0.0.1:0",
         "--duration", f"{seconds:g}"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
        text=True, cwd=REPO)
    assert sim.stdout is not None
    for line in sim.stdout:
        if m := _LISTEN_RE.search(line):
            return sim, int(m.group(2))
    raise RuntimeError("sim did not start")


class _Timed:
    """Wraps a hook; adds its wall time to a shared accumulator."""

    def __init__(self, acc: list[float], fn: Any) -> None:
        self.acc, self.fn = acc, fn

    def __call__(self, *a: Any, **k: Any) -> Any:
        t0 = time.perf_counter()
        try:
            return self.fn(*a, **k)
        finally:
            self.acc[0] += time.perf_counter() - t0


def _fly(seconds: float, record: bool, tmp: Path) -> dict[str, float]:
    """One lockstep flight of the daemon in this process; recorder hooks timed."""
    from tfl_mav.controller.daemon import Daemon
    from tfl_mav.scenario import load_scenario

    scenario = load_scenario("paper")
    sim, port = _start_sim(seconds)
    acc = [0.0]
    hooks: dict[str, Any] = {}
    close = None
    if record:
        hooks, close = _fly_recorder(scenario, tmp / "ctl.mcap")
        hooks = {k: _Timed(acc, v) for k, v in hooks.items()}
    daemon = Daemon(scenario, vehicle=("127.0.0.1", port), **hooks)
    t0 = time.perf_counter()
    result = daemon.run(seconds)
    wall = time.perf_counter() - t0
    daemon.close()
    if close is not None:
        close()
    sim.wait(timeout=60)
    ticks = max(result.stats.ticks, 1)
    return {"ticks": ticks, "wall_us_per_tick": wall / ticks * 1e6,
            "hook_us_per_tick": acc[0] / ticks * 1e6}


def _fly_recorder(scenario: Any, path: Path) -> tuple[dict[str, Any], Any]:
    """The recorder hooks of ``tfl-mav fly --mcap`` (its own ``open_recorder``)."""
    open_recorder = importlib.import_module(_cli() + ".fly").open_recorder

    rec = open_recorder(scenario, str(path), None)
    return {"on_frame": rec.on_frame, "on_tick": rec.controller,
            "on_event": lambda lvl, text, t: rec.log(
                lvl if lvl != "critical" else "error", text, t)}, rec.close


def bench_control_path(seconds: float, repeats: int) -> dict[str, Any]:
    rows: dict[str, list[dict[str, float]]] = {"off": [], "on": []}
    with tempfile.TemporaryDirectory() as d:
        for _ in range(repeats):
            for record in (False, True):
                rows["on" if record else "off"].append(_fly(seconds, record, Path(d)))

    def med(key: str, which: str) -> float:
        vals = sorted(r[key] for r in rows[which])
        return vals[len(vals) // 2]

    return {"hook_us_per_tick": med("hook_us_per_tick", "on"),
            "wall_us_per_tick_off": med("wall_us_per_tick", "off"),
            "wall_us_per_tick_on": med("wall_us_per_tick", "on"),
            "throughput_ratio_on_vs_off": med("wall_us_per_tick", "off")
            / med("wall_us_per_tick", "on")}


def _demo(seconds: float, out: Path, foxglove: str | None) -> tuple[float, Path]:
    cmd = [sys.executable, "-m", _cli(), "demo", "paper", "--out", str(out),
           "--duration", f"{seconds:g}", "--no-plots", "--json"]
    if foxglove:
        cmd += ["--foxglove", foxglove]
    t0 = time.perf_counter()
    client = None
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=REPO)
    if foxglove:
        client = _LiveClient(int(foxglove.rsplit(":", 1)[-1]))
        client.start()
    proc.communicate(timeout=600)
    wall = time.perf_counter() - t0
    if client is not None:
        client.stop()
        print(f"  live client received {client.count} messages", file=sys.stderr)
    if proc.returncode not in (0, 1):
        raise RuntimeError(f"demo failed ({proc.returncode})")
    return wall, out


class _LiveClient:
    """A Foxglove WebSocket client (thread) that subscribes to every channel and counts."""

    def __init__(self, port: int) -> None:
        import threading

        self.port, self.count = port, 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(10)

    def _run(self) -> None:
        from websockets.sync.client import connect

        deadline = time.monotonic() + 30
        while not self._stop.is_set() and time.monotonic() < deadline:
            try:
                ws = connect(f"ws://127.0.0.1:{self.port}", open_timeout=1,
                             subprotocols=["foxglove.websocket.v1", "foxglove.sdk.v1"])
                break
            except Exception:           # not listening yet (or refused): try again
                time.sleep(0.05)
        else:
            return
        sub_id = 0
        with ws:
            while not self._stop.is_set():
                try:
                    msg = ws.recv(timeout=0.2)
                except TimeoutError:
                    continue
                except Exception:
                    return
                if isinstance(msg, str):
                    d = json.loads(msg)
                    if d.get("op") == "advertise":
                        subs = []
                        for ch in d["channels"]:
                            sub_id += 1
                            subs.append({"id": sub_id, "channelId": ch["id"]})
                        ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                else:
                    self.count += 1


def bench_child_cost(ticks: int = 3000) -> dict[str, float]:
    """The recording child's own work per tick (decode, encode, write; + live publishing
    to one client subscribed to everything): the CPU the live server adds beside the loop."""
    from tfl_mav.flightlog.recorder import Recorder
    from tfl_mav.link.dialect import mav, new_mavlink
    from tfl_mav.model.airframe import rotor_xy_m
    from tfl_mav.scenario import load_scenario

    v = load_scenario("paper").vehicle
    packer = new_mavlink(1, 1)
    frames = []
    for k in range(ticks):
        for msg in (mav.MAVLink_odometry_message(
                k * 1000, 1, 12, 0.1, 0.2, -1.5, [1.0, 0.0, 0.0, 0.0], 0.1, 0.2, 0.3, 0.0, 0.0,
                0.0, [math.nan] + [0.0] * 20, [math.nan] + [0.0] * 20, 0, 0, 100),
                mav.MAVLink_esc_telemetry_1_to_4_message([30] * 4, [1600] * 4, [500] * 4,
                                                         [10] * 4, [6000] * 4, [0] * 4)):
            frames.append(bytes(msg.pack(packer)))
    out: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as d:
        for live in (False, True):
            port = _free_port()
            rec = Recorder(Path(d) / f"c{live}.mcap", rotor_xy_m=rotor_xy_m(v),
                           thrust_max_n=v.thrust_max_n,
                           live=("127.0.0.1", port) if live else None)
            client = None
            if live:
                client = _LiveClient(port)
                client.start()
                rec.path([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
                time.sleep(1.0)           # connected and subscribed to what is advertised
            t0 = time.process_time()
            for k in range(ticks):
                t = k * 1e-3
                rec.on_frame("rx", frames[2 * k], True, time.time())
                rec.on_frame("rx", frames[2 * k + 1], True, time.time())
                rec.truth(t, [0.1, 0.2, 1.5], [0.0] * 3, [1.0, 0.0, 0.0, 0.0], [0.0] * 3,
                          [2.7, 2.6, 2.8, 2.7], 2, 1.0, 1.0)
            cpu = time.process_time() - t0
            rec.close()
            if client is not None:
                client.stop()
            out["child_cpu_us_per_tick_live" if live else "child_cpu_us_per_tick"] = \
                cpu / ticks * 1e6
    out["live_extra_cpu_fraction"] = (out["child_cpu_us_per_tick_live"]
                                      / out["child_cpu_us_per_tick"] - 1.0)
    return out


def bench_child_flight(seconds: float) -> dict[str, float]:
    """The recording children's CPU per tick on a real lockstep flight's hand-off batches
    (bench/recorder_replay.py: captured, then replayed through the child's batch handler)."""
    import recorder_replay  # bench/recorder_replay.py, next to this file

    with tempfile.TemporaryDirectory() as d:
        recorder_replay.capture(round(seconds * 1000), Path(d))
        res = recorder_replay.measure(Path(d), 3, False, None, Path(d))
    return {"flight_sim_child_us_per_tick": res["run"]["cpu_us_per_tick"],
            "flight_daemon_child_us_per_tick": res["ctl"]["cpu_us_per_tick"]}


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def bench_files_and_live(seconds: float, repeats: int, live: bool) -> dict[str, Any]:
    out: dict[str, Any] = {}
    walls: dict[str, list[float]] = {"off": [], "on": []}
    with tempfile.TemporaryDirectory() as d:
        for i in range(repeats):
            wall, o = _demo(seconds, Path(d) / f"off{i}", None)
            walls["off"].append(wall)
            if i == 0:
                per_min = 60.0 / seconds
                out["run_mcap_mib_per_min"] = (o / "run.mcap").stat().st_size * per_min / 2**20
                out["ctl_mcap_mib_per_min"] = (o / "ctl.mcap").stat().st_size * per_min / 2**20
            if live:
                walls["on"].append(_demo(seconds, Path(d) / f"on{i}",
                                         f"127.0.0.1:{_free_port()}")[0])
    walls = {k: sorted(v) for k, v in walls.items()}
    out["demo_wall_s"] = walls["off"][len(walls["off"]) // 2]
    if live:
        out["demo_wall_s_live"] = walls["on"][len(walls["on"]) // 2]
        out["live_slowdown"] = out["demo_wall_s_live"] / out["demo_wall_s"] - 1.0
    return out


def _use_tree(tree: Path) -> None:
    """Measure checkout ``tree``: this bench again in a fresh interpreter (the tree's own
    venv's if it has one: its editable install maps its own directories) with the tree first
    on PYTHONPATH, inherited by every subprocess; there, the tree is their working directory
    (``python -m`` puts the cwd first)."""
    global REPO
    import tfl_mav

    if not Path(tfl_mav.__file__).resolve().is_relative_to(tree):
        python = tree / ".venv" / "bin" / "python"
        exe = str(python) if python.exists() else sys.executable
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(
            filter(None, (str(tree), os.environ.get("PYTHONPATH")))))
        os.execve(exe, [exe, __file__, *sys.argv[1:]], env)
    for name in ("tfl_mav.sitl", "tfl_mav.tools"):     # the tree's, not another checkout's
        spec = importlib.util.find_spec(name)
        if spec is not None and spec.origin and not Path(spec.origin).resolve().is_relative_to(
                tree):
            raise SystemExit(f"--tree {tree}: {name} imported from {spec.origin}")
    REPO = tree
    import recorder_replay

    recorder_replay.REPO = tree


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=5.0, help="sim seconds per flight")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", metavar="FILE", help="also write the numbers as JSON")
    ap.add_argument("--before", metavar="FILE", help="earlier --json output to compare")
    ap.add_argument("--skip", choices=["control", "files"], action="append", default=[],
                    help="leave out a part (its numbers come from --merge)")
    ap.add_argument("--merge", metavar="FILE", help="take the skipped parts from this JSON")
    ap.add_argument("--tree", metavar="DIR", type=Path,
                    help="measure this checkout instead (see the module docstring)")
    args = ap.parse_args()
    if args.tree:
        _use_tree(args.tree.resolve())
    demo_cmd = importlib.import_module(_cli() + ".demo")

    live = "--foxglove" in Path(demo_cmd.__file__).read_text()
    res: dict[str, Any] = {"machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                                       "load_1min": os.getloadavg()[0]},
                           "seconds": args.seconds, "repeats": args.repeats}
    merged = json.loads(Path(args.merge).read_text()) if args.merge else {}
    if merged:
        res["seconds"], res["repeats"] = merged["seconds"], merged["repeats"]
        args.seconds, args.repeats = merged["seconds"], merged["repeats"]
    res["control_path"] = (merged.get("control_path", {}) if "control" in args.skip
                           else bench_control_path(args.seconds, args.repeats))
    res["files"] = (merged.get("files", {}) if "files" in args.skip
                    else bench_files_and_live(args.seconds, args.repeats, live))
    if live:
        res["child"] = bench_child_cost()
    res["child"] = {**res.get("child", {}), **bench_child_flight(args.seconds)}
    before = json.loads(Path(args.before).read_text()) if args.before else None
    rows = [("recorder hand-off on the fly control path, µs/tick",
             ("control_path", "hook_us_per_tick"), ".1f"),
            ("daemon wall µs/tick, no recording", ("control_path", "wall_us_per_tick_off"),
             ".0f"),
            ("daemon wall µs/tick, recording", ("control_path", "wall_us_per_tick_on"), ".0f"),
            ("throughput recording / not (same run)",
             ("control_path", "throughput_ratio_on_vs_off"), ".2f"),
            ("run.mcap MiB per flight-minute", ("files", "run_mcap_mib_per_min"), ".2f"),
            ("ctl.mcap MiB per flight-minute", ("files", "ctl_mcap_mib_per_min"), ".2f"),
            ("demo wall s (lockstep)", ("files", "demo_wall_s"), ".2f"),
            ("demo wall s with --foxglove + client", ("files", "demo_wall_s_live"), ".2f"),
            ("live server slowdown of the loop", ("files", "live_slowdown"), "+.1%"),
            ("recording child CPU µs/tick (sim side)", ("child", "child_cpu_us_per_tick"),
             ".1f"),
            ("recording child CPU µs/tick, real flight, sim side",
             ("child", "flight_sim_child_us_per_tick"), ".1f"),
            ("recording child CPU µs/tick, real flight, daemon side",
             ("child", "flight_daemon_child_us_per_tick"), ".1f"),
            ("... with the live server + 1 client", ("child", "child_cpu_us_per_tick_live"),
             ".1f"),
            ("live server's extra CPU in the child", ("child", "live_extra_cpu_fraction"),
             "+.1%")]

    def get(d: dict[str, Any] | None, key: tuple[str, str]) -> str:
        return "" if d is None or key[1] not in d.get(key[0], {}) else d[key[0]][key[1]]

    print(f"machine: {os.cpu_count()} cpus, load {res['machine']['load_1min']:.2f}; "
          f"{args.seconds:g} s flights, median of {args.repeats}")
    print(f"{'measure':48s} {'before':>10s} {'now':>10s}")
    for label, key, fmt in rows:
        b, n = get(before, key), get(res, key)
        print(f"{label:48s} {format(b, fmt) if b != '' else '-':>10s} "
              f"{format(n, fmt) if n != '' else '-':>10s}")
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
