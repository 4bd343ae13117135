"""MAVLink 2 STATUSTEXT beyond 50 characters: split into chunks, and joined again.

A STATUSTEXT carries at most 50 characters. MAVLink 2 sends a longer text as chunks that
share a non-zero ``id`` with ``chunk_seq`` 0, 1, …; a chunk shorter than 50 characters (an
empty one when the text is a multiple of 50) ends the text. ``id`` 0 is a text on its own.
A receiver that prints each chunk prints words split in two; :class:`Reassembler` gives
whole texts, one per sender.

A text of exactly 50 characters fits one STATUSTEXT without a terminator. Sent with ``id``
0 it is whole at once (what :func:`split`'s callers do). Sent as a chunk (``id`` ≠ 0, as
MAVLink allows), nothing on the wire says whether more follows: the receiver completes it
when no further chunk has come for :data:`CHUNK_TIMEOUT_S` (the caller's clock), rather
than holding it forever.
"""

from __future__ import annotations

from collections.abc import Hashable

__all__ = ["CHUNK_TIMEOUT_S", "MAX_CHUNKS", "TEXT_LEN", "Reassembler", "split"]

TEXT_LEN = 50        # STATUSTEXT.text
MAX_CHUNKS = 8       # longest text kept: 400 characters (the rest is cut, said with "…")
CHUNK_TIMEOUT_S = 1.0   # a text whose last chunk was full, and no chunk since: complete


def split(text: str) -> list[bytes]:
    """``text`` (ASCII, anything else replaced by ``?``) as the chunks to send in order:
    one when it fits, else ≤ :data:`MAX_CHUNKS`, with an empty terminator after a full
    last chunk."""
    data = text.encode("ascii", "replace")
    if len(data) <= TEXT_LEN:
        return [data]
    chunks = [data[i:i + TEXT_LEN] for i in range(0, len(data), TEXT_LEN)][:MAX_CHUNKS]
    if len(chunks[-1]) == TEXT_LEN and len(chunks) < MAX_CHUNKS:
        chunks.append(b"")
    return chunks


class Reassembler:
    """Whole texts from STATUSTEXT chunks, per sender (any hashable key, e.g. the
    (sysid, compid) pair). A chunk of another ``id`` from the same sender, or more than
    :data:`MAX_CHUNKS` chunks, ends the pending text as it is (marked ``…``: its end was
    lost)."""

    def __init__(self) -> None:
        self._pending: dict[Hashable, tuple[int, dict[int, str]]] = {}
        self._last_s: dict[Hashable, float] = {}    # sender → time of its last chunk

    def add(self, sender: Hashable, text: str, text_id: int, chunk_seq: int,
            time_s: float | None = None) -> list[str]:
        """The texts this chunk completes, in order (none while more chunks are due).

        With ``time_s`` (seconds on any clock the caller keeps), pending texts of any sender
        whose last chunk is more than :data:`CHUNK_TIMEOUT_S` older come first
        (:meth:`expire`)."""
        out = self.expire(time_s) if time_s is not None else []
        pending = self._pending.get(sender)
        if pending is not None and pending[0] != text_id:
            out.append(_join(pending[1]) + "…")
            del self._pending[sender]
            pending = None
        if text_id == 0:
            out.append(text)
            return out
        parts = pending[1] if pending is not None else {}
        parts[chunk_seq] = text
        if len(text) < TEXT_LEN or len(parts) >= MAX_CHUNKS:
            self._pending.pop(sender, None)
            out.append(_join(parts) + ("" if len(text) < TEXT_LEN else "…"))
        else:
            self._pending[sender] = (text_id, parts)
            if time_s is not None:
                self._last_s[sender] = time_s
        return out

    def expire(self, time_s: float) -> list[str]:
        """Pending texts whose last chunk (a full one) came more than
        :data:`CHUNK_TIMEOUT_S` before ``time_s``: complete as they are (a text of a
        multiple of 50 characters sent without its empty terminator)."""
        out: list[str] = []
        for sender, last_s in list(self._last_s.items()):
            if time_s - last_s > CHUNK_TIMEOUT_S:
                del self._last_s[sender]
                pending = self._pending.pop(sender, None)
                if pending is not None:
                    out.append(_join(pending[1]))
        return out

    def flush(self) -> list[str]:
        """Texts still waiting for their end (at close: print what arrived)."""
        out = [_join(parts) + "…" for _, parts in self._pending.values()]
        self._pending.clear()
        self._last_s.clear()
        return out


def _join(parts: dict[int, str]) -> str:
    return "".join(parts[k] for k in sorted(parts))
