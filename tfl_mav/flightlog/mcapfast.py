"""mcap's :class:`~mcap.writer.Writer` with a lean per-message path.

Why: ``Writer.add_message`` builds a ``Message`` dataclass and writes it field by field
through several small Python calls (~9 µs a message here); a flight records
~10-12 messages per 1 ms tick per process, which made the recorder children the slowest
processes of a lockstep flight on 2 cores. Here the chunk in progress is one ``bytearray``
(:class:`_Chunk`, standing in for the library's chunk builder): a message is one
``struct.pack`` of its record header plus the data, appended, and its index entry two ints
on a flat per-channel list; the chunk's and the file's statistics (counts, start and end
times) are summed once per chunk, when it ends. The file is byte-identical to the
library's (tests/system/test_recorder.py checks it). Everything else (schemas, channels, chunk
compression, indexes, summary) is the library's own code, which calls :class:`_Chunk`
exactly as it calls its own builder.

It reaches into the writer's private state (the chunk builder, the statistics); a
library version without it (checked at construction) falls back to ``Writer.add_message``.
"""

from __future__ import annotations

import struct
from typing import Any

import mcap.writer as _mcap_writer
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.writer import Writer

__all__ = ["MESSAGE_FIXED", "MESSAGE_HEADER", "MESSAGE_OPCODE", "FastWriter"]

MESSAGE_OPCODE = _MESSAGE_OPCODE = 0x05
MESSAGE_HEADER = _MESSAGE_HEADER = struct.Struct("<BQHIQQ")  # opcode, record length,
MESSAGE_FIXED = _MESSAGE_FIXED = 2 + 4 + 8 + 8  # channel, sequence, log_time, publish_time
_INDEX_HEADER = struct.Struct("<BQHI")       # opcode, record length, channel, records length


class _MessageIndex:
    """A chunk's message index of one channel from a flat [log_time, offset, ...] list,
    written with one ``struct.pack`` (the library's loop costs as much as the messages)."""

    def __init__(self, channel_id: int, flat: list[int]) -> None:
        self.channel_id = channel_id
        self.flat = flat

    @property
    def records(self) -> list[tuple[int, int]]:
        f = self.flat
        return list(zip(f[0::2], f[1::2], strict=True))

    def write(self, stream: Any) -> None:
        n = len(self.flat)
        stream.write(_INDEX_HEADER.pack(Opcode.MESSAGE_INDEX, 6 + 8 * n, self.channel_id,
                                        8 * n))
        stream.write(struct.pack(f"<{n}Q", *self.flat))


class _Chunk:
    """The chunk in progress: the library's ``ChunkBuilder`` interface over one bytearray.
    ``index``: channel id → flat [log_time, offset, ...] (insertion order = the order of
    each channel's first message, as the library's)."""

    def __init__(self, stats: Any) -> None:
        self.buf = bytearray()
        self.index: dict[int, list[int]] = {}
        self._stats = stats          # the writer's Statistics, brought up to date at end()
        self.message_start_time = 0
        self.message_end_time = 0

    @property
    def count(self) -> int:
        return len(self.buf)

    @property
    def num_messages(self) -> int:
        return sum(len(f) for f in self.index.values()) >> 1

    @property
    def message_indices(self) -> dict[int, _MessageIndex]:
        return {cid: _MessageIndex(cid, f) for cid, f in self.index.items()}

    def _record(self, record: Any) -> None:
        rb = RecordBuilder()
        record.write(rb)
        self.buf += rb.end()

    add_channel = add_schema = _record

    def end(self) -> bytes:
        """The chunk's bytes; first its and the file's statistics, from the index."""
        st = self._stats
        counts = st.channel_message_counts
        start = end = None
        total = 0
        for cid, flat in self.index.items():
            logs = flat[0::2]
            n = len(logs)
            counts[cid] += n
            total += n
            lo, hi = min(logs), max(logs)
            start = lo if start is None or lo < start else start
            end = hi if end is None or hi > end else end
        if total:
            self.message_start_time, self.message_end_time = start, end
            st.message_start_time = (start if st.message_count == 0
                                     else min(start, st.message_start_time))
            st.message_end_time = max(end, st.message_end_time)
            st.message_count += total
        return bytes(self.buf)

    def reset(self) -> None:
        self.buf = bytearray()
        self.index = {}
        self.message_start_time = self.message_end_time = 0


class _Zstd:
    """``zstandard`` as mcap's writer calls it (``zstandard.compress(data)``), at ``level``."""

    def __init__(self, level: int) -> None:
        import zstandard

        self._module = zstandard
        self._compress = zstandard.ZstdCompressor(level=level).compress

    def compress(self, data: bytes, *_a: Any, **_k: Any) -> bytes:
        return self._compress(data)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._module, name)


class FastWriter(Writer):
    """A :class:`~mcap.writer.Writer` (chunked) whose :meth:`add_message` is ~5× cheaper.

    ``zstd_level``: the zstd level of the chunks (None: the library's, 3). Why: the
    recorder's chunks (base64 frames, JSON) compress as well at level 1 as at 3 (18.5 %
    vs 19.0 % of their size, a lockstep flight) in ~60 % of the CPU (bench/
    recorder_replay.py); the library has no setting for it, so the writer's ``zstandard``
    is swapped for one at that level while a chunk is finished."""

    def __init__(self, output: Any, *, chunk_size: int, zstd_level: int | None = None,
                 **kw: Any) -> None:
        super().__init__(output, chunk_size=chunk_size, **kw)
        self._zstd = (_Zstd(zstd_level) if zstd_level is not None
                      and hasattr(_mcap_writer, "zstandard") else None)
        self._limit = chunk_size
        stats = getattr(self, "_Writer__statistics", None)
        library = getattr(Writer, "_Writer__finalize_chunk", None)   # not our override
        finalize = library.__get__(self) if library is not None else None
        self._fast = (stats is not None and finalize is not None
                      and getattr(self, "_Writer__chunk_builder", None) is not None
                      and hasattr(stats, "channel_message_counts"))
        if self._fast:
            self._chunk = _Chunk(stats)
            self._Writer__chunk_builder = self._chunk
        self._library_finalize = finalize

    @property
    def chunk(self) -> _Chunk:
        """The chunk in progress, for a caller that appends records itself as
        :meth:`add_pair` does (``buf``, ``index``; only when ``_fast``): past
        :attr:`chunk_limit` bytes it calls :meth:`end_chunk`, then re-reads ``buf`` and
        ``index`` (a new chunk)."""
        return self._chunk

    @property
    def chunk_limit(self) -> int:
        return self._limit

    def end_chunk(self) -> None:
        """Finish the chunk in progress (compressed, indexed, written)."""
        self._finalize()

    def _finalize(self) -> None:
        """Finish the chunk in progress (the library's code, at ``zstd_level``)."""
        if self._library_finalize is None:
            return
        if self._zstd is None:
            self._library_finalize()
            return
        module = _mcap_writer.zstandard
        _mcap_writer.zstandard = self._zstd
        try:
            self._library_finalize()
        finally:
            _mcap_writer.zstandard = module

    # every chunk the library finishes itself (flush, finish, a full chunk of channels)
    _Writer__finalize_chunk = _finalize

    def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int,
                    sequence: int = 0) -> None:
        """What ``Writer.add_message`` does, byte for byte."""
        if not self._fast:
            super().add_message(channel_id, log_time, data, publish_time, sequence)
            return
        ch = self._chunk
        buf = ch.buf
        flat = ch.index.get(channel_id)
        if flat is None:
            flat = ch.index[channel_id] = []
        flat += (log_time, len(buf))
        buf += _MESSAGE_HEADER.pack(_MESSAGE_OPCODE, _MESSAGE_FIXED + len(data), channel_id,
                                    sequence, log_time, publish_time)
        buf += data
        if len(buf) > self._limit:
            self._finalize()

    def add_same_time(self, items: Any, log_time: int, publish_time: int) -> None:
        """(channel id, data) messages with the same times (e.g. the three truth records),
        as as many :meth:`add_message` calls (a chunk may end between them)."""
        if not self._fast:
            for cid, data in items:
                super().add_message(cid, log_time, data, publish_time, 0)
            return
        ch = self._chunk
        index = ch.index
        buf = ch.buf
        for cid, data in items:
            flat = index.get(cid)
            if flat is None:
                flat = index[cid] = []
            flat += (log_time, len(buf))
            buf += _MESSAGE_HEADER.pack(_MESSAGE_OPCODE, _MESSAGE_FIXED + len(data), cid, 0,
                                        log_time, publish_time)
            buf += data
            if len(buf) > self._limit:
                self._finalize()
                index = ch.index
                buf = ch.buf

    def add_pair(self, cid_a: int, data_a: bytes, cid_b: int, data_b: bytes, log_time: int,
                 publish_time: int) -> None:
        """Two messages with the same times (a frame's raw and decoded records), as two
        :meth:`add_message` calls (a chunk may end between them)."""
        if not self._fast:
            super().add_message(cid_a, log_time, data_a, publish_time, 0)
            super().add_message(cid_b, log_time, data_b, publish_time, 0)
            return
        ch = self._chunk
        buf = ch.buf
        index = ch.index
        flat = index.get(cid_a)
        if flat is None:
            flat = index[cid_a] = []
        flat += (log_time, len(buf))
        buf += _MESSAGE_HEADER.pack(_MESSAGE_OPCODE, _MESSAGE_FIXED + len(data_a), cid_a, 0,
                                    log_time, publish_time)
        buf += data_a
        if len(buf) > self._limit:
            self._finalize()
            ch = self._chunk
            buf = ch.buf
            index = ch.index
        flat = index.get(cid_b)
        if flat is None:
            flat = index[cid_b] = []
        flat += (log_time, len(buf))
        buf += _MESSAGE_HEADER.pack(_MESSAGE_OPCODE, _MESSAGE_FIXED + len(data_b), cid_b, 0,
                                    log_time, publish_time)
        buf += data_b
        if len(buf) > self._limit:
            self._finalize()
