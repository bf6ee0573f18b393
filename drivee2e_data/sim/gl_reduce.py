"""Views read back small: a drawn view area-resized on the GPU before it is read.

The closed-loop observer's cameras are read by a network at a fraction of their drawn size.
Their area resize (OpenCV's INTER_AREA, as the Dataset resizes the logged images) runs as a
shader pass over the drawn colour texture (`shaders/reduce.frag`), each output pixel the mean
of the drawn pixels under it; only the output's pixels come back. A step's views, each drawn
into a framebuffer of its own (drawn at an offset in a shared one, llvmpipe shades a few
pixels a level apart), are reduced side by side into one framebuffer (`atlas`), read once. At
night the reduction adds the camera's noise, averaged from the pool over each output pixel's
full-size area (`noise_pool_textures`, `conditions.with_reduced_noise`). Where GL draws on the
CPU, the same arithmetic by OpenCV on the whole view read back costs less (`reduced_on_cpu`).
The camera's exposure is metered on the reduced image and applied to it afterwards
(`sensors.camera.render_reduced`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

# the drawn view's colour is bound here: after the scene's three textures and the gather's;
# the night's noise pool beside it
TEXTURE_UNIT = 4
NOISE_UNIT = 5
NOISE_TEXTURE_WIDTH = 4096  # texels a row of the pool's textures (`reduce.frag`'s shift)


@dataclass(frozen=True)
class Atlas:
    """Views laid out in one framebuffer of `size` (width, height): view k's lower left corner
    at `origins[k]` (x, y) in GL's window coordinates, its own size at `sizes[k]`."""

    size: tuple[int, int]
    origins: tuple[tuple[int, int], ...]
    sizes: tuple[tuple[int, int], ...]

    def viewport(self, k: int) -> tuple[int, int, int, int]:
        """View k's rectangle (x, y, width, height)."""
        return (*self.origins[k], *self.sizes[k])

    def view_of(self, pixels: NDArray, k: int) -> NDArray:
        """View k's part of `pixels` (H, W, ...), the whole atlas as read back (GL's row 0
        first)."""
        x, y, width, height = self.viewport(k)
        return pixels[y : y + height, x : x + width]


def atlas(sizes: Sequence[tuple[int, int]], max_px: int) -> Atlas:
    """`sizes` (width, height each) left to right in rows at most `max_px` wide (GL's largest
    framebuffer side), each row as high as its highest view, rows bottom up."""
    origins: list[tuple[int, int]] = []
    x = y = row_height = width = 0
    for view_width, view_height in sizes:
        if view_width > max_px or view_height > max_px:
            raise ValueError(f"a view of {view_width}x{view_height} exceeds GL's {max_px} pixels")
        if x and x + view_width > max_px:
            x, y, row_height = 0, y + row_height, 0
        origins.append((x, y))
        x += view_width
        width, row_height = max(width, x), max(row_height, view_height)
    height = y + row_height
    if height > max_px:
        raise ValueError(f"{len(sizes)} views of {sizes[0]} do not fit {max_px} pixels square")
    return Atlas((width, height), tuple(origins), tuple(tuple(s) for s in sizes))


class ViewReduction:
    """The pass, one triangle a view over its rectangle of an atlas the caller gives
    (`corners`: a buffer of the triangle's three corners in clip space, `in_corner`), reading
    the view's drawn colour texture."""

    def __init__(self, context, reduce_program, corners) -> None:
        self.context = context
        self.reduce_array = context.vertex_array(reduce_program, [(corners, "2f", "in_corner")])
        reduce_program["noise_pool"].value = NOISE_UNIT  # read only where a view has noise

    def reduce(
        self,
        sources: Sequence,
        drawn: Sequence[tuple[int, int]],
        target,
        reduced: Atlas,
        noise: NightNoise | None = None,
    ) -> None:
        """Into `target` (laid out as `reduced`): each colour texture of `sources` (a view each,
        drawn at its size in `drawn`) area-resized, each pixel the mean of the drawn pixels
        under it; with `noise`, each view's night noise added
        (`conditions.with_reduced_noise`) where it has a start."""
        starts = noise.starts if noise is not None else (None,) * len(sources)
        uniforms, pools = [], []
        for (width, height), size, start in zip(drawn, reduced.sizes, starts, strict=True):
            values = {"scale": (width / size[0], height / size[1]),
                      "noise_start": -1 if start is None else start // 3}  # fmt: skip
            if start is not None:
                full_width, full_height = noise.full_size
                values["full_width"] = full_width
                values["noise_scale"] = (full_width / size[0], full_height / size[1])
            uniforms.append(values)
            pools.append(None if start is None else noise.pools[start % 3])
        self._pass(self.reduce_array, sources, target, reduced, uniforms, pools)

    def _pass(
        self,
        array,
        sources: Sequence,
        target,
        written: Atlas,
        uniforms: list[dict],
        pools: Sequence | None = None,
    ) -> None:
        """One triangle a view over its rectangle of `target` (laid out as `written`), reading
        its texture of `sources` (and its noise pool's texture of `pools`, where not None):
        the shaders take the rectangle's corner (`origin`) and see the view's own pixel
        coordinates."""
        import moderngl

        target.use()
        self.context.disable(moderngl.DEPTH_TEST)
        self.context.disable(moderngl.CULL_FACE)
        program = array.program
        program["source"].value = TEXTURE_UNIT
        pools = pools if pools is not None else (None,) * len(sources)
        for k, (source, values, pool) in enumerate(zip(sources, uniforms, pools, strict=True)):
            source.use(location=TEXTURE_UNIT)
            if pool is not None:
                pool.use(location=NOISE_UNIT)
            self.context.viewport = written.viewport(k)
            program["origin"].value = written.origins[k]
            for name, value in values.items():
                program[name].value = value
            array.render(moderngl.TRIANGLES, vertices=3)

    def release(self) -> None:
        self.reduce_array.release()


@dataclass(frozen=True)
class NightNoise:
    """The night's noise of a step's views for the reduction: each view's first value in the
    pool (`conditions.night_noise_start`; None: none added), the cameras' full size (width,
    height) and the pool as GL textures (`noise_pool_textures`)."""

    starts: tuple[int | None, ...]
    full_size: tuple[int, int]
    pools: tuple


def noise_pool_textures(context) -> tuple:
    """`conditions.noise_pool` as three integer textures of `context`, one per phase p: texel
    k holds the levels `3k + p` to `3k + p + 2`, so that a window starting at any value reads a
    full-size pixel's three levels in one fetch (`NOISE_TEXTURE_WIDTH` texels a row; 48 MiB,
    uploaded once per context)."""
    import moderngl

    from drivee2e_data.sim.conditions import noise_pool

    pool = noise_pool()
    textures = []
    for phase in range(3):
        texels = (len(pool) - phase) // 3
        rows = -(-texels // NOISE_TEXTURE_WIDTH)
        levels = np.zeros((rows * NOISE_TEXTURE_WIDTH, 3), np.int8)
        levels[:texels] = pool[phase : phase + 3 * texels].reshape(texels, 3)
        texture = context.texture((NOISE_TEXTURE_WIDTH, rows), 3, levels.tobytes(), dtype="i1")
        texture.filter = (moderngl.NEAREST, moderngl.NEAREST)  # integer textures: nearest only
        textures.append(texture)
    return tuple(textures)


def reduced_on_cpu(bgra: NDArray[np.uint8], size: tuple[int, int]) -> NDArray[np.uint8]:
    """The pass's arithmetic on the CPU: a whole BGRA view `(H, W, 4)` area-resized to `size`
    (width, height; a view smaller than that is enlarged, as OpenCV's INTER_AREA enlarges,
    bilinearly)."""
    import cv2

    return cv2.resize(bgra, tuple(size), interpolation=cv2.INTER_AREA)
