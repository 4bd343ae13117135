"""Coverage-guided fuzzing (atheris, libFuzzer) of the MAVLink receive path.

What one input drives: :meth:`tfl_mav.link.receive.Receiver.ingest`, the function
:meth:`~tfl_mav.link.transport.Link.recv` hands every datagram to (framing, the signature,
the CRC, the per-tick decode, pymavlink's decode, the skimmed messages, peer learning and
pinning, the counters), on a real :class:`~tfl_mav.link.transport.Link` over a real UDP
socket, in one of six states chosen by the input's first byte: listening (peer unknown),
settled unsigned (the per-tick fast path), settled with the vehicle's skimmed ids, signed,
signed with the frame built and signed by the harness (so fuzzed payloads reach the
decoders behind a valid signature), and unsigned with the frame built (valid framing and
CRC around fuzzed payloads). Every decoded message's fields are read, STATUSTEXTs go
through :class:`~tfl_mav.link.statustext.Reassembler`.

Invariants checked per input: nothing raises; the datagram is counted once
(``rx_datagrams``); accepted frames are exactly ``rx_frames``'s increase; a frame that
claims the link's own identity is never accepted.

Run (from the repository root, atheris from PyPI)::

    python tests/fuzz/link_receive.py -runs=1000000 -max_len=600 -len_control=0 tests/fuzz/corpus
    python tests/fuzz/link_receive.py --replay tests/fuzz/corpus         # replay, no atheris
    coverage run --source=tfl_mav/link tests/fuzz/link_receive.py --replay tests/fuzz/corpus
    coverage report

``tests/fuzz/corpus`` (created if missing) keeps the inputs that found new coverage; a crash
leaves ``crash-*`` with the input, as libFuzzer does.
"""

from __future__ import annotations

import os
import struct
import sys
import time
from pathlib import Path

from tfl_mav.link.dialect import mav
from tfl_mav.link.signing import Signing, mavlink_timestamp, signature48
from tfl_mav.link.statustext import Reassembler
from tfl_mav.link.transport import Link

KEY = bytes(range(1, 33))
PEER = ("127.0.0.1", 9)                 # the fuzzed datagrams' sender (never sent to)
OWN = (1, 1)                            # the link's identity: the vehicle's
_VEHICLE_SKIM = (mav.MAVLINK_MSG_ID_NAMED_VALUE_FLOAT, mav.MAVLINK_MSG_ID_DEBUG_FLOAT_ARRAY)
_KNOWN_IDS = sorted(mav.mavlink_map)
_texts = Reassembler()
_stamp = [0]                            # the harness's last signing timestamp


def _link(mode: int) -> Link:
    signing = Signing(KEY) if mode in (3, 4) else None
    settled = mode in (1, 2, 3, 4, 5)
    return Link.listen(("127.0.0.1", 0), src_system=OWN[0], src_component=OWN[1],
                       peer=PEER if settled else None, peer_sysid=42 if settled else None,
                       signing=signing, skim_ids=_VEHICLE_SKIM if mode == 2 else ())


_LINKS: dict[int, Link] = {}


def _framed(data: bytes, signer: Signing | None) -> bytes:
    """A frame around fuzzed bytes: msgid from the input, payload the rest, right CRC,
    signed by ``signer``'s key (then it verifies)."""
    if len(data) < 3:
        return data
    msgid = _KNOWN_IDS[data[0] % len(_KNOWN_IDS)]
    sysid = 42 if data[1] & 0x80 else data[1]
    payload = data[2:257]
    incompat = 1 if signer is not None else 0
    header = struct.pack("<BBBBBBBHB", 0xFD, len(payload), incompat, 0, 0, sysid, 191,
                         msgid & 0xFFFF, msgid >> 16)
    crc = mav.x25crc(header[1:] + payload + bytes([mav.mavlink_map[msgid].crc_extra])).crc
    frame = header + payload + struct.pack("<H", crc)
    if signer is None:
        return frame
    # signed as the peer would: link id 0, a timestamp newer than the last one (verify
    # then advance), the MAVLink 2 signature over key ‖ frame ‖ link id ‖ timestamp
    _stamp[0] = max(_stamp[0] + 1, mavlink_timestamp(time.time()))
    signed = frame + bytes([0]) + _stamp[0].to_bytes(6, "little")
    return signed + signature48(KEY, signed)


def one_input(data: bytes) -> None:
    if not data:
        return
    mode = data[0] % 6
    link = _LINKS.get(mode)
    if link is None:
        link = _LINKS[mode] = _link(mode)
    body = data[1:]
    if mode == 4:
        body = _framed(body, link.signing)
    elif mode == 5:
        body = _framed(body, None)
    st = link.stats
    before_dg, before_rx = st.rx_datagrams, st.rx_frames
    out: list = []
    link.receiver.ingest(body, PEER, out)
    assert st.rx_datagrams == before_dg + 1
    assert st.rx_frames - before_rx == len(out)
    for msg in out:
        assert (msg.get_srcSystem(), msg.get_srcComponent()) != OWN, "own identity accepted"
        for name in msg.get_fieldnames():
            getattr(msg, name)
        if msg.get_msgId() == mav.MAVLINK_MSG_ID_STATUSTEXT:
            _texts.add(msg.get_srcSystem(), msg.text, getattr(msg, "id", 0),
                       getattr(msg, "chunk_seq", 0), 0.0)
    if mode == 0 and link.peer is not None:     # learned: start listening afresh next time
        link.close()
        del _LINKS[mode]


def _replay(paths: list[str]) -> int:
    n = 0
    for p in paths:
        files = sorted(Path(p).iterdir()) if Path(p).is_dir() else [Path(p)]
        for f in files:
            one_input(f.read_bytes())
            n += 1
    print(f"replayed {n} inputs, no failure", file=sys.stderr)
    return 0


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] == "--replay":
        return _replay(sys.argv[2:])
    try:
        import atheris
    except ImportError:
        print("tests/fuzz/link_receive.py: atheris is not installed (pip install atheris); "
              "--replay DIR runs a corpus without it", file=sys.stderr)
        return 2
    for arg in sys.argv[1:]:
        if not arg.startswith("-"):
            os.makedirs(arg, exist_ok=True)
    atheris.instrument_all()
    atheris.Setup(sys.argv, one_input)
    atheris.Fuzz()
    return 0


if __name__ == "__main__":
    sys.exit(main())
