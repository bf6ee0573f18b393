"""Views read back small: a drawn view exposed and area-resized on the GPU before it is read.

The closed-loop observer's cameras are read by a network at a fraction of their drawn size.
Their exposure and area resize (`conditions.expose`, then OpenCV's INTER_AREA, as the Dataset
and the camera's collection do it) run as two shader passes over the drawn colour texture:
one samples the exposure meter's pixels (`shaders/sample.frag`), read back for the gain; the
other exposes each drawn pixel by that gain and averages the pixels under each output pixel
(`shaders/reduce.frag`). Only the meter's and the output's pixels come back. Where GL draws
on the CPU, the same arithmetic by OpenCV on the whole view read back costs less
(`reduced_on_cpu`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

# the drawn view's colour is bound here: after the scene's three textures and the gather's
TEXTURE_UNIT = 4


class ViewReduction:
    """The two passes, each one triangle over a small framebuffer the caller gives (`corners`:
    a buffer of the triangle's three corners in clip space, `in_corner`)."""

    def __init__(self, context, sample_program, reduce_program, corners) -> None:
        self.context = context
        self.sample_array = context.vertex_array(sample_program, [(corners, "2f", "in_corner")])
        self.reduce_array = context.vertex_array(reduce_program, [(corners, "2f", "in_corner")])

    def sample(self, source, target, step: int) -> None:
        """Into `target` (of `samples_size`): the colour texture `source` at every `step`-th
        row and column from `step // 2`, as numpy's `rgb[s // 2 :: s, s // 2 :: s]`."""
        self._pass(self.sample_array, source, target, {"step": step})

    def reduce(
        self, source, drawn: tuple[int, int], target, size: tuple[int, int], gain: float = 1.0
    ) -> None:
        """Into `target` (`size`: width, height): the colour texture `source` (drawn at `drawn`)
        exposed by `gain` and area-resized, each pixel the mean of the drawn pixels under it."""
        scale = (drawn[0] / size[0], drawn[1] / size[1])
        self._pass(self.reduce_array, source, target, {"scale": scale, "gain": gain})

    def _pass(self, array, source, target, uniforms: dict) -> None:
        import moderngl

        target.use()
        self.context.disable(moderngl.DEPTH_TEST)
        self.context.disable(moderngl.CULL_FACE)
        source.use(location=TEXTURE_UNIT)
        array.program["source"].value = TEXTURE_UNIT
        for name, value in uniforms.items():
            array.program[name].value = value
        array.render(moderngl.TRIANGLES, vertices=3)

    def release(self) -> None:
        self.sample_array.release()
        self.reduce_array.release()


def samples_size(drawn: tuple[int, int], step: int) -> tuple[int, int]:
    """(width, height) of a view drawn at `drawn` sampled at every `step`-th row and column."""
    return len(range(step // 2, drawn[0], step)), len(range(step // 2, drawn[1], step))


def reduced_on_cpu(
    bgra: NDArray[np.uint8],
    size: tuple[int, int],
    gain_of: Callable[[NDArray[np.uint8]], float] | None,
    meter_step: int,
) -> NDArray[np.uint8]:
    """The passes' arithmetic on the CPU: a whole BGRA view `(H, W, 4)` exposed by the gain
    `gain_of` gives for its pixels at every `meter_step`-th row and column (as RGB) and
    area-resized to `size` (width, height; a view smaller than that is enlarged, as OpenCV's
    INTER_AREA enlarges, bilinearly)."""
    import cv2

    if gain_of is not None:
        start = meter_step // 2
        gain = float(gain_of(bgra[start::meter_step, start::meter_step, 2::-1]))
        if gain != 1.0:
            bgra = cv2.convertScaleAbs(bgra, alpha=gain)
    return cv2.resize(bgra, tuple(size), interpolation=cv2.INTER_AREA)
