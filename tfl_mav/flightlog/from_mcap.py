"""Rebuild a :class:`~tfl_mav.flightlog.flight.FlightLog` from the MCAP files of a flight.

The vehicle's log (``run.mcap``) holds the ground truth (``/sim/truth/state``: the rigid
body, the true rotor thrusts and the attack, one message a tick; older files had the
thrusts and the attack on ``/sim/truth/thrusts``, ``/sim/truth/attack``) and every MAVLink
frame; the controller's
log (``ctl.mcap``, optional) holds ``/controller/state`` every tick (mode, detection,
estimate, saturation). The path distance is recomputed from the true positions with the
scenario's path, so it is the *true* distance, not the controller's measured one.
"""

from __future__ import annotations

import json
import math
import operator
import struct
from pathlib import Path
from typing import Any

import numpy as np

from tfl_mav.flightlog.flight import SERIES, FlightLog
from tfl_mav.flightlog.logread import LogReader
from tfl_mav.flightlog.pathdist import path_distances
from tfl_mav.from_scenario import scenario_path
from tfl_mav.model.airframe import mix
from tfl_mav.model.modes import Mode
from tfl_mav.scenario import Scenario, ScenarioError, scenario_from_dict

__all__ = ["TRUTH_TOPICS", "add_truth", "controller_states", "flight_log_from_mcap",
           "load_flight", "log_metadata", "scenario_from_log", "truth_parts"]

_TRUTH = {"/sim/truth/state", "/sim/truth/thrusts", "/sim/truth/attack"}


def controller_states(ctl_path: str | Path) -> dict[int, dict[str, Any]]:
    """``/controller/state`` messages keyed by sim time in µs."""
    out: dict[int, dict[str, Any]] = {}
    for m in LogReader(ctl_path).messages({"/controller/state"}):
        d = m.decode()
        out[round(d["t_s"] * 1e6)] = d
    return out


TRUTH_TOPICS = frozenset(_TRUTH)


def add_truth(truth: dict[int, dict[str, Any]], topic: str, record: dict[str, Any]) -> None:
    """File one decoded ``/sim/truth/*`` record under its tick (sim time in µs), as the
    parts ``state``, ``thrusts`` and ``attack`` (:func:`truth_parts`)."""
    truth.setdefault(round(record["t_s"] * 1e6), {}).update(
        truth_parts(topic, record))


def truth_parts(topic: str, record: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """A ``/sim/truth/*`` record as the parts it holds: ``state`` (t_s, position_m,
    velocity_mps, quaternion_wxyz, body_rates_radps), ``thrusts`` (t_s, thrust_n,
    attack_rotor), ``attack`` (t_s, rotor, active, applied_n, requested_n)."""
    name = topic.rsplit("/", 1)[-1]
    if name != "state" or "thrust_n" not in record:     # an older file's separate part
        return {name: record}
    t, rotor = record["t_s"], record.get("attack_rotor", 0)
    thrusts = {"t_s": t, "attack_rotor": rotor, "thrust_n": record["thrust_n"]}
    attack = {"t_s": t, "rotor": rotor, "active": rotor != 0}
    for key in ("applied_n", "requested_n"):
        if f"attack_{key}" in record:
            attack[key] = record[f"attack_{key}"]
    return {"state": record, "thrusts": thrusts, "attack": attack}


def flight_log_from_mcap(run_path: str | Path, scenario: Scenario,
                         ctl_path: str | Path | None = None,
                         truth: dict[int, dict[str, Any]] | None = None,
                         texts: list[str] | None = None) -> FlightLog:
    """The flight in ``run_path`` (and ``ctl_path``) as a finished FlightLog. ``truth``
    and ``texts``: its truth records (:func:`add_truth`) and ``/log`` texts already read
    (a reader that passes over the file anyway), else they are read here.

    Read as a stream (:func:`_stream_flight`): the truth and the controller's records are
    merged tick by tick as they come off the two files, and each sample goes straight into
    the log's arrays, so memory is the finished log's (~230 bytes a tick) and no more,
    however long the flight. A log whose ticks are not in order (or from before
    ``/sim/truth/state`` held the thrusts) is read whole into memory instead, as it
    always was."""
    if truth is None:
        try:
            return _stream_flight(run_path, scenario, ctl_path)
        except _NotStreamableError:
            pass
        truth, texts = {}, []
        run_reader: LogReader | None = LogReader(run_path)
        for m in run_reader.messages(_TRUTH | {"/log"}):
            if m.topic == "/log":
                texts.append(log_texts(m.data))
            else:
                add_truth(truth, m.topic, m.decode())
    else:
        run_reader = None
    crashed = crash_reason(texts or [])
    ctl = controller_states(ctl_path) if ctl_path and Path(ctl_path).exists() else {}
    log = _empty_log(scenario)
    path = scenario_path(scenario)
    log.path_points_m = path.sample(400)
    v = scenario.vehicle
    detected: list[int] = []
    yaw_prev: float | None = None
    yaw_unwrapped = 0.0
    rows = []
    for key in sorted(truth):
        rec = truth[key]
        if not {"state", "thrusts", "attack"} <= rec.keys():
            continue
        st, th, at = rec["state"], rec["thrusts"], rec["attack"]
        # older files left non-finite values out (JSON has no NaN): such a sample has no
        # position/thrust/attack; a diverged one is not plotted
        if not ("position_m" in st and "quaternion_wxyz" in st and "thrust_n" in th
                and "applied_n" in at) or not all(map(math.isfinite, (
                    *st["position_m"], *st["quaternion_wxyz"], *th["thrust_n"],
                    at["applied_n"]))):
            continue
        rows.append((key, st, th, at))
    # the true distance of every sample, as a tracker evaluating each in turn gives it
    distances = path_distances(path, [st["position_m"] for _, st, _, _ in rows])
    for (key, st, th, at), distance in zip(rows, distances, strict=True):
        pos = st["position_m"]
        w, x, y, z = st["quaternion_wxyz"]
        yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        yaw_unwrapped = yaw if yaw_prev is None else \
            yaw_unwrapped + math.remainder(yaw - yaw_prev, math.tau)
        yaw_prev = yaw
        c = ctl.get(key, {})
        uf, tp, tq, tr = mix(v, th["thrust_n"])
        est = c.get("attack_estimate_n")
        log.append(t_s=st["t_s"], position_m=pos, velocity_mps=st["velocity_mps"],
                   body_rates_radps=st["body_rates_radps"], yaw_rad=yaw_unwrapped,
                   path_distance_m=distance, thrust_cmd_n=c.get("rotor_thrust_cmd_n",
                                                                     th["thrust_n"]),
                   thrust_true_n=th["thrust_n"], attack_true_n=at["applied_n"],
                   attack_estimate_n=est if est is not None else math.nan, uf_n=uf,
                   torque_nm=(tp, tq, tr),
                   # no controller record for this tick: unknown, not "unsaturated"
                   saturated=float(bool(c["saturated"])) if "saturated" in c else math.nan,
                   mode=int(Mode.parse(c.get("mode", "nominal"))))
        detected.append(int(c.get("detected_rotor") or 0))
    log.finish()
    if ctl:
        log.detected_rotor = np.asarray(detected, dtype=int)
    if run_reader is not None:
        log.log_cut = _cuts(run_path, run_reader, float(log["t_s"][-1]) if len(log["t_s"])
                            else None, ctl_path)
    return _judged(log, crashed)


def _empty_log(scenario: Scenario) -> FlightLog:
    v = scenario.vehicle
    return FlightLog(thrust_max_n=v.thrust_max_n, attack_rotor=scenario.attack.rotor,
                     attack_start_s=scenario.attack.start_s if scenario.attack.rotor
                     else math.nan)


def _judged(log: FlightLog, crashed: str) -> FlightLog:
    """The crash verdict of a finished log: the vehicle's own word, else its rates."""
    if len(log["t_s"]):
        rates = np.abs(log["body_rates_radps"])
        log.crashed = bool(np.max(rates) > 300.0)
    if crashed:                  # the vehicle said so (flipped, hit the ground, ...)
        log.crashed, log.crash_reason = True, crashed
    return log


class _NotStreamableError(Exception):
    """The log is not one :func:`_stream_flight` reads in order: read it whole."""


# A /sim/truth/state message as the recorder packs it (protos.truth_state), its tags and
# lengths included so they can be checked: (tag, t), 5 × (tag, length, values...),
# (tag, attack rotor < 128), (tag, applied), (tag, requested).
_TRUTH_FIXED = struct.Struct("<Bd" + "BB3d" + "BB3d" + "BB4d" + "BB3d" + "BB4d" + "BB" + "Bd"
                             + "Bd")
_TRUTH_TAGS = operator.itemgetter(0, 2, 3, 7, 8, 12, 13, 18, 19, 23, 24, 29, 31, 33)
_TRUTH_TAG_VALUES = (0x09, 0x12, 24, 0x1A, 24, 0x22, 32, 0x2A, 24, 0x32, 32, 0x38, 0x41, 0x49)
_BLOCK = 16384                   # samples converted to arrays at a time


def _truth_rows(m: Any) -> tuple[Any, ...] | None:
    """(t, x, y, z, vx, vy, vz, qw, qx, qy, qz, p, q, r, f1..f4, applied) of one
    ``/sim/truth/state`` message; None if it lacks a field (an older file's sample)."""
    data = m.data
    if len(data) == _TRUTH_FIXED.size:
        u = _TRUTH_FIXED.unpack(data)
        if _TRUTH_TAGS(u) == _TRUTH_TAG_VALUES:
            return (u[1], u[4], u[5], u[6], u[9], u[10], u[11], u[14], u[15], u[16], u[17],
                    u[20], u[21], u[22], u[25], u[26], u[27], u[28], u[32])
    rec = m.decode()
    try:
        return (rec["t_s"], *rec["position_m"], *rec["velocity_mps"],
                *rec["quaternion_wxyz"], *rec["body_rates_radps"], *rec["thrust_n"],
                rec["attack_applied_n"])
    except (KeyError, TypeError):
        return None


class _Controller:
    """The controller's ``/controller/state`` records in tick order, one at a time: the
    record of a given tick (µs key) or None, reading ``ctl.mcap`` only as far as needed.
    Raises :class:`_NotStreamableError` if its ticks go back in time."""

    def __init__(self, path: str | Path | None) -> None:
        self._it = iter(LogReader(path).messages({"/controller/state"})) if path else iter(())
        self._cls: Any = None
        self._next: tuple[int, Any] | None = self._read()
        self.any = self._next is not None
        self._modes: dict[str, int] = {}

    def _read(self) -> tuple[int, Any] | None:
        for m in self._it:
            sc = m.schema
            if sc is None or sc.encoding != "protobuf":
                raise _NotStreamableError         # an older (JSON) controller log
            if self._cls is None:
                from tfl_mav.flightlog.protos import message_class

                self._cls = message_class(sc.name, bytes(sc.data))
            rec = self._cls.FromString(m.data)
            return round(rec.t_s * 1e6), rec
        return None

    def at(self, key: int) -> Any:
        """The last record of tick ``key`` (None if there is none); ticks before it are
        passed over."""
        nxt = self._next
        found = None
        while nxt is not None and nxt[0] <= key:
            if nxt[0] == key:
                found = nxt[1]
            following = self._read()
            if following is not None and following[0] < nxt[0]:
                raise _NotStreamableError
            nxt = following
        self._next = nxt
        return found

    def mode(self, name: str) -> int:
        code = self._modes.get(name)
        if code is None:
            code = self._modes[name] = int(Mode.parse(name or "nominal"))
        return code


def _stream_flight(run_path: str | Path, scenario: Scenario,
                   ctl_path: str | Path | None) -> FlightLog:
    """:func:`flight_log_from_mcap` in one pass over each file (see there): the same
    samples, values and verdict as reading them whole, to the bit."""
    ctl = _Controller(ctl_path if ctl_path and Path(ctl_path).exists() else None)
    reader = LogReader(run_path)
    counts = reader.message_counts() or {}
    capacity = counts.get("/sim/truth/state")
    path = scenario_path(scenario)
    log = _empty_log(scenario)
    log.path_points_m = path.sample(400)
    texts: list[str] = []
    nan = math.nan
    atan2, remainder, tau, isfinite = math.atan2, math.remainder, math.tau, math.isfinite
    cols = _Columns(capacity)
    block: list[tuple[float, ...]] = []
    yaw_prev: float | None = None
    yaw_unwrapped = 0.0
    last_key: int | None = None
    pending: tuple[int, tuple[Any, ...]] | None = None   # the newest sample of its tick

    def emit(key: int, r: tuple[Any, ...]) -> None:
        nonlocal yaw_prev, yaw_unwrapped
        # older files left non-finite values out; a diverged sample is not plotted
        if not all(map(isfinite, r[1:4] + r[7:11] + r[14:19])):
            return
        w, x, y, z = r[7:11]
        yaw = atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        yaw_unwrapped = yaw if yaw_prev is None else \
            yaw_unwrapped + remainder(yaw - yaw_prev, tau)
        yaw_prev = yaw
        c = ctl.at(key)
        if c is None:
            cmd = r[14:18]
            est = sat = nan
            mode = 0
            det = 0.0
        else:
            cmd = tuple(c.rotor_thrust_cmd_n) if len(c.rotor_thrust_cmd_n) else r[14:18]
            est = c.attack_estimate_n if c.HasField("attack_estimate_n") else nan
            sat = float(bool(c.saturated)) if c.HasField("saturated") else nan
            mode = ctl.mode(c.mode) if c.HasField("mode") else 0
            det = float(c.detected_rotor or 0) if c.HasField("detected_rotor") else 0.0
        block.append((*r, yaw_unwrapped, *cmd, est, sat, float(mode), det))
        if len(block) >= _BLOCK:
            cols.add(block)
            block.clear()

    for m in reader.messages(_TRUTH | {"/log"}):
        if m.topic == "/log":
            texts.append(log_texts(m.data))
            continue
        if m.topic != "/sim/truth/state":
            raise _NotStreamableError                 # an older file's separate parts
        r = _truth_rows(m)
        if r is None:
            raise _NotStreamableError
        key = round(r[0] * 1e6)
        if last_key is not None and key < last_key:
            raise _NotStreamableError
        if pending is not None and key != pending[0]:
            emit(*pending)
        pending = (key, r)                       # a tick's last record wins
        last_key = key
    if pending is not None:
        emit(*pending)
    if block:
        cols.add(block)
    data = log.data
    data.update(cols.finish())
    n = len(data["t_s"])
    v = scenario.vehicle
    ell, d = v.arm_m, v.drag_thrust_ratio_m
    th = data["thrust_true_n"]
    f1, f2, f3, f4 = th[:, 0], th[:, 1], th[:, 2], th[:, 3]
    # the true distance of every sample, as a tracker evaluating each in turn gives it
    data["path_distance_m"] = np.asarray(path_distances(path, data["position_m"]),
                                         dtype=float) if n else np.zeros(0)
    data["thrust_req_n"] = np.zeros(0)
    data["uf_n"] = f1 + f2 + f3 + f4                 # eq. (4), as mix() sums it
    data["torque_nm"] = np.stack((ell * (f4 - f2), ell * (f3 - f1),
                                  d * (f1 - f2 + f3 - f4)), axis=1) if n \
        else np.zeros((0, 3))
    detected = data.pop("detected_rotor").astype(int)
    del th, f1, f2, f3, f4
    if n == 0:                  # the shapes an empty log has when read whole
        for k in SERIES:
            data[k] = np.asarray([], dtype=float)
    log.finish()
    if ctl.any:
        log.detected_rotor = detected
    log.log_cut = _cuts(run_path, reader, float(data["t_s"][-1]) if n else None, ctl_path)
    return _judged(log, crash_reason(texts))


def _file_cut(path: str | Path, role: str, complete: bool | None, error: str | None,
              last_t_s: float | None) -> dict[str, Any] | None:
    """Whether the log ``path`` ends before its flight did, and where: the file says so
    (a repaired file's, or an orphaned recorder's, ``recording`` metadata), or it has no
    summary (``complete`` False: read up to the damage)."""
    from tfl_mav.flightlog.mcaprepair import cut_short

    md = cut_short(log_metadata(path))
    if md is not None:
        at = md.get("last_sim_time_s")
        return {"file": Path(path).name, "role": role,
                "at_s": float(at) if at else last_t_s, "reason": md.get("reason", "")}
    if complete is False:
        return {"file": Path(path).name, "role": role, "at_s": last_t_s,
                "reason": f"no summary: read up to {error or 'the end of the file'}"}
    return None


def _cuts(run_path: str | Path, reader: LogReader, last_t_s: float | None,
          ctl_path: str | Path | None) -> list[dict[str, Any]] | None:
    """The cut-short files of a flight (vehicle's first), or None."""
    out = []
    run_cut = _file_cut(run_path, "vehicle", reader.complete, reader.error, last_t_s)
    if run_cut is not None:
        out.append(run_cut)
    if ctl_path and Path(ctl_path).exists():
        ctl_reader = LogReader(ctl_path)
        finished = ctl_reader.message_counts() is not None
        ctl_cut = _file_cut(ctl_path, "controller", finished, None, None)
        if ctl_cut is not None:
            out.append(ctl_cut)
    return out or None


_LAYOUT = (("t_s", 0, 1), ("position_m", 1, 4), ("velocity_mps", 4, 7),
           ("body_rates_radps", 11, 14), ("thrust_true_n", 14, 18), ("attack_true_n", 18, 19),
           ("yaw_rad", 19, 20), ("thrust_cmd_n", 20, 24), ("attack_estimate_n", 24, 25),
           ("saturated", 25, 26), ("mode", 26, 27), ("detected_rotor", 27, 28))
"""Where each series sits in a sample row of :func:`_stream_flight` (truth: t, position,
velocity, quaternion (7:11, used for yaw only), rates, thrusts, applied attack; then yaw,
command, estimate, saturated, mode, detected rotor)."""


class _Columns:
    """Sample rows gathered block by block straight into one array a series (each C
    contiguous, as :class:`FlightLog` holds them): sized from the file's summary
    (``capacity``) when known, else grown by doubling, one series at a time."""

    def __init__(self, capacity: int | None) -> None:
        self._cap = capacity or 0
        self._n = 0
        self._arrays = {name: np.empty((self._cap, hi - lo) if hi - lo > 1 else self._cap)
                        for name, lo, hi in _LAYOUT}

    def add(self, rows: list[tuple[float, ...]]) -> None:
        b = np.array(rows, dtype=float)
        n, m = self._n, len(b)
        if n + m > self._cap:
            self._cap = max(2 * self._cap, n + m, 4 * _BLOCK)
            for name, arr in self._arrays.items():
                grown = np.empty((self._cap, *arr.shape[1:]))
                grown[:n] = arr[:n]
                self._arrays[name] = grown
        for name, lo, hi in _LAYOUT:
            self._arrays[name][n:n + m] = b[:, lo:hi] if hi - lo > 1 else b[:, lo]
        self._n = n + m

    def finish(self) -> dict[str, np.ndarray]:
        """The series, ``len`` samples each (views of the arrays: no copy)."""
        out = {name: arr[:self._n] for name, arr in self._arrays.items()}
        self._arrays = {}
        return out


def log_metadata(path: str | Path) -> dict[str, dict[str, str]]:
    """The MCAP metadata records of ``path`` (name → key/value map; of an unfinished file,
    those before its first message)."""
    return {md.name: dict(md.metadata) for md in LogReader(path).read_metadata()}


def crash_reason(texts: list[str]) -> str:
    """The vehicle's own word on a crash among its logged texts (its "crashed: ..."
    STATUSTEXT, on ``/log``), or ""."""
    for text in texts:
        at = text.find("crashed: ")
        if at >= 0:
            return text[at + len("crashed: "):]
    return ""


def log_texts(data: bytes) -> str:
    """The text of one ``/log`` message (foxglove.Log, protobuf)."""
    from foxglove_schemas_protobuf.Log_pb2 import Log

    return str(Log.FromString(data).message)


def scenario_from_log(path: str | Path) -> Scenario:
    """The scenario a log was flown with (``scenario`` metadata: the vehicle writes
    ``scenario_json``, the controller ``toml``, both ``Scenario.to_dict()`` as JSON);
    :class:`ScenarioError` if there is none."""
    meta = log_metadata(path).get("scenario", {})
    text = meta.get("scenario_json") or meta.get("toml")
    if not text:
        raise ScenarioError("scenario", f"{path} has no scenario metadata: pass --scenario NAME")
    data = json.loads(text)
    data.pop("source", None)
    return scenario_from_dict(data, source=f"{path} (metadata)")


def load_flight(run_path: str | Path, scenario: Scenario | None = None,
                ctl_path: str | Path | None = None,
                truth: dict[int, dict[str, Any]] | None = None,
                texts: list[str] | None = None) -> tuple[FlightLog, Scenario]:
    """The flight of a vehicle log as ``report``, ``inspect`` and ``demo`` all see it:
    scenario from the log unless given, the controller's log from ``ctl_path`` or
    ``ctl.mcap`` next to it, the requested duration from the ``run`` metadata
    (``truth``, ``texts``: as :func:`flight_log_from_mcap`)."""
    run_path = Path(run_path)
    sc = scenario if scenario is not None else scenario_from_log(run_path)
    ctl = Path(ctl_path) if ctl_path else run_path.with_name("ctl.mcap")
    log = flight_log_from_mcap(run_path, sc, ctl if ctl.exists() and ctl != run_path else None,
                               truth, texts)
    meta = log_metadata(run_path)
    duration = meta.get("run", {}).get("duration_s")
    if duration is not None:
        log.duration_s = float(duration)
    wall = meta.get("timeline", {}).get("wall_time_s")     # lockstep logs keep the wall clock
    if wall is not None:
        log.wall_time_s = float(wall)
    return log, sc
