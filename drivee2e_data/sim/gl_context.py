"""The process's one OpenGL context (EGL, headless): made on first use (`context`), made current
around a renderer's calls (`current`), asked what draws (`gl_driver`, `rasterises_on_cpu`) and
given back to the driver (`release_context`), with what was made in it and kept for it (the
shaders' programs, `gl_programs`), which registers to be forgotten with it
(`forget_with_context`).
"""

from __future__ import annotations

import ctypes
import functools
import logging
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from drivee2e_data.sim import egl_context, mesa

LOG = logging.getLogger(__name__)
# what is kept for the context and goes with it (`forget_with_context`)
_FORGOTTEN_WITH_IT: list[Callable[[], None]] = []


def forget_with_context(forget: Callable[[], None]) -> None:
    """Call `forget` when the context is released (`release_context`): for what was made in it
    and kept for it, which a new context cannot use."""
    _FORGOTTEN_WITH_IT.append(forget)


@functools.cache
def context():
    """The process's OpenGL context (EGL, headless), made on first use, at the priority asked
    for (`egl_context.requested_priority`; else glcontext's); None where none can be made (no
    moderngl, no EGL driver)."""
    priority = egl_context.requested_priority()  # a bad value is the user's error, not "no GL"
    try:
        import moderngl

        mesa.activate()  # a newer Mesa where one was fetched, before EGL's first call
        with current(None):
            if priority is not None:
                made, given = egl_context.create(priority)
                LOG.debug("GL context at priority %s (asked %s)", given, priority)
                return made
            return moderngl.create_standalone_context(backend="egl")
    except Exception as error:  # any failure means: no GL here
        LOG.debug("no OpenGL context: %s", error)
        return None


GL_READ_FRAMEBUFFER, GL_DRAW_FRAMEBUFFER = 0x8CA8, 0x8CA9
GL_DEPTH_BUFFER_BIT, GL_NEAREST = 0x100, 0x2600


@functools.cache
def depth_copy() -> Callable[[object, object, int], None] | None:
    """A function copying the depth of one moderngl framebuffer into another's (both square, of
    the size given) with glBlitFramebuffer, fetched through EGL (moderngl's copies take colour
    only); None where EGL does not give it. The target is left bound."""
    egl = egl_context.libegl()
    if egl is None:
        return None
    blit_address = egl.eglGetProcAddress(b"glBlitFramebuffer")
    bind_address = egl.eglGetProcAddress(b"glBindFramebuffer")
    if not blit_address or not bind_address:
        return None
    blit = ctypes.CFUNCTYPE(None, *[ctypes.c_int] * 8, ctypes.c_uint, ctypes.c_uint)(blit_address)
    bind = ctypes.CFUNCTYPE(None, ctypes.c_uint, ctypes.c_uint)(bind_address)

    def copy(source, target, size: int) -> None:
        bind(GL_READ_FRAMEBUFFER, source.glo)
        bind(GL_DRAW_FRAMEBUFFER, target.glo)
        blit(0, 0, size, size, 0, 0, size, size, GL_DEPTH_BUFFER_BIT, GL_NEAREST)
        target.use()  # both bindings back to one framebuffer, as moderngl keeps them

    return copy


@contextmanager
def current(made) -> Iterator[None]:
    """`made` (a moderngl context; None: one the block makes) current for the block, and
    whatever EGL context was current before (pybullet's EGL plugin's, in a process that has both
    kinds of world) made current again after it: the plugin never makes its own current again,
    and would draw into ours."""
    egl = egl_context.libegl()
    saved = None
    if egl is not None and egl.eglGetCurrentContext():
        saved = egl_context.current_egl(egl)
    try:
        if made is None:  # the block makes its own context (current)
            yield
        else:
            with made:
                yield
    finally:
        if saved is not None:
            egl.eglMakeCurrent(*saved)


def gl_available() -> bool:
    """Whether an OpenGL 3.3 context can be made in this process (made once, then kept)."""
    return context() is not None


def context_made() -> bool:
    """Whether this process holds the answer of `context` (a context, or None where none can
    be made) since it last released one (`release_context`)."""
    return context.cache_info().currsize > 0


def release_context() -> bool:
    """Give this process's GL context back to the driver now rather than at the process's exit:
    made current nowhere, destroyed, and its EGL display terminated, so that the driver frees
    what it holds for the context (NVIDIA's does so one process at a time, docs/benchmarks.md).
    Every renderer drawing with it must have been released first, and pybullet's EGL plugin (a
    world with renderer "egl") closed: the display they may share is terminated. Its compiled
    programs and the uniforms last set are forgotten (`forget_with_context`); the next
    `context()` makes a new one.
    Returns whether there was one to release."""
    if not context_made():
        return False
    made = context()
    context.cache_clear()
    for forget in _FORGOTTEN_WITH_IT:
        forget()
    if made is None:
        return False
    egl = egl_context.libegl()
    display = None
    if egl is not None:
        with made:
            display = egl.eglGetCurrentDisplay()
    made.release()  # eglDestroyContext: deferred while the context is current
    if display:
        egl.eglMakeCurrent(display, None, None, None)
        egl.eglTerminate(display)
        egl.eglReleaseThread()
    return True


def gl_version() -> str:
    """The GL driver's version string (for example '4.5 (Core Profile) Mesa 25.0.7...')."""
    made = context()
    return "" if made is None else str(made.info["GL_VERSION"])


def gl_driver() -> str:
    """What draws: the renderer and version strings, for example 'llvmpipe (LLVM 15.0.6, 256
    bits), OpenGL 4.5 (Core Profile) Mesa 25.0.7-2~bpo12+1'; "" without a context."""
    return f"{gl_renderer_name()}, OpenGL {gl_version()}" if gl_available() else ""


def gl_renderer_name() -> str:
    """The GL driver's renderer string (for example 'llvmpipe ...' or 'NVIDIA H100 ...')."""
    made = context()
    return "" if made is None else str(made.info["GL_RENDERER"])


# GL drivers that rasterise on the CPU: every vertex of a draw is shaded on the calling thread
# there (once per view), so the models are posed once per state on the CPU, and each material
# group gets a program of its own (llvmpipe runs every branch of a shader for every pixel)
SOFTWARE_RENDERERS = ("llvmpipe", "softpipe", "swrast")


def rasterises_on_cpu() -> bool:
    """Whether this process's GL draws on the CPU (Mesa's llvmpipe, as on a machine without a
    GPU)."""
    name = gl_renderer_name().lower()
    return any(software in name for software in SOFTWARE_RENDERERS)
