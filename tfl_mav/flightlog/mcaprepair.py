"""Make an MCAP file whose writer died readable again, in place, by any MCAP reader.

A writer killed mid-flight (SIGKILL, out of memory, power) leaves a file with no summary
and no footer, often ending in a chunk whose length field still holds the writer's
placeholder (``0xFFFF…``): ``mcap.reader.make_reader`` refuses it. Everything before that
chunk is intact. :func:`repair` walks the data section record by record, decompresses and
CRC-checks every chunk (the same checks a reader makes), truncates the file after the last
record that reads, and appends what the writer would have written at close (the MCAP spec's
summary section): a ``recording`` metadata record saying the file was cut short and where,
Data End, the schemas and channels, statistics, one chunk index per chunk, metadata indexes,
summary offsets, the footer and the closing magic. The result is then *read back* with
``mcap.reader.make_reader`` (``iter_messages``), the way a user's tool reads it, and the
message count compared: a repair is only reported good if that read agrees (``mcap
recover`` has been seen to exit 0 on a file no reader opens, foxglove/mcap #1474).

Idempotent: a file that already has its footer is left alone; a repair that was itself
killed leaves a file ending after its Data End or inside the new summary, which the next
repair truncates back to that point and writes again.

Command line (what :class:`~tfl_mav.flightlog.recorder_process.RecorderProcess` runs, in a
process of its own, the moment its recorder child dies): ``python -m
tfl_mav.flightlog.mcaprepair FILE [REASON]`` prints the :class:`Repair` as one JSON line;
exit code 0 when the file reads, 3 when it does not.
"""

from __future__ import annotations

import errno
import io
import json
import os
import struct
import sys
import zlib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from mcap.stream_reader import get_chunk_data_stream

__all__ = ["CUT_METADATA", "Repair", "cut_short", "repair"]

MAGIC = b"\x89MCAP0\r\n"
CUT_METADATA = "recording"
"""Name of the metadata record of a file that did not end as its writer meant it to
(``complete`` = ``false``, ``reason``, ``last_log_time_ns``, ``last_sim_time_s``); a file
closed normally has none."""

MIN_KEPT = 0.9
"""On a full disk, the newest chunks are given up to make room for the summary only while
this share of the messages stays; else the file is left without one (a stream reader
still reads it all) rather than readable by every reader but nearly empty."""

_HEAD = struct.Struct("<BQ")                 # opcode, record length
_OPCODES = frozenset(op.value for op in Opcode)   # the record kinds MCAP defines
_MSG = struct.Struct("<HIQQ")                # channel id, sequence, log time, publish time
_TIMED_TOPICS = ("/sim/truth/state", "/controller/state")   # records that carry t_s


@dataclass
class Repair:
    """What :func:`repair` found and did. ``readable``: ``make_reader`` reads the file
    (all ``messages``) after the repair; ``repaired``: the file was rewritten (False: it
    was already complete, or nothing could be saved); ``kept_bytes``/``cut_bytes``: the
    data section kept and the damaged tail dropped; ``last_log_time_ns`` and
    ``last_sim_time_s`` (sim time of the last truth or controller record, None if none):
    where the file now ends; ``error``: why the scan stopped, or why it is unreadable."""

    path: str
    readable: bool = False
    repaired: bool = False
    messages: int = 0
    chunks: int = 0
    kept_bytes: int = 0
    cut_bytes: int = 0
    last_log_time_ns: int | None = None
    last_sim_time_s: float | None = None
    error: str | None = None
    reason: str = ""

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class _Scan:
    end: int = 0                       # end of the last good record of the data section
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    chunk_indexes: list[ChunkIndex] = field(default_factory=list)
    metadata_indexes: list[MetadataIndex] = field(default_factory=list)
    counts: dict[int, int] = field(default_factory=dict)
    start_ns: int | None = None
    end_ns: int = 0
    last: dict[int, bytes] = field(default_factory=dict)      # channel → last message data
    chunk_counts: list[dict[int, int]] = field(default_factory=list)    # per chunk index
    chunk_last: list[dict[int, bytes]] = field(default_factory=list)
    complete: bool = False             # the footer is there
    stop: str | None = None


def _read_chunk_records(data: bytes, scan: _Scan, counts: dict[int, int],
                        last: dict[int, bytes]) -> list[int]:
    """Parse a chunk's records (ValueError if any is malformed); the channel ids seen."""
    at, n = 0, len(data)
    seen: list[int] = []
    while at < n:
        if at + 9 > n:
            raise ValueError("chunk ends inside a record header")
        op, length = _HEAD.unpack_from(data, at)
        body, at = at + 9, at + 9 + length
        if at > n:
            raise ValueError("chunk ends inside a record")
        if op == Opcode.MESSAGE:
            cid = _MSG.unpack_from(data, body)[0]
            if cid not in counts:
                counts[cid] = 0
                seen.append(cid)
            counts[cid] += 1
            last[cid] = data[body + _MSG.size:at]
        elif op == Opcode.SCHEMA:
            sc = Schema.read(ReadDataStream(io.BytesIO(data[body:at])))
            scan.schemas[sc.id] = sc
        elif op == Opcode.CHANNEL:
            ch = Channel.read(ReadDataStream(io.BytesIO(data[body:at])))
            scan.channels[ch.id] = ch
    return seen


def _scan(f: Any, size: int) -> _Scan:
    """Walk the data section; stop at the first record that does not read whole."""
    scan = _Scan()
    if f.read(8) != MAGIC:
        scan.stop = "not an MCAP file (no magic)"
        return scan
    at = 8
    pending: ChunkIndex | None = None          # the chunk whose message indexes follow
    chunk_channels: dict[int, set[int]] = {}   # chunk offset → channels of its messages
    while True:
        f.seek(at)
        head = f.read(9)
        if len(head) < 9:
            scan.stop = "file ends inside a record header" if head else None
            break
        op, length = _HEAD.unpack(head)
        end = at + 9 + length
        if end > size:
            scan.stop = (f"{Opcode(op).name if op in _OPCODES else op} "
                         f"record at byte {at} is cut short")
            break
        if op == Opcode.DATA_END:
            # the summary follows: a footer at the very end means a whole file
            f.seek(size - 8 - 9 - 20)
            tail = f.read(9 + 20 + 8)
            scan.complete = tail[-8:] == MAGIC and tail[0] == Opcode.FOOTER
            if not scan.complete:
                scan.stop = "summary section cut short"
            break
        body = f.read(length)
        try:
            if op == Opcode.CHUNK:
                chunk = Chunk.read(ReadDataStream(io.BytesIO(body)))
                stream, n = get_chunk_data_stream(chunk, validate_crc=True)
                counts: dict[int, int] = {}
                last: dict[int, bytes] = {}
                seen = _read_chunk_records(stream.read(n), scan, counts, last)
                for cid, k in counts.items():
                    scan.counts[cid] = scan.counts.get(cid, 0) + k
                scan.last.update(last)
                if seen:
                    scan.start_ns = chunk.message_start_time if scan.start_ns is None \
                        else min(scan.start_ns, chunk.message_start_time)
                    scan.end_ns = max(scan.end_ns, chunk.message_end_time)
                pending = ChunkIndex(
                    message_start_time=chunk.message_start_time,
                    message_end_time=chunk.message_end_time, chunk_start_offset=at,
                    chunk_length=9 + length, message_index_offsets={},
                    message_index_length=0, compression=chunk.compression,
                    compressed_size=len(chunk.data), uncompressed_size=chunk.uncompressed_size)
                chunk_channels[at] = set(seen)
                scan.chunk_indexes.append(pending)
                scan.chunk_counts.append(counts)
                scan.chunk_last.append(last)
            elif op == Opcode.MESSAGE_INDEX and pending is not None:
                cid = struct.unpack_from("<H", body)[0]
                pending.message_index_offsets[cid] = at
                pending.message_index_length += 9 + length
            elif op == Opcode.METADATA:
                md = Metadata.read(ReadDataStream(io.BytesIO(body)))
                scan.metadata_indexes.append(MetadataIndex(offset=at, length=9 + length,
                                                           name=md.name))
            elif op == Opcode.SCHEMA:
                sc = Schema.read(ReadDataStream(io.BytesIO(body)))
                scan.schemas[sc.id] = sc
            elif op == Opcode.CHANNEL:
                ch = Channel.read(ReadDataStream(io.BytesIO(body)))
                scan.channels[ch.id] = ch
            elif op == Opcode.MESSAGE:
                cid, _seq, log_ns, _pub = _MSG.unpack_from(body)
                scan.counts[cid] = scan.counts.get(cid, 0) + 1
                scan.last[cid] = body[_MSG.size:]
                scan.start_ns = log_ns if scan.start_ns is None else min(scan.start_ns,
                                                                         log_ns)
                scan.end_ns = max(scan.end_ns, log_ns)
        except Exception as exc:      # bad CRC, bad compression, malformed record
            scan.stop = f"record at byte {at} does not read ({type(exc).__name__}: {exc})"
            if op == Opcode.CHUNK and scan.chunk_indexes and \
                    scan.chunk_indexes[-1].chunk_start_offset == at:
                _drop_last_chunk(scan)
            break
        if op != Opcode.MESSAGE_INDEX and op != Opcode.CHUNK:
            pending = None
        scan.end = end
        at = end
    # a chunk's message indexes are usable only if every channel in it has one (a reader
    # skips a chunk whose indexes do not name the channel it wants); else none: unknown
    for index in scan.chunk_indexes:
        if set(index.message_index_offsets) != chunk_channels[index.chunk_start_offset]:
            index.message_index_offsets = {}
            index.message_index_length = 0
    if scan.end == 0:
        scan.end = at
    return scan


def _drop_last_chunk(scan: _Scan) -> int:
    """Forget the last chunk (and what follows it); returns where the data now ends."""
    index = scan.chunk_indexes.pop()
    counts = scan.chunk_counts.pop()
    scan.chunk_last.pop()
    for cid, k in counts.items():
        scan.counts[cid] -= k
        if not scan.counts[cid]:
            del scan.counts[cid]
    end = index.chunk_start_offset
    scan.metadata_indexes = [m for m in scan.metadata_indexes if m.offset < end]
    kept = [c for c, n in zip(scan.chunk_indexes, scan.chunk_counts, strict=True) if n]
    scan.start_ns = min((c.message_start_time for c in kept), default=None)
    scan.end_ns = max((c.message_end_time for c in kept), default=0)
    scan.last = {}
    for last in scan.chunk_last:
        scan.last.update(last)
    scan.end = end
    return end


def _last_sim_time(scan: _Scan) -> float | None:
    """Sim time of the last truth or controller record the file keeps."""
    from tfl_mav.flightlog.logread import LogMessage

    best: float | None = None
    for cid, ch in scan.channels.items():
        if ch.topic not in _TIMED_TOPICS or cid not in scan.last:
            continue
        sc = scan.schemas.get(ch.schema_id)
        try:
            t = LogMessage(ch.topic, sc.name if sc else "", 0, 0, scan.last[cid],
                           sc).decode().get("t_s")
        except Exception:
            continue
        if isinstance(t, (int, float)):
            best = float(t) if best is None else max(best, float(t))
    return best


def _summary(scan: _Scan, start: int, marker: Metadata) -> bytes:
    """Metadata marker + Data End + summary + footer + magic, to go at byte ``start``."""
    rb = RecordBuilder()
    marker.write(rb)
    metadata_indexes = [*scan.metadata_indexes,
                        MetadataIndex(offset=start, length=rb.count, name=marker.name)]
    DataEnd(data_section_crc=0).write(rb)
    summary_start = start + rb.count
    groups: list[SummaryOffset] = []
    sb = RecordBuilder()

    def group(opcode: int, records: list[Any]) -> None:
        g0 = sb.count
        for r in records:
            r.write(sb)
        if records:
            groups.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + g0,
                                        group_length=sb.count - g0))

    group(Opcode.SCHEMA, list(scan.schemas.values()))
    group(Opcode.CHANNEL, list(scan.channels.values()))
    group(Opcode.STATISTICS, [Statistics(
        message_count=sum(scan.counts.values()), schema_count=len(scan.schemas),
        channel_count=len(scan.channels), attachment_count=0,
        metadata_count=len(metadata_indexes), chunk_count=len(scan.chunk_indexes),
        message_start_time=scan.start_ns or 0, message_end_time=scan.end_ns,
        channel_message_counts=dict(scan.counts))])
    group(Opcode.CHUNK_INDEX, scan.chunk_indexes)
    group(Opcode.METADATA_INDEX, metadata_indexes)
    offsets_start = summary_start + sb.count
    for g in groups:
        g.write(sb)
    summary = sb.end()
    crc = zlib.crc32(summary)
    crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, offsets_start),
                     crc)
    Footer(summary_start=summary_start, summary_offset_start=offsets_start,
           summary_crc=crc).write(sb)
    return rb.end() + summary + sb.end() + MAGIC


class _ShortWriteError(Exception):
    def __init__(self, errno_: int, written: int) -> None:
        super().__init__(os.strerror(errno_))
        self.errno, self.written = errno_, written


def _write_at(fd: int, at: int, data: bytes) -> None:
    """All of ``data`` at byte ``at``; :class:`_ShortWriteError` (the errno and how much was
    written) if the disk refuses the rest."""
    view = memoryview(data)
    written = 0
    while view:
        try:
            n = os.pwrite(fd, view, at)
        except OSError as exc:
            raise _ShortWriteError(exc.errno or 0, written) from None
        view, at, written = view[n:], at + n, written + n


def read_back(path: str | Path) -> tuple[int, str | None]:
    """Every message of ``path`` through ``mcap.reader.make_reader`` (the summary, every
    chunk, CRCs checked), and the summary's statistics and chunk indexes checked against
    what was read: (count, None) or (count so far, why it failed)."""
    from mcap.reader import make_reader

    n = 0
    try:
        with open(path, "rb") as f:
            reader = make_reader(f, validate_crcs=True)
            summary = reader.get_summary()
            for _ in reader.iter_messages(log_time_order=False):
                n += 1
    except Exception as exc:
        return n, f"{type(exc).__name__}: {exc}"
    # the summary must be the file's: it indexes every chunk and counts every message
    if summary is None or summary.statistics is None:
        return n, "no summary statistics"
    if summary.statistics.message_count != n:
        return n, (f"the summary counts {summary.statistics.message_count} messages, "
                   f"{n} read")
    if n and not summary.chunk_indexes:
        return n, "no chunk index"
    return n, None


def repair(path: str | Path, reason: str = "the recording process died") -> Repair:
    """Make ``path`` readable in place (see the module docstring); never raises for a bad
    file (``error`` says what is wrong), OSError if it cannot be opened for writing."""
    p = Path(path)
    out = Repair(str(p), reason=reason)
    with open(p, "r+b", buffering=0) as f:
        size = os.fstat(f.fileno()).st_size
        scan = _scan(f, size)
        out.error = scan.stop
        out.messages = sum(scan.counts.values())
        out.chunks = len(scan.chunk_indexes)
        out.last_log_time_ns = scan.end_ns or None
        out.last_sim_time_s = _last_sim_time(scan)
        if scan.complete:
            n, err = read_back(p)
            out.readable, out.messages, out.error = err is None, n, err
            return out
        if scan.end < 8 + 9:           # not even a header: nothing to save
            out.error = out.error or "no MCAP header"
            return out
        size_cut = size - scan.end
        lowest = scan.end            # the file is intact up to here
        natural_messages = sum(scan.counts.values())
        capacity: int | None = None  # the largest file a full disk allows, once known
        while True:
            marker = Metadata(name=CUT_METADATA, metadata={
                "complete": "false", "reason": reason,
                "last_log_time_ns": str(scan.end_ns),
                "last_sim_time_s": "" if out.last_sim_time_s is None
                else f"{out.last_sim_time_s:.6f}",
                "cut_bytes": str(size - scan.end), "repaired_by": "tfl-mav mcaprepair"})
            tail = _summary(scan, scan.end, marker)
            if capacity is not None and scan.end + len(tail) > capacity:
                # a full disk: the summary needs more room than the cut freed; give up
                # the newest chunks (bookkeeping only, nothing cut yet) until it fits
                if not scan.chunk_indexes or (
                        sum(scan.counts.values()) - sum(scan.chunk_counts[-1].values())
                        < MIN_KEPT * natural_messages):
                    # no room for a summary without giving up much of what was written:
                    # keep every chunk that reads (a stream reader still reads them:
                    # tfl-mav inspect, --recover)
                    f.truncate(lowest)
                    out.messages = natural_messages
                    out.kept_bytes, out.cut_bytes = lowest, size - lowest
                    out.error = (f"no room for a summary (disk full): the file reads as a "
                                 f"stream up to byte {lowest} (`tfl-mav inspect {p} "
                                 "--recover OUT.mcap`)")
                    return out
                _drop_last_chunk(scan)
                out.last_sim_time_s = _last_sim_time(scan)
                continue
            f.truncate(scan.end)
            lowest = min(lowest, scan.end)
            try:
                _write_at(f.fileno(), scan.end, tail)
                os.fsync(f.fileno())
                break
            except _ShortWriteError as exc:
                f.truncate(scan.end)
                if exc.errno not in (errno.ENOSPC, errno.EFBIG, errno.EDQUOT):
                    raise OSError(exc.errno, os.strerror(exc.errno)) from None
                room = scan.end + exc.written - 512     # a margin for the file system
                capacity = room if capacity is None else min(capacity, room)
        out.messages = sum(scan.counts.values())
        out.chunks = len(scan.chunk_indexes)
        out.last_log_time_ns = scan.end_ns or None
        if size - scan.end > size_cut:
            out.error = (f"{out.error}; {size - scan.end - size_cut} more bytes given up to "
                         "fit the summary on a full disk")
    out.repaired = True
    out.kept_bytes = scan.end
    out.cut_bytes = size - scan.end
    n, err = read_back(p)
    out.readable = err is None and n == out.messages
    if err is not None:
        out.error = f"still unreadable after repair: {err}"
    elif n != out.messages:
        out.error = f"read back {n} messages, expected {out.messages}"
    return out


def cut_short(metadata: dict[str, dict[str, str]]) -> dict[str, str] | None:
    """The ``recording`` metadata of a file that was cut short, else None."""
    rec = metadata.get(CUT_METADATA)
    return rec if rec is not None and rec.get("complete") == "false" else None


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if not 1 <= len(args) <= 2:
        print("usage: python -m tfl_mav.flightlog.mcaprepair FILE [REASON]", file=sys.stderr)
        return 2
    try:
        result = repair(args[0], *args[1:])
    except OSError as exc:
        result = Repair(args[0], error=f"cannot open {args[0]}: {exc.strerror or exc}")
    print(json.dumps(result.as_dict()), flush=True)
    return 0 if result.readable else 3


if __name__ == "__main__":
    sys.exit(main())
