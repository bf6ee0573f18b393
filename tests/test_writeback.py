"""The disk's writes started as a file grows (`logs/writeback.py`)."""

from __future__ import annotations

import sys

import pytest

from drivee2e_data.logs import writeback
from drivee2e_data.logs.writeback import Writeback


def test_ranges_are_handed_to_the_disk_every_so_many_bytes(tmp_path, monkeypatch):
    ranges = []
    monkeypatch.setattr(writeback, "_START_WRITES",
                        lambda fd, offset, size, flags: ranges.append((offset, size, flags)) or 0)  # fmt: skip
    path = tmp_path / "log"
    with open(path, "wb") as stream:
        stream.write(b"h" * 100)  # written before: not the writeback's
        behind = Writeback(stream, every_bytes=1000)
        for k in range(10):
            stream.write(bytes([k]) * 600)
            behind.written()
    # every second write passes 1000 bytes since the last range
    assert ranges == [(100 + 1200 * k, 1200, writeback.SYNC_FILE_RANGE_WRITE) for k in range(5)]
    assert behind.calls == 5 and behind.started == 6100
    assert path.read_bytes() == b"h" * 100 + b"".join(bytes([k]) * 600 for k in range(10))


def test_a_refusal_turns_it_off_and_the_file_is_written_whole(tmp_path, monkeypatch):
    calls = []
    monkeypatch.setattr(writeback, "_START_WRITES", lambda *args: calls.append(args) or -1)
    path = tmp_path / "log"
    with open(path, "wb") as stream:
        behind = Writeback(stream, every_bytes=10)
        for _ in range(5):
            stream.write(b"x" * 20)
            behind.written()
    assert len(calls) == 1 and not behind.enabled and behind.calls == 0
    assert path.read_bytes() == b"x" * 100


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="sync_file_range is Linux's")
def test_linux_takes_the_call_on_a_real_file(tmp_path):
    with open(tmp_path / "log", "wb") as stream:
        behind = Writeback(stream, every_bytes=4096)
        stream.write(b"y" * 10000)
        behind.written()
    assert behind.enabled and behind.calls == 1 and behind.started == 10000
