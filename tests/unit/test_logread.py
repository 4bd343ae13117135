"""LogReader on a finished file (through its summary) gives what the mcap library's own
readers give: the same messages, in the same order; a damaged file is streamed to the damage.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader

from tfl_mav.flightlog.logread import LogReader
from tfl_mav.flightlog.recorder import Recorder


@pytest.fixture(scope="module")
def log_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A recorder's file of many small chunks: truth, controller records and logs."""
    path = tmp_path_factory.mktemp("logread") / "run.mcap"
    with Recorder(path, clock=lambda: 1_700_000_000.0, chunk_size_bytes=2048) as rec:
        for k in range(3000):
            t = k * 0.001
            rec.truth(t, [math.cos(t), math.sin(t), 1.0], [0.0, 0.1, 0.0],
                      [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [2.7, 1.0, 2.7, 2.7], 2, 1.0,
                      1.0)
            rec.controller(t, {"mode": "attacked", "detected_rotor": 2, "x": k})
            if k % 500 == 0:
                rec.log("info", f"tick {k}", t)
    return path


def _library(path: Path, topics: set[str] | None = None) -> list[tuple[str, int, int, bytes]]:
    with open(path, "rb") as f:
        return [(c.topic, m.log_time, m.publish_time, m.data)
                for _s, c, m in make_reader(f).iter_messages(log_time_order=False)
                if topics is None or c.topic in topics]


def _ours(path: Path, topics: set[str] | None = None) -> tuple[list[tuple[str, int, int,
                                                                         bytes]], LogReader]:
    reader = LogReader(path)
    return [(m.topic, m.log_time_ns, m.publish_time_ns, m.data)
            for m in reader.messages(topics)], reader


@pytest.mark.parametrize("topics", [None, {"/controller/state"}, {"/log", "/sim/truth/state"}])
def test_a_finished_file_reads_as_the_library_reads_it(log_file: Path, topics) -> None:
    ours, reader = _ours(log_file, topics)
    assert ours == _library(log_file, topics) and len(ours) > 100
    assert reader.complete and reader.error is None
    assert {md.name for md in reader.metadata} >= {"tfl-mav"}
    assert reader.channels and reader.schemas
    if topics is None:
        assert ours[0][0] == "/sim/truth/state"
        assert any(m[0] == "/sim/truth/state" for m in ours[1:])


def test_a_damaged_file_is_streamed_to_the_damage(log_file: Path, tmp_path: Path) -> None:
    data = log_file.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[:len(data) // 2])
    ours, reader = _ours(cut)
    assert not reader.complete and reader.error is not None
    with open(cut, "rb") as f:        # the library's stream reader, up to the same record
        streamed = []
        try:
            for rec in StreamReader(f, validate_crcs=True).records:
                if type(rec).__name__ == "Message":
                    streamed.append(rec.data)
        except Exception:
            pass
    assert [m[3] for m in ours] == streamed and 100 < len(ours) < len(_library(log_file))


def test_a_bad_chunk_in_a_finished_file_ends_the_read_and_says_why(log_file: Path,
                                                                   tmp_path: Path) -> None:
    with open(log_file, "rb") as f:
        index = sorted(make_reader(f).get_summary().chunk_indexes,
                       key=lambda c: c.chunk_start_offset)[3]
    data = bytearray(log_file.read_bytes())
    at = index.chunk_start_offset + index.chunk_length - 10      # inside the 4th chunk
    data[at] ^= 0xFF
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    ours, reader = _ours(bad)
    assert reader.error is not None and not reader.complete
    assert 0 < len(ours) < len(_library(log_file))
