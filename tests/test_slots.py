"""Input slots: a worker's arrays to its policy server through shared memory."""

from __future__ import annotations

import numpy as np


def test_a_slot_carries_a_requests_arrays_and_grows_with_them(tmp_path) -> None:
    import gc
    import os

    from drivee2e_data.evaluate.slots import InputSlot, SlotReader

    slot, reader = InputSlot(str(tmp_path), 3), SlotReader()
    rng = np.random.default_rng(1)
    small = {"images": rng.integers(0, 256, (3, 3, 9, 16), dtype=np.uint8),
             "vector": rng.standard_normal(6).astype(np.float32)}  # fmt: skip
    layout = slot.write(small)
    assert layout[0] == str(tmp_path / "worker-3")
    assert [entry[0] for entry in layout[1]] == ["images", "vector"]
    read = reader.read(layout)
    assert all(np.array_equal(read[k], small[k]) and read[k].dtype == small[k].dtype for k in small)
    # the next request's arrays, larger: the file grows and the server maps it again
    large = {"images": rng.integers(0, 256, (3, 3, 36, 64), dtype=np.uint8),
             "vector": rng.standard_normal(6).astype(np.float32)}  # fmt: skip
    read = reader.read(slot.write(large))
    assert all(np.array_equal(read[k], large[k]) for k in large)
    del slot, read
    gc.collect()
    assert not os.path.exists(tmp_path / "worker-3")  # a worker's slot goes with it


def test_a_runs_slot_folder_is_in_memory_and_removed_at_its_end() -> None:
    import os

    from drivee2e_data.evaluate.slots import InputSlot, remove_slots, slot_folder

    folder = slot_folder()
    try:
        if os.access("/dev/shm", os.W_OK):
            assert folder.startswith(f"/dev/shm/drivee2e-policy-{os.getpid()}-")
        InputSlot(folder, 0).write({"x": np.zeros(4, np.float32)})
    finally:
        remove_slots(folder)
    assert not os.path.exists(folder)


def test_the_slots_of_a_command_killed_outright_go_with_the_next_run() -> None:
    import os
    import subprocess
    import sys
    from pathlib import Path

    from drivee2e_data.evaluate.slots import remove_slots, slot_folder

    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    probe = slot_folder()
    root = Path(probe).parent
    remove_slots(probe)
    orphan = root / f"drivee2e-policy-{gone.stdout.strip()}-left"
    living = root / f"drivee2e-policy-{os.getppid()}-kept"  # this process's parent runs
    for folder in (orphan, living):
        folder.mkdir()
        (folder / "worker-0").write_bytes(b"x")
    try:
        remove_slots(slot_folder())
        assert not orphan.exists() and living.exists()
    finally:
        remove_slots(str(orphan))
        remove_slots(str(living))
