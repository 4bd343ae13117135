"""mcap's :class:`~mcap.writer.Writer` with a lean per-message path.

Why: ``Writer.add_message`` builds a ``Message`` dataclass and writes it field by field
through several small Python calls (~9 µs a message here, issue #13); a flight records
~20 messages per 1 ms tick per process, which made the recorder children the slowest
processes of a lockstep flight on 2 cores. :meth:`FastWriter.add_message` writes the very
same bytes (one ``struct.pack`` of the record header, then the data) into the writer's
chunk, and keeps the same statistics and message indexes, so the file is byte-identical to
the library's (tests/test_recorder.py checks it). Everything else (schemas, channels,
chunk compression, indexes, summary) is the library's own code.

It reaches into the writer's private state (the chunk builder, the statistics); a
library version without it (checked at construction) falls back to ``Writer.add_message``.
"""

from __future__ import annotations

import struct
from itertools import chain
from typing import Any

from mcap.opcode import Opcode
from mcap.records import MessageIndex
from mcap.writer import Writer

__all__ = ["FastWriter"]

_MESSAGE_OPCODE = 0x05
_MESSAGE_HEADER = struct.Struct("<BQHIQQ")   # opcode, record length, channel, sequence,
_MESSAGE_FIXED = 2 + 4 + 8 + 8               # log_time, publish_time; then the data


class _MessageIndex(MessageIndex):
    """A chunk's message index written with one ``struct.pack`` instead of two calls per
    message (the library's loop costs as much as writing the message)."""

    def write(self, stream: Any) -> None:
        records = self.records
        stream.start_record(Opcode.MESSAGE_INDEX)
        stream.write2(self.channel_id)
        stream.write4(len(records) * 16)
        stream.write(struct.pack(f"<{2 * len(records)}Q", *chain.from_iterable(records)))
        stream.finish_record()


class FastWriter(Writer):
    """A :class:`~mcap.writer.Writer` (chunked) whose :meth:`add_message` is ~5× cheaper."""

    def __init__(self, output: Any, *, chunk_size: int, **kw: Any) -> None:
        super().__init__(output, chunk_size=chunk_size, **kw)
        self._limit = chunk_size
        stats = getattr(self, "_Writer__statistics", None)
        builder = getattr(self, "_Writer__chunk_builder", None)
        buffer = getattr(getattr(builder, "record_writer", None), "_buffer", None)
        finalize = getattr(self, "_Writer__finalize_chunk", None)
        self._fast = (stats is not None and builder is not None and finalize is not None
                      and hasattr(buffer, "write") and hasattr(builder, "message_indices"))
        if self._fast:
            self._stats = stats
            self._builder = builder
            self._finalize = finalize

    def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int,
                    sequence: int = 0) -> None:
        """What ``Writer.add_message`` does, byte for byte."""
        if not self._fast:
            super().add_message(channel_id, log_time, data, publish_time, sequence)
            return
        st = self._stats
        if st.message_count == 0 or log_time < st.message_start_time:
            st.message_start_time = log_time
        if log_time > st.message_end_time:
            st.message_end_time = log_time
        st.channel_message_counts[channel_id] += 1
        st.message_count += 1
        cb = self._builder
        if cb.num_messages == 0 or log_time < cb.message_start_time:
            cb.message_start_time = log_time
        if log_time > cb.message_end_time:
            cb.message_end_time = log_time
        buf = cb.record_writer._buffer       # replaced at every chunk end: look it up
        offset = buf.tell()
        index = cb.message_indices.get(channel_id)
        if index is None:
            index = cb.message_indices[channel_id] = _MessageIndex(channel_id=channel_id,
                                                                   records=[])
        index.records.append((log_time, offset))
        cb.num_messages += 1
        buf.write(_MESSAGE_HEADER.pack(_MESSAGE_OPCODE, _MESSAGE_FIXED + len(data), channel_id,
                                       sequence, log_time, publish_time))
        buf.write(data)
        if buf.tell() > self._limit:
            self._finalize()
