"""MAVLink 2 signing: hostile frames accepted (must be 0), the future-timestamp attack, and
what signing costs.

Measures, on this machine, over real UDP on loopback:

1. **hostile command frames** sent to a signed control port *from the peer's own address*
   (the worst case: source address spoofed on the path, so pinning does not help and only
   signing stands in the way): unsigned, wrong key, forged signature, replayed (genuine
   frames sent again), far-future timestamp. Frames sent vs accepted by the link.
2. **the vehicle under attack**: a signed :class:`~tfl_mav.sitl.vehicle.Vehicle` flown in lockstep
   by a genuine controller that, before every reply, also injects one hostile frame
   (full-throttle controls for the awaited tick, MAV_CMD_INJECT_FAILURE, ...). Commands the
   vehicle applied or accepted from them.
3. **the future-timestamp attack**: one forged frame with a far-future timestamp, then
   genuine frames: how many genuine ones pymavlink 2.4.50's own verifier accepts (its flaw,
   measured here) and how many ours does.
4. **cost**: µs per frame to sign (stamp + pack) and to verify, against packing/decoding
   unsigned; lockstep ticks/s of ``tfl-mav sim`` flown by our Link, signed vs unsigned.

Usage: ``python bench/bench_signing.py [--frames N] [--ticks N] [--json FILE]`` from the
repository root.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import statistics
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from tfl_mav.link.dialect import mav, new_mavlink
from tfl_mav.link.signing import Signing, mavlink_timestamp, signature48
from tfl_mav.link.transport import Link
from tfl_mav.scenario import load_scenario
from tfl_mav.sitl.vehicle import Vehicle
from tfl_mav.tools.harness.pilot import NoStateError, Pilot, hover_controls, hover_fraction
from tfl_mav.tools.harness.processes import popen_sim

KEY = bytes.fromhex("5a" * 8 + "c3" * 8 + "0f" * 8 + "e1" * 8)
WRONG_KEY = bytes(range(1, 33))
LOOPBACK = ("127.0.0.1", 0)
BATCH = 200            # datagrams sent before the receiver drains (stay inside the buffer)
CONTROLLER_IDS = (2, 191)


# ---------------------------------------------------------------------------- frames
def controls(time_usec: int, u: float) -> Any:
    return mav.MAVLink_hil_actuator_controls_message(time_usec, [u] * 4 + [0.0] * 12, 128, 1)


def command_long() -> Any:
    return mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_INJECT_FAILURE, 0, 101, 1, 2,
                                           0, 0, 0, 0)


def command_int() -> Any:
    return mav.MAVLink_command_int_message(1, 1, 0, mav.MAV_CMD_INJECT_FAILURE, 0, 0, 101, 1,
                                          2, 0, 0, 0, 0.0)


COMMANDS: list[Callable[[int], Any]] = [
    lambda k: controls(k * 1000, 1.0), lambda k: command_long(), lambda k: command_int()]


def pack(msg: Any, *, key: bytes | None, timestamp: int | None = None) -> bytes:
    """``msg`` as the controller's ids, signed with ``key`` (None: unsigned)."""
    packer = new_mavlink(*CONTROLLER_IDS)
    if key is not None:
        packer.signing.secret_key = key
        packer.signing.sign_outgoing = True
        packer.signing.timestamp = (mavlink_timestamp(time.time()) if timestamp is None
                                    else timestamp)
    return bytes(msg.pack(packer))


def forged(msg: Any) -> bytes:
    """Right ids, link id and a fresh timestamp; the signature made up (no key)."""
    frame = bytearray(pack(msg, key=WRONG_KEY))
    frame[-6:] = os.urandom(6)
    return bytes(frame)


# ---------------------------------------------------------------------------- 1. link
def bench_hostile_frames(n_each: int) -> dict[str, dict[str, int]]:
    """Hostile command frames from the peer's own address to a signed listening link."""
    vehicle = Link.listen(LOOPBACK, src_system=1, src_component=1, signing=Signing(KEY))
    controller = Link.connect(vehicle.local_address, src_system=CONTROLLER_IDS[0],
                              src_component=CONTROLLER_IDS[1], signing=Signing(KEY))
    captured: list[bytes] = []
    controller.on_frame = lambda d, b, m, t: captured.append(bytes(b))
    controller.send(mav.MAVLink_heartbeat_message(18, 8, 0, 0, 0, 3))
    for k in range(n_each):                    # genuine traffic, to replay later
        controller.send(COMMANDS[k % 3](k))
        if k % BATCH == BATCH - 1:
            _drain(vehicle, k + 2)
    _drain(vehicle, n_each + 1)
    controller.on_frame = None
    assert vehicle.stats.rx_frames == n_each + 1, vehicle.stats.summary()
    far = mavlink_timestamp(time.time()) + 10**9
    kinds: dict[str, Callable[[int], bytes]] = {
        "unsigned": lambda k: pack(COMMANDS[k % 3](k), key=None),
        "wrong_key": lambda k: pack(COMMANDS[k % 3](k), key=WRONG_KEY),
        "forged_signature": lambda k: forged(COMMANDS[k % 3](k)),
        "replayed": lambda k: captured[1 + k % n_each],
        "future_timestamp_forged": lambda k: pack(COMMANDS[k % 3](k), key=WRONG_KEY,
                                                  timestamp=far + k),
    }
    out = {}
    try:
        for name, make in kinds.items():
            before = vehicle.stats.rx_datagrams
            accepted = 0
            for k in range(n_each):
                controller.send_raw(make(k))
                if k % BATCH == BATCH - 1:
                    accepted += len(_drain(vehicle, before + k + 1))
            accepted += len(_drain(vehicle, before + n_each))
            out[name] = {"sent": n_each, "received": vehicle.stats.rx_datagrams - before,
                         "accepted": accepted}
        # After all that, the genuine controller still gets through.
        before = vehicle.stats.rx_datagrams
        got: list[Any] = []
        for k in range(n_each):
            controller.send(controls(k, 0.5))
            if k % BATCH == BATCH - 1:
                got += _drain(vehicle, before + k + 1)
        got += _drain(vehicle, before + n_each)
        out["genuine_after_attacks"] = {"sent": n_each,
                                        "received": vehicle.stats.rx_datagrams - before,
                                        "accepted": len(got)}
        out["link_counters"] = {k: v for k, v in vehicle.stats.as_dict().items() if v}
    finally:
        vehicle.close()
        controller.close()
    return out


def _drain(link: Link, expect_datagrams: int, timeout_s: float = 2.0) -> list[Any]:
    out: list[Any] = []
    deadline = time.monotonic() + timeout_s
    while link.stats.rx_datagrams < expect_datagrams and time.monotonic() < deadline:
        out += link.recv(0.05)
    return out + link.recv(0.0)


# ---------------------------------------------------------------------------- 2. vehicle
def bench_vehicle_under_attack(n_ticks: int) -> dict[str, Any]:
    """A signed vehicle in lockstep; one hostile frame before every genuine reply."""
    sc = load_scenario("paper").replace(**{"attack.rotor": 0})
    hover = hover_fraction(sc)
    vehicle = Vehicle(sc, listen=LOOPBACK, key=KEY)
    result: dict[str, Any] = {}
    thread = threading.Thread(
        target=lambda: result.update(r=vehicle.run(n_ticks * sc.run.control_dt_s)),
        daemon=True)
    thread.start()
    last_tx = [b""]           # the last frame we sent: the previous tick's genuine reply

    def keep_tx(direction: str, raw: bytes, _msg: Any, _t: float) -> None:
        if direction == "tx":
            last_tx[0] = bytes(raw)

    pilot = Pilot(vehicle.listen_address, sysid=CONTROLLER_IDS[0], compid=CONTROLLER_IDS[1],
                  key=KEY, on_frame=keep_tx)
    hostile = {"unsigned": 0, "wrong_key": 0, "forged_signature": 0, "replayed": 0}
    kinds = list(hostile)
    answered = [0]

    def attack_then_hover(odom: Any, _esc: Any) -> list[float]:
        """Inject one hostile frame, then answer genuinely (the Pilot sends the reply)."""
        k = answered[0]
        kind = kinds[k % len(kinds)]
        attack = COMMANDS[k % 3](odom.time_usec // 1000)
        if kind == "unsigned":
            frame = pack(attack, key=None)
        elif kind == "wrong_key":
            frame = pack(attack, key=WRONG_KEY)
        elif kind == "forged_signature":
            frame = forged(attack)
        else:                               # replay our own last genuine reply
            frame = last_tx[0] if k else pack(attack, key=None)
        pilot.link.send_raw(frame)
        hostile[kind] += 1
        answered[0] += 1
        return [hover] * 4

    pilot.hello()
    try:
        with contextlib.suppress(NoStateError):    # the run ended: counted below
            pilot.fly(n_ticks, attack_then_hover, timeout_s=10.0, keep=False)
        thread.join(10.0)
    finally:
        vehicle.stop()
        thread.join(5.0)
        vehicle.close()
        pilot.close()
    st = vehicle.stats
    return {"ticks": result["r"].ticks if "r" in result else 0, "hostile_sent": hostile,
            "hostile_total": sum(hostile.values()), "controls_applied": st.controls_applied,
            "commands_accepted": st.commands_accepted,
            "failures_injected": st.failures_injected, "stale_controls": st.stale_controls,
            "control_link": {k: v for k, v in st.control_link.as_dict().items() if v}}


# ---------------------------------------------------------------------------- 3. the flaw
def bench_future_timestamp(n_genuine: int) -> dict[str, int]:
    now = mavlink_timestamp(time.time())
    genuine = [pack(controls(k, 0.5), key=KEY, timestamp=now + k) for k in range(n_genuine)]
    attack = pack(controls(0, 1.0), key=WRONG_KEY, timestamp=now + 10**9)
    pym = new_mavlink(1, 1)
    pym.signing.secret_key = KEY
    ours = Signing(KEY)
    out = {"genuine_sent_after_attack": n_genuine - 1}
    for name, accept in (("pymavlink_2_4_50_accepted", lambda f: _pym_accepts(pym, f)),
                         ("ours_accepted", lambda f: ours.verify(f) is None)):
        accept(genuine[0])
        accept(attack)
        out[name] = sum(accept(f) for f in genuine[1:])
    return out


def _pym_accepts(parser: Any, frame: bytes) -> bool:
    try:
        parser.decode(bytearray(frame))
    except mav.MAVError:
        return False
    return True


# ---------------------------------------------------------------------------- 4. cost
def bench_cost(n: int) -> dict[str, float]:
    msg = controls(123000, 0.5)
    plain = new_mavlink(*CONTROLLER_IDS)
    signer = Signing(KEY)
    packer = new_mavlink(*CONTROLLER_IDS)
    signer.configure_packer(packer, 0)
    frame_plain = bytes(msg.pack(plain))

    def t(fn: Callable[[], Any]) -> float:
        best = float("inf")
        for _ in range(3):
            t0 = time.perf_counter()
            for _ in range(n):
                fn()
            best = min(best, (time.perf_counter() - t0) / n * 1e6)
        return best

    def sign_one() -> None:
        signer.stamp(packer)
        msg.pack(packer)

    frames = []
    for _ in range(n):
        sign_one()
        frames.append(bytes(msg._msgbuf))
    verifier = Signing(KEY, window_s=1e6)
    it = iter(frames * 3)
    decoder = new_mavlink(1, 1)
    return {
        "pack_unsigned_us": t(lambda: msg.pack(plain)),
        "pack_signed_us": t(sign_one),
        "sha256_48_us": t(lambda: signature48(KEY, frame_plain)),
        "verify_us": t(lambda: verifier.verify(next(it))),
        "decode_us": t(lambda: decoder.decode(bytearray(frame_plain))),
    }


def bench_link_path(batches: int = 9, n: int = 100) -> dict[str, float]:
    """µs per frame through :meth:`Link.send` and :meth:`Link.recv` (real UDP, loopback),
    unsigned vs signed: the integrated cost (best of ``batches`` batches of ``n``)."""
    out = {}
    msg = controls(123000, 0.5)
    for mode in ("unsigned", "signed"):
        rx = Link.listen(LOOPBACK, src_system=1, src_component=1,
                         signing=Signing(KEY) if mode == "signed" else None)
        tx = Link.connect(rx.local_address, src_system=CONTROLLER_IDS[0],
                          src_component=CONTROLLER_IDS[1],
                          signing=Signing(KEY) if mode == "signed" else None)
        tx.send(mav.MAVLink_heartbeat_message(18, 8, 0, 0, 0, 3))
        _drain(rx, 1)
        best_send = best_recv = float("inf")
        for b in range(batches):
            t0 = time.perf_counter()
            for _ in range(n):
                tx.send(msg)
            t1 = time.perf_counter()
            _drain(rx, 1 + n * (b + 1))
            t2 = time.perf_counter()
            best_send = min(best_send, (t1 - t0) / n * 1e6)
            best_recv = min(best_recv, (t2 - t1) / n * 1e6)
        if rx.stats.rejected or rx.stats.rx_frames != 1 + n * batches:
            raise RuntimeError(f"link path: lost frames ({rx.stats.summary()})")
        rx.close()
        tx.close()
        out[f"{mode}_send_us"] = best_send
        out[f"{mode}_recv_us"] = best_recv
    return out


def lockstep_ticks_per_s(n_ticks: int, key_file: str | None) -> float:
    """``tfl-mav sim`` (hover, 1 kHz) flown by our Link; signed iff ``key_file``."""
    sc = load_scenario("paper")
    extra = ["--key-file", key_file] if key_file else []
    proc, address = popen_sim(["--set", "attack.rotor=0", "--set",
                               "initial.position_m=[0, 0, 5]", "--duration",
                               f"{n_ticks / 1000.0:g}", *extra], "paper")
    warmup = 200
    try:
        with Pilot(address, sysid=CONTROLLER_IDS[0], compid=CONTROLLER_IDS[1],
                   key=KEY if key_file else None) as pilot:
            pilot.hello()
            pilot.fly(warmup, hover_controls(sc), keep=False)
            t0 = time.perf_counter()
            pilot.fly(n_ticks - warmup, hover_controls(sc), keep=False)
            elapsed = time.perf_counter() - t0
        proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
    if proc.returncode != 0:
        raise RuntimeError(f"sim exited with {proc.returncode}")
    return (n_ticks - warmup) / elapsed


def bench_lockstep(n_ticks: int, repeats: int) -> dict[str, Any]:
    """Alternate unsigned/signed runs; the median of each."""
    with tempfile.TemporaryDirectory() as tmp:
        key_file = Path(tmp) / "key"
        key_file.write_text(KEY.hex() + "\n")
        key_file.chmod(0o600)
        plain, signed = [], []
        for _ in range(repeats):
            plain.append(lockstep_ticks_per_s(n_ticks, None))
            signed.append(lockstep_ticks_per_s(n_ticks, str(key_file)))
    p, s = statistics.median(plain), statistics.median(signed)
    return {"unsigned_ticks_per_s": p, "signed_ticks_per_s": s, "signed_over_unsigned": s / p,
            "unsigned_runs": plain, "signed_runs": signed}


# ---------------------------------------------------------------------------- main
def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=3000,
                        help="hostile frames per kind (default 3000)")
    parser.add_argument("--ticks", type=int, default=10000,
                        help="lockstep ticks per speed run and under attack (default 10000)")
    parser.add_argument("--repeats", type=int, default=3, help="speed runs per mode")
    parser.add_argument("--json", metavar="FILE", help="also write the numbers as JSON")
    args = parser.parse_args()
    if args.frames < 10 or args.ticks <= 400:
        parser.error("--frames must be >= 10 and --ticks > 400")

    hostile = bench_hostile_frames(args.frames)
    under_attack = bench_vehicle_under_attack(args.ticks)
    flaw = bench_future_timestamp(args.frames)
    cost = bench_cost(20000)
    cost.update(bench_link_path())
    # A tick: the vehicle sends ODOMETRY + ESC_TELEMETRY and receives one reply; the
    # controller the reverse. Lockstep is serial, so the costs of both processes add up.
    cost["per_tick_us"] = 3 * (cost["signed_send_us"] - cost["unsigned_send_us"]
                               + cost["signed_recv_us"] - cost["unsigned_recv_us"])
    speed = bench_lockstep(args.ticks, args.repeats)

    rows: list[tuple[str, str]] = []
    for name, r in hostile.items():
        if name != "link_counters":
            rows.append((f"link, from the peer's address: {name.replace('_', ' ')}",
                         f"{r['accepted']} / {r['sent']} accepted"))
    ua = under_attack
    rows += [
        ("vehicle in lockstep: hostile frames injected", f"{ua['hostile_total']}"),
        ("  ticks flown / genuine controls applied",
         f"{ua['ticks']} / {ua['controls_applied']}"),
        ("  hostile commands accepted / failures injected",
         f"{ua['commands_accepted']} / {ua['failures_injected']}"),
        ("future-timestamp attack: genuine frames after it, pymavlink",
         f"{flaw['pymavlink_2_4_50_accepted']} / {flaw['genuine_sent_after_attack']} accepted"),
        ("future-timestamp attack: genuine frames after it, ours",
         f"{flaw['ours_accepted']} / {flaw['genuine_sent_after_attack']} accepted"),
        ("pack HIL_ACTUATOR_CONTROLS unsigned", f"{cost['pack_unsigned_us']:.2f} µs"),
        ("pack signed (stamp + pack + SHA-256)", f"{cost['pack_signed_us']:.2f} µs"),
        ("SHA-256/48 alone", f"{cost['sha256_48_us']:.2f} µs"),
        ("verify (Signing.verify)", f"{cost['verify_us']:.2f} µs"),
        ("decode (pymavlink, for scale)", f"{cost['decode_us']:.2f} µs"),
        ("Link.send per frame, unsigned / signed",
         f"{cost['unsigned_send_us']:.2f} / {cost['signed_send_us']:.2f} µs"),
        ("Link.recv per frame, unsigned / signed",
         f"{cost['unsigned_recv_us']:.2f} / {cost['signed_recv_us']:.2f} µs"),
        ("per lockstep tick: 3 frames signed + 3 verified (both sides)",
         f"{cost['per_tick_us']:.1f} µs"),
        ("lockstep unsigned (median)", f"{speed['unsigned_ticks_per_s']:.0f} ticks/s"),
        ("lockstep signed (median)", f"{speed['signed_ticks_per_s']:.0f} ticks/s"),
        ("signed / unsigned (noisy on a shared machine: see the runs)",
         f"{speed['signed_over_unsigned']:.3f}"),
    ]
    width = max(len(n) for n, _ in rows)
    print(f"bench_signing ({args.frames} frames per kind, {args.ticks} ticks, python "
          f"{platform.python_version()}, {os.cpu_count()} cpus)")
    for name, value in rows:
        print(f"  {name:<{width}}  {value:>22}")
    hostile_accepted = (sum(r["accepted"] for n, r in hostile.items()
                            if n not in ("link_counters", "genuine_after_attacks"))
                        + ua["commands_accepted"] + ua["failures_injected"]
                        + (ua["controls_applied"] - ua["ticks"]))
    print(f"  hostile frames accepted in total: {hostile_accepted}")
    if args.json:
        Path(args.json).write_text(json.dumps({
            "frames_per_kind": args.frames, "ticks": args.ticks,
            "python": platform.python_version(), "cpus": os.cpu_count(),
            "hostile_link": hostile, "vehicle_under_attack": under_attack,
            "future_timestamp_attack": flaw, "cost_us": cost, "lockstep": speed,
            "hostile_accepted_total": hostile_accepted}, indent=2))
    return 0 if hostile_accepted == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
