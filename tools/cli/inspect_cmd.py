"""``tfl-mav inspect RUN.mcap``: what is in a flight log, and how the flight went.

Channels with schema names, message counts, rates and time spans (log time; sim time =
log time − the flight's start on a lockstep log's sim timeline, the ``timeline``
metadata's ``flight_start_ns``; else log time from the first message), then a flight
summary recomputed from the log alone, with the same code as ``tfl-mav report`` and ``tfl-mav demo``
(:func:`tfl_mav.flightlog.from_mcap.load_flight`, :func:`~tfl_mav.flightlog.flight.summarize`,
:mod:`tfl_mav.flightlog.metrics`), so the three agree exactly:

* a vehicle log (``/sim/truth/*`` and scenario metadata): the true path distance, the
  convergence verdict, and, with ``ctl.mcap`` next to it, detection, false alarms and
  saturation from the controller's ``/controller/state``;
* a controller log alone (``ctl.mcap``): detection and saturation from its
  ``/controller/state``, judged against the scenario in its metadata, and convergence on
  the controller's *measured* path distance (labelled so).

Works on damaged files (reads up to the damage and says so); ``--recover OUT`` rewrites
what is readable as a valid file.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from array import array
from pathlib import Path
from typing import Any

import numpy as np

from tfl_mav.flightlog.flight import summarize
from tfl_mav.flightlog.from_mcap import (
    TRUTH_TOPICS,
    load_flight,
    log_texts,
    scenario_from_log,
    truth_parts,
)
from tfl_mav.flightlog.logread import LogReader, recover
from tfl_mav.flightlog.mcaprepair import cut_short, read_back
from tfl_mav.flightlog.metrics import converged, detection, saturated_fraction
from tfl_mav.flightlog.polyline import Polyline
from tfl_mav.flightlog.protos import frames_fields
from tfl_mav.scenario import ScenarioError

__all__ = ["add_parser", "inspect_log", "run"]

_LAST_WINDOW_S = 10.0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "inspect", help="channels, counts, rates and a flight summary of an MCAP log",
        description="Show the channels of a recorded MCAP file (schema, count, rate, time "
                    "span) and a flight summary recomputed from the log alone. Reads damaged "
                    "files up to the damage.")
    p.add_argument("mcap", help="recorded .mcap file")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--recover", metavar="OUT",
                   help="rewrite everything readable as a valid MCAP file OUT")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    try:
        if args.recover:
            n, err = recover(args.mcap, args.recover)
            # proved by reading it back with the standard reader, not by our own word
            n_back, bad = read_back(args.recover)
            if bad is not None or n_back != n:
                print(f"tfl-mav inspect: --recover {args.recover}: the copy does not read "
                      f"back ({bad or f'{n_back} of {n} messages'})", file=sys.stderr)
                return 3
            msg = f"recovered {n} messages into {args.recover} (read back whole)"
            msg += f" (input ends early: {err})" if err else " (input was complete)"
            print(msg, file=sys.stderr if args.json else sys.stdout)
        report = inspect_log(args.mcap)
    except ValueError as exc:
        print(f"tfl-mav inspect: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"tfl-mav inspect: {exc}", file=sys.stderr)
        return 3
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(_format(report))
    return 0


# ------------------------------------------------------------------ reading
class _Channel:
    __slots__ = ("count", "first_log", "first_pub", "last_log", "last_pub", "schema")

    def __init__(self, schema: str) -> None:
        self.schema = schema
        self.count = 0
        self.first_log = self.last_log = self.first_pub = self.last_pub = 0


def inspect_log(path: str | Path) -> dict[str, Any]:
    """The ``inspect --json`` report of ``path`` (see the module docstring).

    One pass over the file counts every message for its channel, holding nothing per
    message; the flight is then rebuilt by :func:`~tfl_mav.flightlog.from_mcap.load_flight`,
    which streams the file again (memory: the rebuilt flight's arrays, not the decoded
    records). A log without a scenario, or a controller's, keeps only the few numbers per
    tick its summary needs (:class:`_Compact`)."""
    try:
        sc = scenario_from_log(path)
    except (ScenarioError, ValueError):
        sc = None
    reader = LogReader(path)
    chans: dict[str, _Channel] = {}
    compact = _Compact()
    has_truth = False
    texts: list[str] = []
    frames = {"rx": 0, "tx": 0, "rx_rejected": 0}
    sat_hil = [0]
    path_points: list[list[float]] | None = None
    for m in reader.messages():
        topic = m.topic
        c = chans.get(topic)
        if c is None:
            c = chans[topic] = _Channel(m.schema_name)
            c.first_log, c.first_pub = m.log_time_ns, m.publish_time_ns
        c.count += 1
        c.last_log, c.last_pub = m.log_time_ns, m.publish_time_ns
        if topic == "/mavlink/raw":       # a datagram's frames (one a message in old files)
            raws, tx, refused = frames_fields(m.data) or _frames_of(m)
            frames["tx" if tx else "rx"] += len(raws)
            frames["rx_rejected"] += len(refused)
        elif topic in TRUTH_TOPICS:
            has_truth = True
            if sc is None:              # no scenario: the summary is made from these
                for part, rec in truth_parts(topic, m.decode()).items():
                    compact.truth(part, rec)
        elif topic.endswith("/HIL_ACTUATOR_CONTROLS"):
            sat_hil[0] += 1
        elif topic == "/log":
            texts.append(log_texts(m.data))
        elif topic == "/scene/path":
            path_points = _path_points(m.data) or path_points
        elif topic == "/controller/state":
            compact.controller(m.decode())
    if not chans and reader.error:
        raise OSError(f"{path}: not a readable MCAP file ({reader.error})")
    log_first = min((c.first_log for c in chans.values()), default=0)
    log_last = max((c.last_log for c in chans.values()), default=0)
    metadata = {md.name: md.metadata for md in reader.metadata}
    start = metadata.get("timeline", {}).get("flight_start_ns")
    start_ns = int(start) if start else log_first
    for c in chans.values():            # sim time from the timeline (see the docstring)
        c.first_pub, c.last_pub = (max(c.first_log - start_ns, 0),
                                   max(c.last_log - start_ns, 0))
    pub_first = min((c.first_pub for c in chans.values()), default=0)
    pub_last = max((c.last_pub for c in chans.values()), default=0)
    report: dict[str, Any] = {
        "file": str(path),
        "complete": reader.complete,
        "read_error": reader.error,
        "messages": sum(c.count for c in chans.values()),
        "log_time_span_s": (log_last - log_first) * 1e-9,
        "sim_time_span_s": (pub_last - pub_first) * 1e-9,
        "frames": frames,
        "channels": {topic: _channel_report(c) for topic, c in sorted(chans.items())},
        "metadata": metadata,
    }
    cut = cut_short(metadata)
    if cut is not None:
        report["cut_short"] = cut
    timeline = report["metadata"].get("timeline", {})
    report["timeline"] = timeline.get("log_time", "wall")
    report["flight"] = _flight_summary(path, sc, has_truth, compact, path_points, sat_hil)
    return report


class _Compact:
    """What the summary of a log without a scenario (or a controller's log) needs, a few
    floats a tick in flat arrays: the truth's time and position, the attack's activity,
    the thrusts' range, the controller's distance, detection and saturation."""

    def __init__(self) -> None:
        self.state_t = array("d")
        self.state_pos = array("d")          # x, y, z per sample (NaN: not recorded)
        self.attack_first: tuple[int, float] | None = None    # (rotor, t) first active
        self.attack_seen = False
        self.applied_max: float | None = None
        self.thrust_min: float | None = None
        self.thrust_max: float | None = None
        self.ctl_n = 0
        self.ctl_last_t: float | None = None
        self.dist = array("d")                # t, d pairs where recorded
        self.det = array("d")                 # t, rotor pairs where recorded
        self.sat = array("d")                 # saturated (1/0) or NaN, every record
        self.any_sat = False

    def truth(self, part: str, rec: dict[str, Any]) -> None:
        if part == "state":
            self.state_t.append(rec["t_s"])
            self.state_pos.extend(rec.get("position_m", (math.nan,) * 3))
        elif part == "attack":
            self.attack_seen = True
            if rec["active"]:
                if self.attack_first is None:
                    self.attack_first = (rec["rotor"], rec["t_s"])
                if "applied_n" in rec:
                    a = rec["applied_n"]
                    self.applied_max = a if self.applied_max is None else \
                        max(self.applied_max, a)
        elif part == "thrusts":
            values = rec.get("thrust_n", ())
            if values:
                lo, hi = min(values), max(values)
                self.thrust_min = lo if self.thrust_min is None else min(self.thrust_min, lo)
                self.thrust_max = hi if self.thrust_max is None else max(self.thrust_max, hi)

    def controller(self, rec: dict[str, Any]) -> None:
        self.ctl_n += 1
        self.ctl_last_t = rec["t_s"]
        if "path_distance_m" in rec:
            self.dist.extend((rec["t_s"], rec["path_distance_m"]))
        if "detected_rotor" in rec:
            self.det.extend((rec["t_s"], rec["detected_rotor"]))
        if "saturated" in rec:
            self.any_sat = True
            self.sat.append(float(bool(rec["saturated"])))
        else:
            self.sat.append(math.nan)


def _frames_of(m: Any) -> tuple[list[Any], bool, list[int]]:
    """(frames, tx, refused indexes) of a ``/mavlink/raw`` message the shortcut did not read
    (another layout, or an old file's JSON frame)."""
    f = m.decode()
    if "direction" in f:
        return [f["data"]], f["direction"] == "tx", [] if f["accepted"] else [0]
    return f.get("frames", []), bool(f.get("tx")), f.get("rejected", [])


def _path_points(data: bytes) -> list[list[float]] | None:
    """The first line strip of a ``foxglove.SceneUpdate`` (protobuf; JSON in old files)."""
    if data[:1] == b"{":
        ents = json.loads(data)["entities"]
        lines = ents[0]["lines"] if ents else []
        return [[p["x"], p["y"], p["z"]] for p in lines[0]["points"]] if lines else None
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    ents = SceneUpdate.FromString(data).entities
    lines = ents[0].lines if ents else []
    return [[p.x, p.y, p.z] for p in lines[0].points] if lines else None


def _channel_report(c: _Channel) -> dict[str, Any]:
    log_span = (c.last_log - c.first_log) * 1e-9
    pub_span = (c.last_pub - c.first_pub) * 1e-9
    return {
        "schema": c.schema,
        "count": c.count,
        "rate_hz": round((c.count - 1) / log_span, 3) if log_span > 0 else None,
        "sim_rate_hz": round((c.count - 1) / pub_span, 3) if pub_span > 0 else None,
        "log_time_span_s": log_span,
        "sim_time_first_s": c.first_pub * 1e-9,
        "sim_time_last_s": c.last_pub * 1e-9,
    }


# ------------------------------------------------------------------ flight summary
def _f(x: float) -> float | None:
    return float(x) if x is not None and math.isfinite(x) else None


def _distance_stats(t: np.ndarray, d: np.ndarray, source: str) -> dict[str, Any]:
    ok = np.isfinite(d)
    t, d = t[ok], d[ok]
    if len(d) == 0:
        return {"path_distance_source": source}
    last = t >= t[-1] - _LAST_WINDOW_S
    conv = converged(t, d)
    return {
        **conv.as_dict(),
        "convergence": conv.reason,
        "path_distance_source": source,
        "final_path_distance_m": _f(d[-1]),
        "max_path_distance_m": _f(np.max(d)),
        "mean_path_distance_m": _f(np.mean(d)),
        "max_path_distance_last_10s_m": _f(np.max(d[last])),
        "rms_path_distance_last_10s_m": _f(math.sqrt(float(np.mean(d[last] ** 2)))),
    }


def _flight_summary(path: str | Path, sc: Any, has_truth: bool, comp: _Compact,
                    path_points: list[list[float]] | None,
                    sat_hil: list[int]) -> dict[str, Any]:
    if has_truth and sc is not None:
        log, _ = load_flight(path, sc)
        out = summarize(log)
        if not log.wall_time_s:         # not in the log: no number rather than a wrong one
            del out["wall_time_s"], out["real_time_factor"]
        out["path_distance_source"] = "truth position vs the scenario's path"
        has_ctl = log.detected_rotor is not None
        out["saturation_source"] = "/controller/state.saturated (ctl.mcap)" if has_ctl else None
        if not has_ctl:
            out["detection"] = "needs the controller's log (ctl.mcap next to this file)"
        if log.log_cut is not None:
            out["log_cut_short"] = log.log_cut
        return out
    out: dict[str, Any] = {}
    if len(comp.state_t):
        out["sim_time_s"] = comp.state_t[-1]
    elif comp.ctl_n:
        out["sim_time_s"] = comp.ctl_last_t
    if len(comp.state_t) and path_points is not None and len(path_points) >= 2:
        pos = np.frombuffer(comp.state_pos, dtype=float).reshape(-1, 3)
        t = np.frombuffer(comp.state_t, dtype=float)
        ok = np.all(np.isfinite(pos), axis=1)
        d = np.full(len(pos), np.nan)
        d[ok] = Polyline(path_points).distances(pos[ok])
        out.update(_distance_stats(t, d, "truth position vs /scene/path"))
    elif len(comp.dist):
        td = np.frombuffer(comp.dist, dtype=float).reshape(-1, 2)
        out.update(_distance_stats(td[:, 0].copy(), td[:, 1].copy(),
                                   "/controller/state.path_distance_m (measured)"))
    attack_rotor = sc.attack.rotor if sc is not None else None
    start = sc.attack.start_s if sc is not None and sc.attack.rotor else None
    if comp.attack_seen and sc is None:   # no scenario: the ground truth says when and where
        first = comp.attack_first
        attack_rotor = first[0] if first else 0
        start = first[1] if first else None
    out["attack_rotor"] = attack_rotor
    out["attack_start_s"] = start
    out["attack_max_n"] = comp.applied_max
    out["thrust_true_min_n"] = comp.thrust_min
    out["thrust_true_max_n"] = comp.thrust_max
    if len(comp.det) and attack_rotor is not None:
        tr = np.frombuffer(comp.det, dtype=float).reshape(-1, 2)
        out.update(detection(tr[:, 0].tolist(), [int(r) for r in tr[:, 1]], attack_rotor,
                             start))
    elif len(comp.det):
        out["detection"] = "attack unknown (no scenario metadata): not judged"
    if comp.any_sat:
        out["saturated_fraction"] = saturated_fraction(np.frombuffer(comp.sat, dtype=float))
        out["saturation_source"] = "/controller/state.saturated"
    else:
        out["saturated_fraction"] = None
        out["saturation_source"] = ("needs the controller's log (ctl.mcap)" if sat_hil[0]
                                    else None)
    return out


# ------------------------------------------------------------------ text output
_UNITS = (("_radps", "rad/s"), ("_mps", "m/s"), ("_kg", "kg"), ("_hz", "Hz"), ("_s", "s"),
          ("_n", "N"), ("_m", "m"))


def _value(key: str, v: Any) -> tuple[str, str]:
    """(label, text) of one summary field: the unit moved from the name to the value, a
    distance below a metre in mm (µm below a millimetre), a fraction in %."""
    if isinstance(v, dict):                 # time in each law (s)
        return key.removesuffix("_s"), ", ".join(f"{k} {x:.3f} s" for k, x in v.items() if x)
    if isinstance(v, list):                 # detections, releases: (time s, rotor)
        return key, ", ".join(f"rotor {r} at {t:.3f} s" for t, r in v) or "none"
    if isinstance(v, bool) or not isinstance(v, float):
        return key, "-" if v is None else str(v)
    if key.endswith("_fraction"):
        return key, f"{100.0 * v:.2f} %"
    for suffix, unit in _UNITS:
        if key.endswith(suffix):
            label = key[:-len(suffix)]
            if unit == "m" and abs(v) < 1.0:
                return label, (f"{v * 1e3:.3f} mm" if abs(v) >= 1e-3 or v == 0.0
                               else f"{v * 1e6:.3f} µm")
            return label, f"{v:.3f} {unit}"
    return key, f"{v:.3f}"


def _num(x: Any, fmt: str = ".3f") -> str:
    return "-" if x is None else format(x, fmt) if isinstance(x, float) else str(x)


def _format(r: dict[str, Any]) -> str:
    tl = r["metadata"].get("timeline", {})
    sim_timeline = r.get("timeline") == "sim"
    head = f"{r['file']}: {r['messages']} messages, sim time {r['sim_time_span_s']:.3f} s"
    if sim_timeline:
        head += (f" (the timeline's: log_time = flight start + sim time); flown in "
                 f"{tl.get('wall_time_s', '?')} s wall ({tl.get('real_time_factor', '?')}x "
                 "real time)")
    else:
        head += f", log time {r['log_time_span_s']:.3f} s"
    lines = [head]
    if not r["complete"]:
        lines.append(f"  NOT FINISHED (read up to: {r['read_error'] or 'end of file'}); "
                     "`--recover OUT` writes a valid copy")
    cut = r.get("cut_short")
    if cut is not None:
        at = cut.get("last_sim_time_s")
        lines.append("  CUT SHORT: the recording ended before the flight"
                     + (f", at sim t = {float(at):.3f} s" if at else "")
                     + f" ({cut.get('reason', 'no reason recorded')})")
    fr = r["frames"]
    lines.append(f"  MAVLink frames: rx {fr['rx']} (rejected {fr['rx_rejected']}), "
                 f"tx {fr['tx']}")
    width = max((len(t) for t in r["channels"]), default=10)
    rates = "  {:>9s}" if sim_timeline else "  {:>9s}  {:>9s}"
    lines.append(f"  {'channel':{width}s}  {'count':>8s}"
                 + (rates.format("Hz") if sim_timeline else rates.format("Hz(log)", "Hz(sim)"))
                 + "  schema")
    for topic, c in r["channels"].items():
        hz = ((_num(c["sim_rate_hz"], ".1f"),) if sim_timeline
              else (_num(c["rate_hz"], ".1f"), _num(c["sim_rate_hz"], ".1f")))
        lines.append(f"  {topic:{width}s}  {c['count']:8d}" + rates.format(*hz)
                     + f"  {c['schema']}")
    lines.append("  flight:")
    for k, v in r["flight"].items():
        if v == "" or v is None:         # no crash: no reason; not in this log: no number
            continue
        label, text = _value(k, v)
        lines.append(f"    {label:30s} {text}")
    return "\n".join(lines)
