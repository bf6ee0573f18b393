"""A worker's inputs to its policy server through shared memory: each worker writes its
observation's arrays into a slot of its own (a file in a run folder under /dev/shm, mapped by
the worker and by the server) and sends the server their layout, a few hundred bytes, instead
of the arrays pickled through a pipe (TCP's three images: 330 kB a step)."""

from __future__ import annotations

import mmap
import os
import shutil
import tempfile
from multiprocessing import util
from pathlib import Path

import numpy as np

from drivee2e_data.processes import process_running

# A request's inputs in a slot: the slot's path, then (key, dtype, shape, byte offset) per array
Layout = tuple[str, tuple[tuple[str, str, tuple[int, ...], int], ...]]
SLOT_ALIGN = 64  # bytes: each array starts on a cache line
SLOT_PREFIX = "drivee2e-policy-"  # then the command's process id


def slot_folder() -> str:
    """A new folder for a run's input slots: under /dev/shm (memory) where there is one, else in
    the temporary folder, named after this process. `remove_slots` removes it when the run
    ends; the folders of commands killed outright (their process gone) go here."""
    root = "/dev/shm" if os.access("/dev/shm", os.W_OK) else tempfile.gettempdir()
    for orphan in Path(root).glob(f"{SLOT_PREFIX}*"):
        owner = orphan.name[len(SLOT_PREFIX) :].split("-")[0]
        if owner.isdigit() and not process_running(int(owner)):
            shutil.rmtree(orphan, ignore_errors=True)
    return tempfile.mkdtemp(prefix=f"{SLOT_PREFIX}{os.getpid()}-", dir=root)


def remove_slots(folder: str) -> None:
    if folder:
        shutil.rmtree(folder, ignore_errors=True)


class InputSlot:
    """One worker's inputs as bytes in a file of `folder` mapped into memory, which the server
    maps too (`SlotReader`): `write` copies the arrays in and returns their layout, the request
    sent instead of the arrays. The worker writes again only after the server's answer, so the
    server reads a slot that nothing is writing. The file goes with the worker's exit."""

    def __init__(self, folder: str, worker: int) -> None:
        self.path = os.path.join(folder, f"worker-{worker}")
        self._map: mmap.mmap | None = None
        util.Finalize(self, _remove_file, (self.path,), exitpriority=10)

    def write(self, inputs: dict[str, np.ndarray]) -> Layout:
        arrays = {key: np.ascontiguousarray(value) for key, value in inputs.items()}
        entries, size = [], 0
        for key, array in arrays.items():
            entries.append((key, array.dtype.str, tuple(array.shape), size))
            size += -(-array.nbytes // SLOT_ALIGN) * SLOT_ALIGN
        if self._map is None or len(self._map) < size:
            self._open(size)
        assert self._map is not None
        for (_, _, _, offset), array in zip(entries, arrays.values(), strict=True):
            self._map[offset : offset + array.nbytes] = array.reshape(-1).view(np.uint8).data
        return self.path, tuple(entries)

    def _open(self, size: int) -> None:
        if self._map is not None:
            self._map.close()
        descriptor = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o600)
        try:
            os.ftruncate(descriptor, size)
            # the pages taken now: a full /dev/shm (a container's is 64 MB) is then an OSError
            # here, where writing into a mapping of pages it cannot give would kill the worker
            # (SIGBUS)
            os.posix_fallocate(descriptor, 0, size)
            self._map = mmap.mmap(descriptor, size)
        finally:
            os.close(descriptor)


def _remove_file(path: str) -> None:
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass


class SlotReader:
    """The server's side of the slots: each worker's file mapped once (again where it grew)."""

    def __init__(self) -> None:
        self._maps: dict[str, mmap.mmap] = {}

    def read(self, layout: Layout) -> dict[str, np.ndarray]:
        """The arrays of one request, as views of the worker's slot (copy them before
        answering it)."""
        path, entries = layout
        end = max(offset + np.dtype(dtype).itemsize * int(np.prod(shape))
                  for _, dtype, shape, offset in entries)  # fmt: skip
        mapped = self._maps.get(path)
        if mapped is None or len(mapped) < end:  # the old map closes with its last view
            with open(path, "rb") as file:
                mapped = self._maps[path] = mmap.mmap(file.fileno(), 0, access=mmap.ACCESS_READ)
        return {
            key: np.frombuffer(mapped, dtype, int(np.prod(shape)), offset).reshape(shape)
            for key, dtype, shape, offset in entries
        }
