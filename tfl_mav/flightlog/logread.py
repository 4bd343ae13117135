"""Read a recorder's MCAP file, finished or not, and rewrite a damaged one as a valid file.

A file whose writer died (SIGKILL, disk full) has no summary and is refused by
``mcap.reader.make_reader``. Read as a stream, every record before the damage is still good:
:class:`LogReader` streams such a file (``mcap.stream_reader.StreamReader``, chunk CRCs
checked) and stops quietly at the first record that does not read, saying why in
``error``. Messages come in file order, which is the order the recorder wrote them.

A finished file is read through its summary instead (``mcap.reader`` for the summary,
``mcap.stream_reader.get_chunk_data_stream`` for each chunk, decompressed and CRC-checked
by the library): the library's record-by-record parse costs ~25 µs a message in Python, a
30 s flight has ~350 000 of them, so :meth:`LogReader.messages` splits a chunk's message
records with one ``struct`` unpack each (the MCAP spec's fixed header: opcode, length,
channel id, sequence, log time, publish time) and skips the channels not asked for
without building them: the same messages, in the same order (tests/unit/test_logread.py).

:meth:`LogMessage.decode` turns a message into plain values whatever its encoding: JSON
(msgspec) or protobuf (the ``protobuf`` library on the schema stored in the file).
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Footer, Message, Metadata, ReadDataStream, Schema
from mcap.stream_reader import StreamReader, get_chunk_data_stream
from mcap.writer import CompressionType, IndexType, Writer

__all__ = ["LogMessage", "LogReader", "mavlink_messages", "raw_frames", "recover"]


@dataclass(frozen=True)
class LogMessage:
    topic: str
    schema_name: str
    log_time_ns: int
    publish_time_ns: int
    data: bytes
    schema: Schema | None = None

    def json(self) -> Any:
        return _decode_json(self.data)

    def decode(self) -> Any:
        """The message as plain values (a dict): JSON parsed, protobuf by its schema
        (set fields only; repeated as lists). ValueError for another encoding."""
        sc = self.schema
        if sc is None or sc.encoding == "jsonschema" or self.data[:1] == b"{":
            return _decode_json(self.data)
        if sc.encoding == "protobuf":
            from tfl_mav.flightlog.protos import message_class, to_dict

            return to_dict(message_class(sc.name, bytes(sc.data)).FromString(self.data))
        raise ValueError(f"{self.topic}: cannot decode schema encoding {sc.encoding!r}")


_decode_json = msgspec.json.Decoder().decode     # what json.loads gives, several times faster
_OP_MESSAGE = 0x05                                # MCAP Message record (spec)
_RECORD_HEAD = struct.Struct("<BQ")               # opcode, length
_MESSAGE_HEAD = struct.Struct("<HIQQ")            # channel id, sequence, log/publish time
_MESSAGE_FIXED = _MESSAGE_HEAD.size


class LogReader:
    """One pass over ``path``. After iterating: ``complete`` (the footer was reached),
    ``error`` (why reading stopped early, None if it did not), ``channels`` and
    ``schemas`` seen, ``metadata`` records."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.complete = False
        self.error: str | None = None
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.metadata: list[Metadata] = []

    def records(self) -> Iterator[Schema | Channel | Message | Metadata]:
        """Schemas, channels, metadata and messages, in file order, up to the damage."""
        try:
            f = open(self.path, "rb")  # noqa: SIM115 -- closed in the finally below
        except OSError as exc:
            raise OSError(f"cannot read MCAP file {self.path}: {exc.strerror}") from None
        try:
            reader = StreamReader(f, validate_crcs=True)
            it = iter(reader.records)
            while True:
                try:
                    rec = next(it)
                except StopIteration:
                    break
                except Exception as exc:     # truncation, bad CRC, bad compression, ...
                    self.error = f"{type(exc).__name__}: {exc}" if str(exc) else \
                        type(exc).__name__
                    break
                if isinstance(rec, Schema):
                    self.schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    self.channels[rec.id] = rec
                elif isinstance(rec, Metadata):
                    self.metadata.append(rec)
                elif isinstance(rec, Footer):
                    self.complete = True
                    continue
                elif not isinstance(rec, Message):
                    continue
                yield rec
        finally:
            f.close()

    def messages(self, topics: set[str] | None = None) -> Iterator[LogMessage]:
        """Messages (optionally only ``topics``) in file order, up to the damage."""
        summary = self._summary()
        if summary is not None:
            yield from self._indexed(summary, topics)
            return
        for rec in self.records():
            if not isinstance(rec, Message):
                continue
            ch = self.channels.get(rec.channel_id)
            if ch is None or (topics is not None and ch.topic not in topics):
                continue
            sc = self.schemas.get(ch.schema_id)
            yield LogMessage(ch.topic, sc.name if sc else "", rec.log_time, rec.publish_time,
                             rec.data, sc)


    def message_counts(self) -> dict[str, int] | None:
        """Messages per topic from a finished file's summary statistics (None: not a
        finished file, or no statistics), without reading the messages."""
        summary = self._summary()
        stats = summary.statistics if summary is not None else None
        if stats is None:
            return None
        out: dict[str, int] = {}
        for cid, n in stats.channel_message_counts.items():
            ch = summary.channels.get(cid)
            if ch is not None:
                out[ch.topic] = out.get(ch.topic, 0) + n
        return out

    def read_metadata(self) -> list[Metadata]:
        """The file's metadata records: all of a finished file's (its summary indexes them,
        wherever they are), else those before the first message (a stream stops there)."""
        try:
            with open(self.path, "rb") as f:
                reader = make_reader(f)
                if reader.get_summary() is not None:
                    self.metadata = list(reader.iter_metadata())
                    return self.metadata
        except OSError as exc:
            raise OSError(f"cannot read MCAP file {self.path}: {exc.strerror}") from None
        except (McapError, ValueError, struct.error, EOFError, IndexError, KeyError):
            pass                 # not a finished file: stream it
        for rec in self.records():
            if isinstance(rec, Message):
                break
        return self.metadata

    def _summary(self) -> Any:
        """The summary of a finished file with chunk indexes, or None (stream it)."""
        try:
            with open(self.path, "rb") as f:
                reader = make_reader(f)
                summary = reader.get_summary()
                if summary is None or not summary.chunk_indexes:
                    return None
                self.metadata = list(reader.iter_metadata())
        except OSError as exc:
            raise OSError(f"cannot read MCAP file {self.path}: {exc.strerror}") from None
        except (McapError, ValueError, struct.error, EOFError, IndexError, KeyError):
            return None          # not a finished file: the stream reader says why
        return summary

    def _indexed(self, summary: Any, topics: set[str] | None) -> Iterator[LogMessage]:
        """:meth:`messages` of a finished file: its chunks in file order (see the module
        docstring); an unreadable chunk ends it, saying why in ``error``."""
        self.schemas = dict(summary.schemas)
        self.channels = dict(summary.channels)
        wanted = {cid: (ch.topic, summary.schemas[ch.schema_id].name
                        if ch.schema_id in summary.schemas else "",
                        summary.schemas.get(ch.schema_id))
                  for cid, ch in summary.channels.items()
                  if topics is None or ch.topic in topics}
        head, msg_head = _RECORD_HEAD.unpack_from, _MESSAGE_HEAD.unpack_from
        with open(self.path, "rb") as f:
            for index in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
                offsets = index.message_index_offsets
                if offsets and not any(cid in wanted for cid in offsets):
                    continue           # no message of a channel asked for in this chunk
                try:
                    stream, n = get_chunk_data_stream(_chunk(f, index), validate_crc=True)
                    data = stream.read(n)
                except Exception as exc:     # a bad CRC, bad compression, a short file
                    self.error = f"{type(exc).__name__}: {exc}" if str(exc) else \
                        type(exc).__name__
                    return
                at = 0
                while at < n:
                    op, length = head(data, at)
                    body = at + 9
                    at = body + length
                    if op != _OP_MESSAGE:
                        continue
                    cid, _seq, log_ns, pub_ns = msg_head(data, body)
                    name = wanted.get(cid)
                    if name is not None:
                        yield LogMessage(name[0], name[1], log_ns, pub_ns,
                                         data[body + _MESSAGE_FIXED:at], name[2])
        self.complete = True


def raw_frames(path: str | Path, reader: LogReader | None = None
               ) -> Iterator[tuple[LogMessage, bytes, bool, bool]]:
    """Every frame of ``/mavlink/raw`` in file order: (its datagram's message, wire bytes,
    sent by the recording process, refused by its link); ``reader``: the one to read with
    (its ``error`` then says why reading stopped)."""
    from tfl_mav.flightlog.protos import frames_fields

    for m in (reader or LogReader(path)).messages({"/mavlink/raw"}):
        fields = frames_fields(m.data) if m.data[:1] != b"{" else None
        if fields is None:
            f = m.decode()
            if isinstance(f.get("data"), str):          # JSON files: base64, one a frame
                import base64

                fields = ([base64.b64decode(f["data"])], f["direction"] == "tx",
                          [] if f["accepted"] else [0])
            else:
                fields = (f.get("frames", []), bool(f.get("tx")), f.get("rejected", []))
        raws, tx, rejected = fields
        for i, raw in enumerate(raws):
            yield m, raw, tx, i in rejected


def mavlink_messages(path: str | Path, name: str, sysid: int | None = None,
                     compid: int | None = None, direction: str | None = None
                     ) -> Iterator[tuple[int, dict[str, Any]]]:
    """Every frame of MAVLink message ``name`` (e.g. ``"ESC_TELEMETRY_1_TO_4"``) the log
    holds, decoded from ``/mavlink/raw`` (the decoded channels are at most 50 Hz; the raw
    one has every frame): (time ns, fields) in file order, optionally only from
    ``sysid``/``compid`` and ``direction`` ("rx"/"tx"); rejected frames are left out. The
    time is sim time on a lockstep log's sim timeline (log time − the ``timeline``
    metadata's ``flight_start_ns``; 0 before the flight), else the log time."""
    from tfl_mav.link.dialect import mav
    from tfl_mav.link.payload import PayloadDecoder

    decoder = PayloadDecoder()
    start = {md.name: md.metadata for md in LogReader(path).read_metadata()}.get(
        "timeline", {}).get("flight_start_ns")
    start_ns = int(start) if start else 0
    msgid = next(i for i, cls in mav.mavlink_map.items() if cls.msgname == name)
    for m, raw, tx, rejected in raw_frames(path):
        if rejected or len(raw) < 12 or (raw[7] | raw[8] << 8 | raw[9] << 16) != msgid:
            continue
        if (sysid is not None and raw[5] != sysid) or (
                compid is not None and raw[6] != compid) or (
                direction is not None and (direction == "tx") != tx):
            continue
        fields = decoder.fields(raw, msgid)
        if fields is not None:
            yield max(m.log_time_ns - start_ns, 0) if start else m.log_time_ns, fields


def _chunk(f: Any, index: Any) -> Chunk:
    """The Chunk record a chunk index points at (its opcode and length skipped)."""
    f.seek(index.chunk_start_offset + 1 + 8)
    return Chunk.read(ReadDataStream(f))


def recover(src: str | Path, dst: str | Path) -> tuple[int, str | None]:
    """Rewrite everything readable in ``src`` into a valid, finished MCAP file ``dst``.

    Returns (messages written, why reading stopped early or None). ``dst`` must differ from
    ``src``.
    """
    if Path(src).resolve() == Path(dst).resolve():
        raise ValueError("--recover: the output must be a different file from the input")
    reader = LogReader(src)
    schema_ids: dict[int, int] = {}
    channel_ids: dict[int, int] = {}
    count = 0
    with open(dst, "wb") as out:
        writer = Writer(out, compression=CompressionType.ZSTD,
                        index_types=IndexType.CHUNK | IndexType.MESSAGE | IndexType.METADATA)
        writer.start("tfl-mav", "tfl-mav recover")
        for rec in reader.records():
            if isinstance(rec, Schema):
                schema_ids[rec.id] = writer.register_schema(rec.name, rec.encoding, rec.data)
            elif isinstance(rec, Channel):
                channel_ids[rec.id] = writer.register_channel(
                    rec.topic, rec.message_encoding, schema_ids.get(rec.schema_id, 0),
                    rec.metadata)
            elif isinstance(rec, Metadata):
                writer.add_metadata(rec.name, rec.metadata)
            elif isinstance(rec, Message) and rec.channel_id in channel_ids:
                writer.add_message(channel_ids[rec.channel_id], rec.log_time, rec.data,
                                   rec.publish_time, rec.sequence)
                count += 1
        writer.finish()
    return count, reader.error
