"""A fuzzing run over real loopback sockets: the batches, the runner, the reports."""

from __future__ import annotations

import math
import random
import socket
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from tfl_mav.link.dialect import mav, new_mavlink
from tfl_mav.tools.harness.fuzz.generators import (
    DAEMON_CATEGORIES,
    VEHICLE_CATEGORIES,
    DaemonGen,
    VehicleGen,
)
from tfl_mav.tools.harness.fuzz.models import DaemonModel, VehicleModel
from tfl_mav.tools.harness.fuzz.wire import (
    DAEMON_ACCEPTS,
    DAEMON_REJECTS,
    FUZZER_COMPID,
    FUZZER_SYSID,
    LINK_REASONS,
    STATE_TIMEOUT_S,
    VEHICLE_ACCEPTS,
    VEHICLE_REJECTS,
    nonfinite_floats,
)
from tfl_mav.tools.harness.pilot import NoStateError, Pilot


# ---------------------------------------------------------------------------- reports
@dataclass
class CategoryReport:
    """One category of one endpoint: what was sent and what the endpoint counted."""

    sent: int = 0                # hostile datagrams sent
    arrived: int = 0             # of those, received by the endpoint (rx_datagrams)
    counted: Counter[str] = field(default_factory=Counter)   # endpoint's counter deltas
    expected: Counter[str] = field(default_factory=Counter)  # the model's prediction
    batches: int = 0
    mismatched_batches: int = 0
    lost_batches: int = 0
    skipped: int = 0             # run-ending legitimate inputs not sent (module docstring)


@dataclass
class EndpointReport:
    endpoint: str
    seed: int
    categories: dict[str, CategoryReport]
    crashes: list[str]
    nan_to_physics: int          # vehicle: ticks with a non-finite state/command/thrust
    nan_to_motors: int           # daemon: HIL_ACTUATOR_CONTROLS non-finite or out of [0, 1]
    nonfinite_tx: list[str]      # any frame either endpoint sent with a NaN/inf float
    mismatches: list[str]        # first few batches where counters ≠ model
    ticks: int
    elapsed_s: float
    completed: bool

    @property
    def sent(self) -> int:
        return sum(c.sent for c in self.categories.values())

    @property
    def inputs_per_s(self) -> float:
        return self.sent / self.elapsed_s if self.elapsed_s > 0 else math.nan


def _rejects(counted: Counter[str], endpoint_rejects: tuple[str, ...]) -> Counter[str]:
    return Counter({k: v for k, v in counted.items()
                    if k in LINK_REASONS or k in endpoint_rejects})


def rejected_total(c: CategoryReport, endpoint: str) -> int:
    rej = VEHICLE_REJECTS if endpoint == "vehicle" else DAEMON_REJECTS
    return sum(_rejects(c.counted, rej).values())


def reject_reasons(c: CategoryReport, endpoint: str) -> Counter[str]:
    rej = VEHICLE_REJECTS if endpoint == "vehicle" else DAEMON_REJECTS
    return _rejects(c.counted, rej)


# ---------------------------------------------------------------------------- harness
def _schedule(categories: tuple[str, ...], n_inputs: int, rng: random.Random,
              batch: int) -> Iterator[tuple[str, int]]:
    """(category, size) per tick until ``n_inputs`` hostile datagrams: categories in a
    seeded random order, each drawn about equally often."""
    sent = 0
    while sent < n_inputs:
        cat = rng.choice(categories)
        size = 1 if cat in ("oversize", "bad_controls", "extreme_state") \
            else min(batch, n_inputs - sent)
        if cat in ("bad_controls", "extreme_state"):
            yield cat, 0
            sent += 1
            continue
        yield cat, size
        sent += size


class _Endpoint:
    """The endpoint's thread, and what escaped from it."""

    def __init__(self) -> None:
        self.crashes: list[str] = []
        self.thread: threading.Thread | None = None

    def start(self, target: Callable[[], Any]) -> None:
        def run() -> None:
            try:
                target()
            except BaseException as exc:  # a crash is what we look for
                self.crashes.append(f"{type(exc).__name__}: {exc}")

        self.thread = threading.Thread(target=run, daemon=True)
        self.thread.start()

    def alive(self) -> bool:
        return self.thread is not None and self.thread.is_alive()


@dataclass
class _Batch:
    """One tick's traffic: hostile datagrams, then the datagram that completes the tick
    (itself hostile for ``bad_controls``, whose bad reply completes the tick)."""

    category: str
    hostile: list[bytes]
    done: bytes
    done_is_hostile: bool = False


class _Runner:
    """Send batches, wait for the endpoint's answer, compare its counters with the model."""

    def __init__(self, endpoint: str, model: Any, send: Callable[[bytes], Any],
                 counters: list[tuple[Any, tuple[str, ...]]],
                 wait: Callable[[], bool], categories: tuple[str, ...]) -> None:
        self.endpoint, self.model, self.send = endpoint, model, send
        self.counters, self.wait = counters, wait
        self.reports = {c: CategoryReport() for c in categories}
        self.mismatches: list[str] = []
        self.sent = 0

    def _snapshot(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for obj, names in self.counters:
            out.update((k, getattr(obj, k)) for k in names)
        return out

    def run(self, b: _Batch) -> bool:
        """One batch; False if the endpoint did not answer (stalled or crashed)."""
        rep = self.reports[b.category]
        model = self.model
        expected: Counter[str] = Counter()
        send: list[bytes] = []
        for data in b.hostile:
            saved = model.save()
            e = model.expect(data)
            if e["ends_run"] or e["genuine"]:
                rep.skipped += 1
                model.restore(saved)
                continue
            send.append(data)
            expected += e
        done_expect = model.expect(b.done)
        done_expect.pop("genuine", None)      # the completer is meant to be flown
        before = self._snapshot()
        for data in send:
            self.send(data)
        self.send(b.done)
        answered = self.wait()
        after = self._snapshot()
        delta = Counter({k: after[k] - before[k] for k in after if after[k] != before[k]})
        n_hostile = len(send) + (1 if b.done_is_hostile else 0)
        arrived = delta.pop("rx_datagrams", 0) - (0 if b.done_is_hostile else 1)
        rep.sent += n_hostile
        rep.arrived += arrived
        rep.batches += 1
        self.sent += n_hostile
        if arrived < n_hostile:
            rep.lost_batches += 1
            return answered
        total = expected + done_expect
        if delta != total:
            rep.mismatched_batches += 1
            if len(self.mismatches) < 10:
                self.mismatches.append(f"{self.endpoint} {b.category}: counted {dict(delta)} "
                                       f"expected {dict(total)}")
        if b.done_is_hostile:
            expected = total
        else:
            delta.subtract(done_expect)
        rep.counted += +delta
        rep.expected += expected
        return answered


_LINK_FIELDS = ("rx_datagrams", "rx_frames", *LINK_REASONS)


def fuzz_vehicle(n_inputs: int, seed: int, *, batch: int = 16,
                 progress: Callable[[int, int], None] | None = None) -> EndpointReport:
    """Fuzz a lockstep :class:`~tfl_mav.sitl.vehicle.Vehicle`'s control port with ``n_inputs``
    hostile datagrams (see the module docstring)."""
    from tfl_mav.scenario import load_scenario
    from tfl_mav.sitl.vehicle import Vehicle

    sc = load_scenario("paper").replace(**{"attack.rotor": 0,
                                           "initial.position_m": [0.0, 0.0, 5.0]})
    fmax = sc.vehicle.thrust_max_n
    hover = sc.vehicle.mass_kg * sc.vehicle.gravity_mps2 / 4.0 / fmax
    rng = random.Random(seed)
    gen = VehicleGen(random.Random(rng.randrange(2**32)), hover)
    ep = _Endpoint()
    nan_ticks = [0]
    nonfinite_tx: list[str] = []

    def on_truth(sim: Any) -> None:
        values = [*sim.state.as_list(), *sim.rotor_commands_n, *sim.rotor_thrusts_n]
        if not all(math.isfinite(v) for v in values) or not all(
                0.0 <= f <= fmax for f in sim.rotor_commands_n):
            nan_ticks[0] += 1

    def on_frame(direction: str, raw: bytes, msg: Any, t: float) -> None:
        if direction == "tx" and msg is not None:
            bad = nonfinite_floats(msg)
            if bad and len(nonfinite_tx) < 20:
                nonfinite_tx.append(f"vehicle sent {msg.get_type()} with {bad}")

    vehicle = Vehicle(sc, listen=("127.0.0.1", 0), on_truth=on_truth, on_frame=on_frame)
    ep.start(lambda: vehicle.run(math.inf))
    # The fuzzer is the vehicle's controller: the lockstep client, sending the hostile
    # datagrams from its own (pinned) address and reading the states it gets back.
    pilot = Pilot(vehicle.listen_address, sysid=FUZZER_SYSID, compid=FUZZER_COMPID)
    awaited = [-1]

    def next_state() -> bool:
        """Receive until the vehicle's state for the tick after ``awaited``."""
        while True:
            try:
                odom, _esc = pilot.state(STATE_TIMEOUT_S)
            except (NoStateError, OSError):
                return False
            if odom.time_usec > awaited[0]:
                awaited[0] = odom.time_usec
                return True

    model = VehicleModel()
    runner = _Runner("vehicle", model, pilot.link.send_raw,
                     [(vehicle.stats.control_link, _LINK_FIELDS),
                      (vehicle.stats, (*VEHICLE_REJECTS, *VEHICLE_ACCEPTS))],
                     next_state, VEHICLE_CATEGORIES)
    t0 = time.perf_counter()
    pilot.link.send_raw(gen.pack(mav.MAVLink_heartbeat_message(
        mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)))
    completed = next_state()
    for category, size in _schedule(VEHICLE_CATEGORIES, n_inputs, rng, batch):
        if not completed or not ep.alive():
            completed = False
            break
        model.awaited_usec = awaited[0]
        hostile, done = gen.batch(category, size, awaited[0])
        b = (_Batch(category, [], done, True) if category == "bad_controls"
             else _Batch(category, hostile, done))
        completed = runner.run(b)
        if progress is not None:
            progress(runner.sent, n_inputs)
    elapsed = time.perf_counter() - t0
    vehicle.stop()
    if ep.thread is not None:
        ep.thread.join(5.0)
    if ep.alive():
        ep.crashes.append("vehicle thread did not stop within 5 s")
    ticks = vehicle.stats.ticks
    vehicle.close()
    pilot.close()
    return EndpointReport("vehicle", seed, runner.reports, ep.crashes, nan_ticks[0], 0,
                          nonfinite_tx, runner.mismatches, ticks, elapsed,
                          completed and not ep.crashes)


def fuzz_daemon(n_inputs: int, seed: int, *, batch: int = 16,
                progress: Callable[[int, int], None] | None = None) -> EndpointReport:
    """Fuzz a :class:`~tfl_mav.controller.daemon.Daemon` with ``n_inputs`` hostile datagrams, the
    fuzzer acting as its vehicle (see the module docstring)."""
    from tfl_mav.controller.daemon import Daemon
    from tfl_mav.model.frames import enu_to_ned
    from tfl_mav.scenario import load_scenario

    sc = load_scenario("paper").replace(**{"attack.rotor": 0})
    v = sc.vehicle
    hover_radps = math.sqrt(v.mass_kg * v.gravity_mps2 / 4.0 / v.k_f)
    hover_rpm = round(hover_radps * 60.0 / (2.0 * math.pi))
    position_ned = tuple(float(c) for c in enu_to_ned(sc.initial.position_m))
    rng = random.Random(seed)
    gen = DaemonGen(random.Random(rng.randrange(2**32)), hover_rpm, position_ned)
    ep = _Endpoint()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)   # the fuzzer, as the vehicle
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(STATE_TIMEOUT_S)
    bad_cmds = [0]
    nonfinite_tx: list[str] = []

    def on_frame(direction: str, raw: bytes, msg: Any, t: float) -> None:
        if direction != "tx" or msg is None:
            return
        bad = nonfinite_floats(msg)
        if bad and len(nonfinite_tx) < 20:
            nonfinite_tx.append(f"daemon sent {msg.get_type()} with {bad}")
        if msg.get_msgId() == mav.MAVLINK_MSG_ID_HIL_ACTUATOR_CONTROLS:
            c = msg.controls
            if not (all(math.isfinite(u) and 0.0 <= u <= 1.0 for u in c[:4])
                    and all(u == 0.0 for u in c[4:])):
                bad_cmds[0] += 1

    daemon = Daemon(sc, vehicle=sock.getsockname(), on_frame=on_frame)
    address = daemon.link.local_address
    ep.start(lambda: daemon.run(math.inf))
    parser = new_mavlink(255, 0)
    tick = [1]

    def await_reply() -> bool:
        """Receive until the daemon's HIL_ACTUATOR_CONTROLS for the completer's time."""
        want = tick[0] * 1000
        while True:
            try:
                data = sock.recv(65535)
            except (TimeoutError, OSError):
                return False
            for msg in parser.parse_buffer(data) or ():
                if (msg.get_msgId() == mav.MAVLINK_MSG_ID_HIL_ACTUATOR_CONTROLS
                        and msg.time_usec == want):
                    return True

    model = DaemonModel()
    runner = _Runner("daemon", model, lambda data: sock.sendto(data, address),
                     [(daemon.link.stats, _LINK_FIELDS),
                      (daemon.stats, (*DAEMON_REJECTS, *DAEMON_ACCEPTS))],
                     await_reply, DAEMON_CATEGORIES)
    t0 = time.perf_counter()
    sock.sendto(gen.pack(mav.MAVLink_heartbeat_message(
        mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_GENERIC, 0, 0, mav.MAV_STATE_ACTIVE, 3)),
        address)
    first = gen.state(tick[0] * 1000)
    model.expect(first)
    sock.sendto(first, address)
    completed = await_reply()
    for category, size in _schedule(DAEMON_CATEGORIES, n_inputs, rng, batch):
        if not completed or not ep.alive():
            completed = False
            break
        tick[0] += 1
        hostile, done = gen.batch(category, max(size, 1), tick[0] * 1000)
        completed = runner.run(_Batch(category, hostile, done, category == "extreme_state"))
        if progress is not None:
            progress(runner.sent, n_inputs)
    elapsed = time.perf_counter() - t0
    daemon.stop()
    if ep.thread is not None:
        ep.thread.join(5.0)
    if ep.alive():
        ep.crashes.append("daemon thread did not stop within 5 s")
    ticks = daemon.stats.ticks
    daemon.close()
    sock.close()
    return EndpointReport("daemon", seed, runner.reports, ep.crashes, 0, bad_cmds[0],
                          nonfinite_tx, runner.mismatches, ticks, elapsed,
                          completed and not ep.crashes)
