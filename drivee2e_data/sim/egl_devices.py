"""Which EGL devices are GPUs, and choosing the one a process's GL context is made on.

EGL lists every device its vendors offer (`eglQueryDevicesEXT`): one per NVIDIA GPU, and Mesa's
software rasteriser (llvmpipe) where Mesa is installed. The GL renderer's context is made on
device 0 unless `GLCONTEXT_DEVICE_INDEX` names another (glcontext reads it when the context is
made), so a collector worker sets it once, before it renders, to spread a pool over the GPUs.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import os

from drivee2e_data.sim import mesa

DEVICE_VARIABLE = "GLCONTEXT_DEVICE_INDEX"  # read by glcontext's EGL backend
EGL_EXTENSIONS = 0x3055
SOFTWARE_EXTENSION = "EGL_MESA_device_software"  # Mesa's llvmpipe device


def devices(library) -> list[int]:
    """The EGL device handles of `library` (libEGL through ctypes, its `eglGetProcAddress`
    returning a pointer), in `eglQueryDevicesEXT`'s order, as glcontext counts them; [] where
    EGL has no device enumeration."""
    library.eglGetProcAddress.restype = ctypes.c_void_p
    library.eglGetProcAddress.argtypes = [ctypes.c_char_p]
    query_address = library.eglGetProcAddress(b"eglQueryDevicesEXT")
    if not query_address:
        return []
    query = ctypes.CFUNCTYPE(
        ctypes.c_uint, ctypes.c_int, ctypes.POINTER(ctypes.c_void_p), ctypes.POINTER(ctypes.c_int)
    )(query_address)
    count = ctypes.c_int(0)
    if not query(0, None, ctypes.byref(count)) or count.value <= 0:
        return []
    handles = (ctypes.c_void_p * count.value)()
    if not query(count.value, handles, ctypes.byref(count)):
        return []
    return list(handles[: count.value])


@functools.cache
def gpu_devices() -> tuple[int, ...]:
    """Indices (in `eglQueryDevicesEXT` order, as glcontext counts) of the EGL devices that are
    not a software rasteriser; () where EGL or its device extension is missing."""
    mesa.activate()  # EGL's vendors are read once, at the first call: the same as the renderer's
    name = ctypes.util.find_library("EGL")
    if name is None:
        return ()
    try:
        library = ctypes.CDLL(name)
    except OSError:
        return ()
    found_devices = devices(library)
    string_address = library.eglGetProcAddress(b"eglQueryDeviceStringEXT")
    if not found_devices or not string_address:
        return ()
    device_string = ctypes.CFUNCTYPE(ctypes.c_char_p, ctypes.c_void_p, ctypes.c_int)(string_address)
    found = []
    for index, device in enumerate(found_devices):
        extensions = (device_string(device, EGL_EXTENSIONS) or b"").decode()
        if SOFTWARE_EXTENSION not in extensions.split():
            found.append(index)
    return tuple(found)


def parse_gpus(text: str) -> tuple[int, ...] | None:
    """`--gpus`: "all" (None: every GPU device found) or comma-separated EGL device indices."""
    if text == "all":
        return None
    try:
        indices = tuple(int(part) for part in text.split(","))
    except ValueError:
        raise ValueError(f"--gpus {text!r}: expected 'all' or device indices like 0,1") from None
    if not indices or min(indices) < 0 or len(set(indices)) != len(indices):
        raise ValueError(f"--gpus {text!r}: expected distinct device indices >= 0")
    return indices


def device_for_worker(worker: int, devices: tuple[int, ...]) -> int | None:
    """The device of the `worker`-th worker (from 0): the devices round robin; None without."""
    if not devices:
        return None
    return devices[worker % len(devices)]


def use_device(device: int | None) -> None:
    """Make this process's GL context on `device` (call before it renders; None: the default)."""
    if device is not None:
        os.environ[DEVICE_VARIABLE] = str(device)


# GL contexts made at once per GPU as a pool starts (the collector's and the evaluator's).
# NVIDIA's driver makes them through a step that takes one at a time: 32 workers making theirs
# together all waited about 1.7 s and were ready together (an H100 host's two GPUs; one alone
# takes 0.2 s), where a few at a time have the first ready in a fraction of that to start on
# their jobs (docs/benchmarks.md, twentieth session; `scripts/dev/bench_context_exit.py
# --at-once K`); 40 evaluation workers on four H200 took 4.5 s each, 16 took 2.2
CONTEXTS_AT_ONCE_PER_GPU = 4


def contexts_at_once(gpus: tuple[int, ...]) -> int:
    """How many pool workers make their GL context at the same time (`CONTEXTS_AT_ONCE_PER_GPU`
    for each of `gpus`, the default device counting as one)."""
    return CONTEXTS_AT_ONCE_PER_GPU * max(1, len(gpus))
