"""A headless OpenGL context made through EGL here rather than by glcontext, for what glcontext
cannot ask for: the context's scheduling priority on its GPU (EGL_IMG_context_priority).

Where closed-loop workers draw on the GPU that their policy server's network runs on, the GPU
shares its time between sixteen or more GL contexts and one CUDA context; a worker's step waits
for the network, so the workers' contexts yield to it: made at low priority, the network's
batches wait less and so does every step (docs/benchmarks.md, closed loop). A driver without
the extension (Mesa's llvmpipe) gives a context of its one priority; either way the pixels are
the same, only their turn on the GPU changes.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import os
from enum import Enum
from typing import Any

from drivee2e_data.errors import DriveE2EError
from drivee2e_data.sim.egl_devices import DEVICE_VARIABLE, EGL_EXTENSIONS, devices

PRIORITY_VARIABLE = "DRIVEE2E_GL_PRIORITY"

EGL_NONE = 0x3038
EGL_DRAW, EGL_READ = 0x3059, 0x305A
EGL_PLATFORM_DEVICE_EXT = 0x313F
EGL_SURFACE_TYPE, EGL_PBUFFER_BIT = 0x3033, 0x0001
EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT = 0x3040, 0x0008
EGL_WIDTH, EGL_HEIGHT = 0x3057, 0x3056
EGL_OPENGL_API = 0x30A2
EGL_CONTEXT_MAJOR_VERSION, EGL_CONTEXT_MINOR_VERSION = 0x3098, 0x30FB
EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT = 0x30FD, 0x1
PRIORITY_EXTENSION = "EGL_IMG_context_priority"
EGL_CONTEXT_PRIORITY_LEVEL_IMG = 0x3100


class Priority(Enum):
    """A GL context's priority on its GPU (the extension's three levels; medium is a context's
    own where none is asked for)."""

    HIGH = "high"
    MEDIUM = "medium"
    LOW = "low"

    @property
    def egl_value(self) -> int:
        return {Priority.HIGH: 0x3101, Priority.MEDIUM: 0x3102, Priority.LOW: 0x3103}[self]


def requested_priority() -> Priority | None:
    """The priority this process's GL context is to have (`PRIORITY_VARIABLE`), or None: the
    context glcontext makes."""
    value = os.environ.get(PRIORITY_VARIABLE, "")
    if not value:
        return None
    try:
        return Priority(value.lower())
    except ValueError:
        names = ", ".join(level.value for level in Priority)
        raise DriveE2EError(f"{PRIORITY_VARIABLE}={value!r}: expected one of {names}") from None


def use_priority(priority: Priority) -> None:
    """Make this process's GL context at `priority` (call before it renders), unless the user
    asked for one (`PRIORITY_VARIABLE`)."""
    os.environ.setdefault(PRIORITY_VARIABLE, priority.value)


def _function(library: Any, name: str, result: Any, *arguments: Any) -> Any:
    function = getattr(library, name)
    function.restype, function.argtypes = result, list(arguments)
    return function


def current_egl(egl: Any) -> tuple[Any, Any, Any, Any]:
    """What is current in this thread: (display, draw surface, read surface, context), as
    `eglMakeCurrent` takes them back; the display None where nothing is."""
    return (egl.eglGetCurrentDisplay(), egl.eglGetCurrentSurface(EGL_DRAW),
            egl.eglGetCurrentSurface(EGL_READ), egl.eglGetCurrentContext())  # fmt: skip


class _Loader:
    """What moderngl asks of a context it did not make: GL's functions, and making the context
    current for a block (and what was current before, again after it) and releasing it."""

    def __init__(self, egl: Any, display: int, surface: int, context: int) -> None:
        self.egl, self.display, self.surface, self.context = egl, display, surface, context
        self.saved: list[tuple[Any, ...]] = []

    def load_opengl_function(self, name: str) -> int:
        return self.egl.eglGetProcAddress(name.encode()) or 0

    def __enter__(self) -> None:
        self.saved.append(current_egl(self.egl))
        self.egl.eglMakeCurrent(self.display, self.surface, self.surface, self.context)

    def __exit__(self, *exception: object) -> None:
        display, draw, read, context = self.saved.pop()
        if display:
            self.egl.eglMakeCurrent(display, draw, read, context)

    def release(self) -> None:
        self.egl.eglDestroySurface(self.display, self.surface)
        self.egl.eglDestroyContext(self.display, self.context)


@functools.cache
def libegl() -> Any:
    """libEGL through ctypes with the functions this project calls typed (to make, save and
    restore contexts), or None where there is none."""
    name = ctypes.util.find_library("EGL")
    if name is None:
        return None
    egl = ctypes.CDLL(name)
    pointer, handle, integer = ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int
    _function(egl, "eglGetProcAddress", pointer, ctypes.c_char_p)
    _function(egl, "eglInitialize", ctypes.c_uint, handle, pointer, pointer)
    _function(egl, "eglQueryString", ctypes.c_char_p, handle, integer)
    _function(egl, "eglChooseConfig", ctypes.c_uint, handle, pointer,
              ctypes.POINTER(handle), integer, ctypes.POINTER(integer))  # fmt: skip
    _function(egl, "eglCreatePbufferSurface", handle, handle, handle, pointer)
    _function(egl, "eglBindAPI", ctypes.c_uint, ctypes.c_uint)
    _function(egl, "eglCreateContext", handle, handle, handle, handle, pointer)
    _function(egl, "eglQueryContext", ctypes.c_uint, handle, handle, integer,
              ctypes.POINTER(integer))  # fmt: skip
    _function(egl, "eglMakeCurrent", ctypes.c_uint, handle, handle, handle, handle)
    _function(egl, "eglGetCurrentDisplay", handle)
    _function(egl, "eglGetCurrentSurface", handle, integer)
    _function(egl, "eglGetCurrentContext", handle)
    _function(egl, "eglDestroySurface", ctypes.c_uint, handle, handle)
    _function(egl, "eglDestroyContext", ctypes.c_uint, handle, handle)
    _function(egl, "eglTerminate", ctypes.c_uint, handle)
    return egl


def _device_display(egl: Any, index: int) -> int:
    """The EGL display of device `index` (in `eglQueryDevicesEXT`'s order), initialised."""
    found = devices(egl)
    display_address = egl.eglGetProcAddress(b"eglGetPlatformDisplayEXT")
    if not display_address:
        raise OSError("EGL has no platform displays (EGL_EXT_platform_base)")
    if not 0 <= index < len(found):
        raise OSError(f"no EGL device {index} (found {len(found)})")
    platform_display = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.c_uint, ctypes.c_void_p,
                                        ctypes.c_void_p)(display_address)  # fmt: skip
    display = platform_display(EGL_PLATFORM_DEVICE_EXT, found[index], None)
    if not display or not egl.eglInitialize(display, None, None):
        raise OSError(f"EGL device {index}: no display")
    return display


def _priority_context(
    egl: Any, display: int, config: Any, priority: Priority | None
) -> tuple[int, Priority | None]:
    """An OpenGL 3.3 core context of `display` at `priority` (None: the driver's own), and the
    priority it was given; where the driver refuses the priority (a level it keeps for a
    privileged process, say), a context of its own priority rather than none."""
    base = [EGL_CONTEXT_MAJOR_VERSION, 3, EGL_CONTEXT_MINOR_VERSION, 3,
            EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT]  # fmt: skip
    if priority is not None:
        attributes = [*base, EGL_CONTEXT_PRIORITY_LEVEL_IMG, priority.egl_value, EGL_NONE]
        context = egl.eglCreateContext(display, config, None,
                                       (ctypes.c_int * len(attributes))(*attributes))  # fmt: skip
        if context:
            level = ctypes.c_int(0)
            egl.eglQueryContext(display, context, EGL_CONTEXT_PRIORITY_LEVEL_IMG,
                                ctypes.byref(level))  # fmt: skip
            return context, next((p for p in Priority if p.egl_value == level.value), None)
    attributes = [*base, EGL_NONE]
    context = egl.eglCreateContext(display, config, None,
                                   (ctypes.c_int * len(attributes))(*attributes))  # fmt: skip
    return context, None


def create(priority: Priority, device: int | None = None) -> tuple[Any, Priority | None]:
    """A moderngl context (OpenGL 3.3 core, a 1x1 pbuffer as its surface) on EGL device
    `device` (default: `DEVICE_VARIABLE`, else 0) at `priority` where the driver offers it;
    with the priority the driver gave it (None where it offers none)."""
    import moderngl

    if device is None:
        device = int(os.environ.get(DEVICE_VARIABLE, "0"))
    egl = libegl()
    if egl is None:
        raise OSError("no libEGL")
    display = _device_display(egl, device)
    extensions = (egl.eglQueryString(display, EGL_EXTENSIONS) or b"").decode().split()
    offered = PRIORITY_EXTENSION in extensions
    wanted = (ctypes.c_int * 5)(EGL_SURFACE_TYPE, EGL_PBUFFER_BIT, EGL_RENDERABLE_TYPE,
                                EGL_OPENGL_BIT, EGL_NONE)  # fmt: skip
    config, found = ctypes.c_void_p(), ctypes.c_int(0)
    chosen = egl.eglChooseConfig(display, wanted, ctypes.byref(config), 1, ctypes.byref(found))
    if not chosen or not found.value:
        raise OSError(f"EGL device {device}: no configuration for an OpenGL pbuffer")
    surface = egl.eglCreatePbufferSurface(display, config,
                                          (ctypes.c_int * 5)(EGL_WIDTH, 1, EGL_HEIGHT, 1, EGL_NONE))  # fmt: skip
    egl.eglBindAPI(EGL_OPENGL_API)
    context, given = _priority_context(egl, display, config, priority if offered else None)
    if not surface or not context:
        raise OSError(f"EGL device {device}: no OpenGL 3.3 context")
    loader = _Loader(egl, display, surface, context)
    with loader:
        moderngl.init_context(loader)
        made = moderngl.get_context()
    return made, given
