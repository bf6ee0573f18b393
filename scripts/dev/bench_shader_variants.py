"""Where the camera shader's time goes: the six cameras of one clip drawn with scene.frag as it
is and with named variants of it (a part replaced by a constant, or left out), alternated in one
process, so that each part's cost is measured against the shader as landed in the same run.

    python scripts/dev/bench_shader_variants.py --data DATA --clip ID [--variants a,b,...]
        [--rounds 3] [--first-frame 30] [--frames 10]

DATA is a curated data root (e.g. `drivee2e synth DATA --clips 16 --seed 0`). Every variant is
compiled fresh (its programs and vertex arrays made again) and draws the six cameras at frames
`--first-frame` to `--first-frame + --frames - 1` after one warm-up frame; a round times every
variant once, and the minimum over rounds is printed with its ratio to "landed". The variants
change only what the cameras show (the image is not the product's: use them to find costs).
Run with `LP_NUM_THREADS=1` on llvmpipe to measure one worker's rasteriser, on a quiet machine.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path

from drivee2e_data import store
from drivee2e_data.sensors.camera import camera_to_world
from drivee2e_data.sensors.ego_state import ego_motion
from drivee2e_data.sensors.rig import default_rig
from drivee2e_data.sim import gl_batches, gl_programs, gl_renderer
from drivee2e_data.sim.world import World

TRIVIAL_MAIN = "void main() { rgba = vec4(colour, 1.0); body_out = body; depth_out = eye_depth; }\n"


def _replace(old: str, new: str) -> Callable[[str], str]:
    def edit(source: str) -> str:
        if old not in source:
            raise SystemExit(f"scene.frag no longer holds {old!r}: update this variant")
        return source.replace(old, new)

    return edit


def _trivial(source: str) -> str:
    return source[: source.index("void main() {")] + TRIVIAL_MAIN


# name: (what it shows, the edit of scene.frag's text, material groups drawn without SHADOWS,
# the shadow map's filter)
VARIANTS: dict[str, tuple[str, Callable[[str], str], frozenset[int], str]] = {
    "landed": ("scene.frag as it is", lambda s: s, frozenset(), "linear"),
    "no-shadow-lookup": (
        "the shadow map's lookup replaced by a constant",
        _replace(
            "float lit = texture(shadow_map, vec3(p.xy, p.z - 0.0006));",
            "float lit = 0.5 + 0.01 * p.z;",
        ),
        frozenset(),
        "linear",
    ),
    "no-sunlit": (
        "the sun term without sunlit()",
        _replace("float sun = sunlit();", "float sun = 0.5 + 0.001 * shadow_position.x;"),
        frozenset(),
        "linear",
    ),
    "no-wear": (
        "the ground's wear raster replaced by a constant",
        _replace("texture(wear_map, (p - wear_origin) / wear_extent)", "vec4(0.5 + 0.001 * p.x)"),
        frozenset(),
        "linear",
    ),
    "no-glossy": (
        "highlights and reflections left out",
        _replace("#ifdef GLOSSY\n", "#ifdef GLOSSY_LEFT_OUT\n"),
        frozenset(),
        "linear",
    ),
    "trivial": ("vertex colour, depth and id only", _trivial, frozenset(), "linear"),
    "ground-unshadowed": (
        "road, paint and grass drawn without the shadow lookup",
        lambda s: s,
        frozenset(
            gl_batches._group_of(m)  # the groups of these materials
            for m in (
                gl_batches.Material.ASPHALT,
                gl_batches.Material.MARKING,
                gl_batches.Material.GRASS,
            )
        ),
        "linear",
    ),
    "nearest-shadows": (
        "the shadow map read with NEAREST instead of the 2x2 comparison filter",
        lambda s: s,
        frozenset(),
        "nearest",
    ),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, required=True)
    parser.add_argument("--clip", required=True)
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--first-frame", type=int, default=30)
    parser.add_argument("--frames", type=int, default=10)
    args = parser.parse_args()
    names = ["landed", *[n for n in args.variants.split(",") if n and n != "landed"]]
    unknown = [n for n in names if n not in VARIANTS]
    if unknown:
        raise SystemExit(f"unknown variant {unknown[0]!r}: expected one of {', '.join(VARIANTS)}")

    import moderngl

    original_source, original_defines = gl_programs.shader_source, gl_renderer.group_defines
    chosen = {"name": "landed"}

    def shader_source(name: str, defines=()):  # type: ignore[no-untyped-def]
        source = original_source(name, defines)
        return VARIANTS[chosen["name"]][1](source) if name == "scene.frag" else source

    def group_defines(group: int, variant: tuple[str, ...]) -> tuple[str, ...]:
        if group in VARIANTS[chosen["name"]][2]:
            variant = tuple(d for d in variant if d != "SHADOWS")
        return original_defines(group, variant)

    gl_programs.shader_source = shader_source
    gl_renderer.group_defines = group_defines
    cameras = default_rig().cameras
    scenario = store.read_scenario(args.data, args.clip)
    timings: dict[str, list[float]] = {name: [] for name in names}
    with World(store.read_map(args.data, scenario.map_id), scenario, "gl") as world:
        ego, motion = scenario.ego, ego_motion(scenario)

        def draw(frame: int) -> None:
            world.place_ego(float(ego.x_m[frame]), float(ego.y_m[frame]), ego.track_id)
            world.set_time(frame)
            for camera in cameras:
                pose = camera_to_world(camera, motion.ego_to_world(frame))
                eye = pose[:3, 3]
                world.render(eye, eye + 10 * pose[:3, 2], camera.width, camera.height,
                             camera.vertical_fov_deg, near_m=0.5, far_m=200.0,
                             native=True)  # fmt: skip

        renderer = world.gl
        for _ in range(args.rounds):
            for name in names:
                chosen["name"] = name
                gl_programs.program.cache_clear()  # compiled again per variant
                gl_programs.LOOKS_SET.clear()
                for key in list(renderer.arrays):
                    renderer.arrays.pop(key).release()
                filtering = moderngl.NEAREST if VARIANTS[name][3] == "nearest" else moderngl.LINEAR
                renderer.shadow_texture.filter = (filtering, filtering)
                draw(args.first_frame - 1)
                start = time.perf_counter()
                for frame in range(args.first_frame, args.first_frame + args.frames):
                    draw(frame)
                timings[name].append(1000 * (time.perf_counter() - start) / args.frames)
    landed = min(timings["landed"])
    print(f"{args.clip}, six cameras, frames {args.first_frame}-"
          f"{args.first_frame + args.frames - 1}, minimum of {args.rounds} rounds:")  # fmt: skip
    for name in names:
        best = min(timings[name])
        print(f"  {name:18s} {best:7.1f} ms  {best / landed:5.3f}x landed   "
              f"({VARIANTS[name][0]})")  # fmt: skip


if __name__ == "__main__":
    main()
