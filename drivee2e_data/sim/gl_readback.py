"""A drawn view's pixels read back from the GL renderer's framebuffer: at once, or queued into
pixel buffers on a GPU, so that the caller draws its next views while the GPU draws and copies
this one (`GLRenderer.queue`; the LiDAR's six views a sweep).

A read at once waits for everything queued before it: on a GPU that several workers' contexts
share, the worker sits idle through its view's drawing and through the other contexts' turns,
once a view. Queued, a sweep's six LiDAR views cost one such wait. A queued read costs a copy
more on the CPU (out of the pixel buffer), so the cameras' 1600x900 images are read at once:
on an H100 host with all 32 cores busy, queuing them as well cost more than it saved
(docs/benchmarks.md). Where Mesa's llvmpipe draws, drawing happens in the calling thread at the
read and nothing would overlap: pixels are read at once there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class Read:
    """One colour attachment to read: its index in the framebuffer, components per pixel and
    moderngl's dtype ("f1": uint8, "f4": float32)."""

    attachment: int
    components: int
    dtype: str

    def array(self, width: int, height: int) -> NDArray:
        """An empty array the attachment's pixels fit: (H, W, C), or (H, W) for one component."""
        shape = (height, width) if self.components == 1 else (height, width, self.components)
        return np.empty(shape, np.uint8 if self.dtype == "f1" else np.float32)


class PendingPixels:
    """The pixels of one view's reads, in the order asked: already in arrays (read at once), or
    on their way into pixel buffers, copied out by `result` (which waits for the GPU; the
    renderer's context current)."""

    def __init__(
        self, arrays: list[NDArray], buffers: list | None = None, pool: list[list] | None = None
    ) -> None:
        self.arrays, self.buffers, self.pool = arrays, buffers, pool

    def result(self) -> list[NDArray]:
        if self.buffers is not None:
            for buffer, array in zip(self.buffers, self.arrays, strict=True):
                buffer.read_into(array)
            self.pool.append(self.buffers)  # free for the next view of this size
            self.buffers = None
        return self.arrays


class PixelReads:
    """Reads from the renderer's framebuffers (`queued`: through pixel buffers where the caller
    asks for it; on a GPU), the buffers kept per view size and reads for the renderer's next
    views: six sets for a LiDAR sweep's views in flight at once, reused every sweep."""

    def __init__(self, context, queued: bool) -> None:
        self.context, self.queued = context, queued
        self.free: dict[tuple, list[list]] = {}
        # every pixel buffer made, released with the world even where a read was never taken
        # (its caller failed between drawing and taking it)
        self.made: list = []

    def read(
        self, framebuffer, reads: tuple[Read, ...], width: int, height: int, queued: bool = True
    ) -> PendingPixels:
        """The `reads` of `framebuffer` (current in the caller's context), `width` x `height`:
        into pixel buffers where reads are `queued` here and the caller asks for it, else at
        once."""
        arrays = [read.array(width, height) for read in reads]
        if not (self.queued and queued):
            for read, array in zip(reads, arrays, strict=True):
                framebuffer.read_into(array, components=read.components,
                                      attachment=read.attachment, dtype=read.dtype)  # fmt: skip
            return PendingPixels(arrays)
        pool = self.free.setdefault((width, height, reads), [])
        if pool:
            buffers = pool.pop()
        else:
            buffers = [self.context.buffer(reserve=array.nbytes) for array in arrays]
            self.made.extend(buffers)
        for read, buffer in zip(reads, buffers, strict=True):
            framebuffer.read_into(buffer, components=read.components,
                                  attachment=read.attachment, dtype=read.dtype)  # fmt: skip
        return PendingPixels(arrays, buffers, pool)

    def release(self) -> None:
        """Free the pixel buffers (the caller's context current)."""
        for buffer in self.made:
            buffer.release()
        self.free, self.made = {}, []


def bgra_under(rgb: NDArray[np.uint8]) -> NDArray[np.uint8] | None:
    """The (H, W, 4) BGRA pixels whose first three channels, backwards, `rgb` (H, W, 3) is, as
    the GL renderer's colour views are (`GLRenderer.queue` reads BGRA), if it is one; else
    None. The pixels are a view of the BGRA read (contiguous rows where `rgb` spans the read's
    width; a window of its rows where the read holds several views side by side, as the
    reduced views' atlas does), which OpenCV takes as it lies."""
    base = rgb.base
    if not (
        isinstance(base, np.ndarray)
        and base.dtype == np.uint8
        and base.ndim == 3
        and base.shape[2] == 4
        and base.flags.c_contiguous
        and rgb.ndim == 3
        and rgb.strides == (base.strides[0], 4, -1)
    ):
        return None
    offset = rgb.__array_interface__["data"][0] - 2 - base.__array_interface__["data"][0]
    row, within = divmod(offset, base.strides[0])
    column, remainder = divmod(within, 4)
    height, width = rgb.shape[:2]
    if offset < 0 or remainder or row + height > base.shape[0] or column + width > base.shape[1]:
        return None
    if (row, column, height, width) == (0, 0, *base.shape[:2]):
        return base
    return base[row : row + height, column : column + width]


def contiguous_rgb(rgb: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """`rgb` (H, W, 3) as a C-contiguous array: itself where it is one, a view of a BGRA read
    (`bgra_under`) converted by OpenCV, else copied. numpy copies such a view a pixel at a time:
    6.2 ms a 1600x900 image against OpenCV's 0.07 here, and for the rain and night clips, whose
    cameras get streaks and noise on the CPU, that had made the slowest condition 1.36x the
    clear day's on an H100 host (docs/benchmarks.md, twentieth session)."""
    if rgb.flags.c_contiguous:
        return rgb
    bgra = bgra_under(rgb)
    if bgra is None:
        return np.ascontiguousarray(rgb)
    import cv2

    return cv2.cvtColor(bgra, cv2.COLOR_BGRA2RGB)
