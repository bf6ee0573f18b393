"""The shaders' programs and what they read, made once per process for its one GL context
(`gl_context`) and forgotten with it: a shader file's text with its defines and includes
(`shader_source`), the scene shader's variant for a look (`scene_variant`), the compiled
programs, the textures every world shares (the night's noise pool) and each program's uniforms,
set only where they changed.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.sim import gl_context
from drivee2e_data.sim.conditions import ShaderLook
from drivee2e_data.sim.gl_reduce import noise_pool_textures
from drivee2e_data.sim.scenery import WearRaster

SHADER_DIR = Path(__file__).with_name("shaders")
_INCLUDE = re.compile(r'^#include "([\w.]+)"$', re.MULTILINE)


def shader_source(name: str, defines: Sequence[str] = ()) -> str:
    """A shader file's text with `defines` after its version line and each `#include "F"` line
    replaced by file F's text (GLSL has no includes); the fragment shaders of the sky and the
    scene begin with common.glsl's (noise, sky colour), after `defines` (scene.frag's
    variants)."""
    text = _INCLUDE.sub(lambda match: (SHADER_DIR / match[1]).read_text(),
                        (SHADER_DIR / name).read_text())  # fmt: skip
    header = "".join(f"#define {define}\n" for define in defines)
    if name in ("sky.frag", "scene.frag"):
        return "#version 330\n" + header + (SHADER_DIR / "common.glsl").read_text() + text
    version, _, rest = text.partition("\n")
    return version + "\n" + header + rest


def scene_variant(look: ShaderLook) -> tuple[str, ...]:
    """The defines of the scene shader a look needs (`scene.frag`'s variants)."""
    variant = []
    if look.shadows:
        variant.append("SHADOWS")
    if look.lamps_on:  # by day (fog) the headlights' cones are lost in daylight: lamps only
        variant.append("NIGHT")
    if look.wetness > 0.0:
        variant.append("WET")
    if look.fog_density > 0.0:
        variant.append("FOG")
    return tuple(variant)


@functools.cache
def gather_program():
    """`DepthGather`'s program, compiled once per process (`program`)."""
    return gl_context.context().program(
        vertex_shader=shader_source("gather.vert"), varyings=["value"]
    )


@functools.cache
def program(
    vertex: str, fragment: str, defines: tuple[str, ...] = (), vertex_defines: tuple[str, ...] = ()
):
    """The program of two shader files (`defines`: the fragment shader's variant;
    `vertex_defines` the vertex shader's), compiled once per process for its one context
    (`gl_context.context`) and kept for every world after: each world draws with up to
    sixteen variants, and llvmpipe takes tens of milliseconds to compile one."""
    return gl_context.context().program(
        vertex_shader=shader_source(vertex, vertex_defines),
        fragment_shader=shader_source(fragment, defines),
    )


@functools.cache
def noise_textures() -> tuple:
    """The night's noise pool in this process's context (`gl_reduce.noise_pool_textures`),
    made when the first night view is reduced and kept for every world after."""
    return noise_pool_textures(gl_context.context())


def wear_texture(context, wear: WearRaster | None):
    """The ground-detail raster as a two-channel texture (wear, mottle; a blank texel without
    one)."""
    import moderngl

    values = np.full((1, 1, 2), 128, np.uint8) if wear is None else wear.values
    texture = context.texture(
        (values.shape[1], values.shape[0]), 2, np.ascontiguousarray(values).tobytes()
    )
    texture.filter = (moderngl.LINEAR, moderngl.LINEAR)
    texture.repeat_x = texture.repeat_y = False
    return texture


def float_texture(context, values: NDArray[np.float32]):
    """A float texture of `(rows, columns, channels)` values, filtered linearly, clamped."""
    import moderngl

    rows, columns, channels = values.shape
    texture = context.texture((columns, rows), channels, values.tobytes(), dtype="f4")
    texture.filter = (moderngl.LINEAR, moderngl.LINEAR)
    texture.repeat_x = texture.repeat_y = False
    return texture


# The value each program's uniform was last given, by (program, name): a view sets some thirty
# uniforms in each of up to eight programs, and most (the clip's look) are the same at every
# view. Programs live as long as the context (`program`), whichever renderer sets them.
_UNIFORMS: dict[tuple[int, str], object] = {}
_MEMBERS: dict[int, frozenset[str]] = {}  # program -> its uniforms' names
LOOKS_SET: dict[int, tuple] = {}  # program -> the look's uniforms last set into it, as a whole


def members(program) -> frozenset[str]:
    """The names of a program's uniforms (asking the program iterates over all of them)."""
    names = _MEMBERS.get(program.glo)
    if names is None:
        names = _MEMBERS[program.glo] = frozenset(program)
    return names


def set_uniform(program, name: str, value) -> None:
    """A uniform's value, where the compiled program kept it (unused ones are dropped) and it
    changed."""
    if name not in members(program):
        return
    if isinstance(value, np.ndarray):
        value = tuple(float(v) for v in value.ravel())
    key = (program.glo, name)
    if _UNIFORMS.get(key) != value:
        program[name].value = value
        _UNIFORMS[key] = value


def set_matrix(program, name: str, matrix: NDArray) -> None:
    if name not in members(program):
        return
    data = np.asarray(matrix).T.astype(np.float32).tobytes()
    key = (program.glo, name)
    if _UNIFORMS.get(key) != data:
        program[name].write(data)
        _UNIFORMS[key] = data


def _forget() -> None:
    program.cache_clear()
    gather_program.cache_clear()
    noise_textures.cache_clear()
    _UNIFORMS.clear()
    _MEMBERS.clear()
    LOOKS_SET.clear()


gl_context.forget_with_context(_forget)
