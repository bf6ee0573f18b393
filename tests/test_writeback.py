"""The disk's writes started as a file grows (`logs/writeback.py`)."""

from __future__ import annotations

import itertools
import sys

import pytest
from conftest import SMALL_COLLECT, copy_clips

from drivee2e_data import store
from drivee2e_data.cli import main
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


def test_a_collected_log_hands_its_bytes_to_the_disk_as_it_grows(
    synthetic_root, collected_root, tmp_path, monkeypatch
):
    """The collector's log (here written in this process: one worker) starts the disk's writes
    of each frame's bytes as they come, and its bytes are the same as without."""
    handed = []
    monkeypatch.setattr(writeback, "_START_WRITES",
                        lambda fd, offset, size, flags: handed.append((offset, size)) or 0)  # fmt: skip
    monkeypatch.setattr(writeback, "EVERY_BYTES", 1)  # after every frame
    scenario_id = store.scenario_ids(synthetic_root)[1]  # collected_root holds it, 6 frames
    root = copy_clips(synthetic_root, tmp_path / "data", [scenario_id])
    arguments = ["collect", str(root), "--only", scenario_id, "--max-frames", "6"]
    assert main([*arguments, *SMALL_COLLECT]) == 0
    log = (root / "logs" / f"{scenario_id}.mcap").read_bytes()
    assert log == (collected_root / "logs" / f"{scenario_id}.mcap").read_bytes()
    # one range a frame, each beginning where the one before ended, all within the data section
    assert len(handed) == 6
    assert all(a + n == b for (a, n), (b, _) in itertools.pairwise(handed))
    assert 0 < handed[0][0] and handed[-1][0] + handed[-1][1] < len(log)
