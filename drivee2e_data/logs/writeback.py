"""A growing file's bytes sent to the disk as they come, so that the fsync that makes it durable
waits only on its last ones.

A log or a log's head is written for tens of seconds and fsynced once, at its end (segment
files, copied into their log and deleted within seconds, are never flushed). The kernel
keeps what was written in memory until then (on a host with a lot of memory, its background
writeback starts only past a share of it, gigabytes), so every worker of a pool that ends at
once waits on its whole file: the run's end waited on the disk for all of them together.
`Writeback.written` starts the disk's writes (Linux's `sync_file_range` with
`SYNC_FILE_RANGE_WRITE`: queued, not waited on) each time `EVERY_BYTES` more have been written.
Where the call is missing (not Linux) or the file system refuses it, it does nothing: the
closing fsync is still what makes the file durable.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys
from collections.abc import Callable
from typing import BinaryIO

# about a frame's bytes (1.1-1.5 MB at 10 Hz): a call a frame or so, each a few microseconds
EVERY_BYTES = 4 << 20
SYNC_FILE_RANGE_WRITE = 2  # linux/fs.h: start writing the range's dirty pages, do not wait


def _sync_file_range() -> Callable[[int, int, int, int], int] | None:
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
        function = libc.sync_file_range
    except (OSError, AttributeError):
        return None
    function.argtypes = (ctypes.c_int, ctypes.c_int64, ctypes.c_int64, ctypes.c_uint)
    function.restype = ctypes.c_int
    return function


_START_WRITES = _sync_file_range()


class Writeback:
    """Starts the disk's writes of `stream`'s bytes as they grow (`written`, after each write or
    group of writes); `stream` is a file opened for writing, its position its end."""

    def __init__(self, stream: BinaryIO, every_bytes: int | None = None) -> None:
        self.stream = stream
        self.every_bytes = EVERY_BYTES if every_bytes is None else every_bytes
        self.started = stream.tell()  # bytes before this are the disk's already, or were there
        self.enabled = _START_WRITES is not None
        self.calls = 0  # ranges handed to the disk (tests read it)

    def written(self) -> None:
        """Hand the disk what was written since the last call that did, once that is
        `every_bytes` or more."""
        if not self.enabled:
            return
        end = self.stream.tell()
        if end - self.started < self.every_bytes:
            return
        self.stream.flush()  # out of Python's buffer into the kernel's
        if _START_WRITES(self.stream.fileno(), self.started, end - self.started,
                         SYNC_FILE_RANGE_WRITE) != 0:  # fmt: skip
            self.enabled = False  # a file system without it: all left to the closing fsync
            return
        self.started = end
        self.calls += 1
