"""Read a recorder's MCAP file, finished or not, and rewrite a damaged one as a valid file.

A file whose writer died (SIGKILL, disk full) has no summary and is refused by
``mcap.reader.make_reader``. Read as a stream, every record before the damage is still good:
:class:`LogReader` always streams (``mcap.stream_reader.StreamReader``, chunk CRCs checked)
and stops quietly at the first record that does not read, saying why in ``error``. Messages
come in file order, which is the order the recorder wrote them.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcap.records import Channel, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, IndexType, Writer

__all__ = ["LogMessage", "LogReader", "recover"]


@dataclass(frozen=True)
class LogMessage:
    topic: str
    schema_name: str
    log_time_ns: int
    publish_time_ns: int
    data: bytes

    def json(self) -> Any:
        return json.loads(self.data)


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
        for rec in self.records():
            if not isinstance(rec, Message):
                continue
            ch = self.channels.get(rec.channel_id)
            if ch is None or (topics is not None and ch.topic not in topics):
                continue
            sc = self.schemas.get(ch.schema_id)
            yield LogMessage(ch.topic, sc.name if sc else "", rec.log_time, rec.publish_time,
                             rec.data)


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
