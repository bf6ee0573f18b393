"""Procedural vehicles that fill their box exactly: cars (sedan, hatchback, SUV), vans, trucks
(a cab with a cargo box, a tractor with a trailer) and buses (one or two bodies).

A body is a loft: rings across the car (rounded bottom, sides with a shoulder, a greenhouse
leaning in towards the roof) placed at sections along its length, as fractions of the box. Glass
is where the greenhouse lies between the pillars of `windows`, and wherever the roof line climbs
or falls between two sections (windscreen, rear window). Bumpers and lamps reach the box's
front and back, mirrors its sides, wheels its bottom and the roof its top.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.sim.models import palette
from drivee2e_data.sim.models.mesh import (
    Joint,
    Light,
    Material,
    MeshBuilder,
    ModelMesh,
    box,
    cylinder,
    loft,
    loft_caps,
    rotation_y,
)

# (x, bottom, belt, top, width, roof width): fractions of the box's length (rear 0, front 1),
# height (ground 0, top 1) and width
Section = tuple[float, float, float, float, float, float]
BODY_END = 0.006  # the body stops this far (fraction of the length) short of bumpers and lamps
TYRE_WIDTH_M = 0.22
RIM_SHARE = 0.62  # rim radius / tyre radius
SPOKES = 5
ROOF_GLASS_RISE = 0.1  # a roof line changing by more than this (of the height) is glass


@dataclass(frozen=True)
class BodyStyle:
    sections: tuple[Section, ...]
    windows: tuple[tuple[float, float], ...]  # side glass between these x fractions
    axles: tuple[float, ...]  # x fractions; the frontmost steers
    wheel_radius: float  # fraction of the height
    corner: float = 0.08  # rounding of the section's corners, fraction of the height
    lamp_z: float = 0.5  # headlights' centre, fraction of the height
    tail_z: float = 0.55


def _windows(start: float, end: float, count: int, pillar: float = 0.012) -> tuple:
    edges = np.linspace(start, end, count + 1)
    return tuple((float(a + pillar), float(b - pillar)) for a, b in itertools.pairwise(edges))


SEDAN = BodyStyle(
    sections=((0.0, 0.30, 0.60, 0.60, 0.90, 0.90), (0.02, 0.18, 0.67, 0.67, 0.95, 0.95),
              (0.06, 0.14, 0.70, 0.70, 0.96, 0.96), (0.21, 0.14, 0.71, 0.71, 0.96, 0.96),
              (0.32, 0.14, 0.70, 0.96, 0.96, 0.80), (0.42, 0.14, 0.70, 1.0, 0.96, 0.82),
              (0.60, 0.14, 0.70, 1.0, 0.96, 0.82), (0.67, 0.14, 0.69, 0.96, 0.96, 0.80),
              (0.79, 0.14, 0.66, 0.66, 0.96, 0.96), (0.94, 0.16, 0.60, 0.60, 0.95, 0.95),
              (0.98, 0.22, 0.55, 0.55, 0.92, 0.92), (1.0, 0.30, 0.50, 0.50, 0.88, 0.88)),
    windows=((0.34, 0.50), (0.525, 0.665)),
    axles=(0.19, 0.79), wheel_radius=0.22, lamp_z=0.52, tail_z=0.58,
)  # fmt: skip
HATCHBACK = BodyStyle(
    sections=((0.0, 0.28, 0.58, 0.58, 0.92, 0.92), (0.015, 0.16, 0.64, 0.86, 0.96, 0.78),
              (0.08, 0.14, 0.68, 1.0, 0.96, 0.82), (0.60, 0.14, 0.68, 1.0, 0.96, 0.82),
              (0.75, 0.14, 0.65, 0.65, 0.96, 0.96), (0.94, 0.16, 0.60, 0.60, 0.95, 0.95),
              (0.985, 0.22, 0.55, 0.55, 0.92, 0.92), (1.0, 0.28, 0.50, 0.50, 0.88, 0.88)),
    windows=((0.10, 0.40), (0.43, 0.59)),
    axles=(0.17, 0.82), wheel_radius=0.21, lamp_z=0.52, tail_z=0.62,
)  # fmt: skip
SUV = BodyStyle(
    sections=((0.0, 0.30, 0.58, 0.58, 0.93, 0.93), (0.02, 0.18, 0.60, 0.92, 0.96, 0.84),
              (0.06, 0.16, 0.61, 1.0, 0.97, 0.86), (0.62, 0.16, 0.61, 1.0, 0.97, 0.86),
              (0.75, 0.16, 0.60, 0.62, 0.97, 0.97), (0.96, 0.18, 0.58, 0.58, 0.96, 0.96),
              (1.0, 0.28, 0.52, 0.52, 0.92, 0.92)),
    windows=((0.08, 0.30), (0.33, 0.47), (0.50, 0.61)),
    axles=(0.18, 0.81), wheel_radius=0.21, lamp_z=0.50, tail_z=0.60,
)  # fmt: skip
VAN = BodyStyle(
    sections=((0.0, 0.15, 0.52, 0.98, 0.97, 0.93), (0.01, 0.12, 0.52, 1.0, 0.98, 0.94),
              (0.74, 0.12, 0.52, 1.0, 0.98, 0.94), (0.86, 0.12, 0.50, 0.55, 0.98, 0.98),
              (0.97, 0.14, 0.48, 0.48, 0.96, 0.96), (1.0, 0.20, 0.44, 0.44, 0.92, 0.92)),
    windows=((0.62, 0.73),),
    axles=(0.16, 0.82), wheel_radius=0.16, corner=0.05, lamp_z=0.40, tail_z=0.45,
)  # fmt: skip
MINIBUS = BodyStyle(
    sections=VAN.sections, windows=_windows(0.04, 0.74, 4), axles=(0.15, 0.83),
    wheel_radius=0.14, corner=0.05, lamp_z=0.38, tail_z=0.42,
)  # fmt: skip
BUS = BodyStyle(
    sections=((0.0, 0.14, 0.42, 0.96, 0.97, 0.95), (0.008, 0.10, 0.42, 1.0, 0.98, 0.96),
              (0.992, 0.10, 0.42, 1.0, 0.98, 0.96), (1.0, 0.14, 0.42, 0.96, 0.97, 0.95)),
    windows=(*_windows(0.03, 0.78, 7), (0.80, 0.97)),
    axles=(0.22, 0.82), wheel_radius=0.16, corner=0.06, lamp_z=0.22, tail_z=0.30,
)  # fmt: skip
CAB = BodyStyle(  # a truck's cab, in its own fractions (placed at the front of the box)
    sections=((0.0, 0.16, 0.50, 0.88, 0.96, 0.94), (0.04, 0.14, 0.50, 0.92, 0.96, 0.94),
              (0.78, 0.14, 0.50, 0.92, 0.96, 0.94), (0.90, 0.14, 0.50, 0.60, 0.96, 0.96),
              (1.0, 0.16, 0.46, 0.46, 0.94, 0.94)),
    windows=((0.45, 0.77),), axles=(), wheel_radius=0.0, corner=0.04,
)  # fmt: skip


def _ring(half_width: float, bottom: float, belt: float, top: float, roof: float,
          corner: float) -> NDArray[np.float64]:  # fmt: skip
    """(14, 2) one section's outline in (y, z), counter-clockwise: bottom, right side,
    shoulder, greenhouse, roof, and back down the left."""
    c = min(corner, 0.5 * (belt - bottom))
    rise = top - belt
    shoulder = half_width - c / 3
    roof = min(roof, shoulder)
    greenhouse_top = belt + 0.85 * rise
    roof_edge = roof - min(0.6 * c, roof) * (rise > 0)
    right = [(0.0, bottom), (half_width - c, bottom), (half_width, bottom + c),
             (half_width, belt - 0.5 * c), (shoulder, belt), (roof, greenhouse_top),
             (roof_edge, top)]  # fmt: skip
    left = [(-y, z) for y, z in right[1:][::-1]]
    return np.array([*right, (0.0, top), *left])


# the ring's segments: 0-1 and 12-13 underbody, 2-3 and 10-11 sides and shoulders, 4 and 9 the
# greenhouse's sides, 5-8 roof edges and roof
UNDER = (0, 1, 12, 13)
GREENHOUSE_SIDES = (4, 9)
GREENHOUSE = (4, 5, 6, 7, 8, 9)


def hull(builder: MeshBuilder, style: BodyStyle, x0: float, x1: float, size: NDArray,
         paint: tuple, z_bottom: float) -> None:  # fmt: skip
    """A loft body from x0 to x1 (model frame, metres) in `style`'s fractions of `size`'s
    height and width, its ground at `z_bottom`."""
    _, width, height = size
    sections = np.asarray(style.sections)
    xs = x0 + sections[:, 0] * (x1 - x0)
    rings = np.stack([
        _ring(0.5 * width * w, bottom * height, belt * height, top * height, 0.5 * width * roof,
              style.corner * height)
        for _, bottom, belt, top, w, roof in sections
    ])  # fmt: skip
    rings[..., 1] += z_bottom
    triangles = loft(xs, rings)  # (S-1, P, 2, 3, 3)
    kinds = np.zeros(triangles.shape[:2], np.int8)  # 0 paint, 1 glass, 2 trim
    kinds[:, list(UNDER)] = 2
    middle = 0.5 * (sections[:-1, 0] + sections[1:, 0])
    side_glass = np.zeros(len(middle), bool)
    for start, end in style.windows:
        side_glass |= (middle > start) & (middle < end)
    kinds[np.ix_(side_glass, list(GREENHOUSE_SIDES))] = 1
    sloped = np.abs(np.diff(sections[:, 3])) > ROOF_GLASS_RISE
    kinds[np.ix_(sloped, list(GREENHOUSE))] = 1
    colours = {0: paint, 1: palette.GLASS_RGB, 2: palette.TRIM_RGB}
    materials = {0: Material.PAINT, 1: Material.GLASS, 2: Material.MATTE}
    for kind in (0, 1, 2):
        builder.add(triangles[kinds == kind], colours[kind], materials[kind])
    builder.add(loft_caps(xs, rings), paint, Material.PAINT, smooth=False)


def wheel(builder: MeshBuilder, centre: NDArray, radius: float, width: float, steers: bool,
          side: int) -> None:  # fmt: skip
    """A tyre with a rim and spokes on its outer face (so its turning shows), turning about its
    own joint."""
    joint = builder.joint(
        Joint(tuple(float(v) for v in centre), "steer_wheel" if steers else "wheel")
    )
    builder.add(cylinder(centre, radius, width, axis=1, sides=16), palette.TYRE_RGB,
                Material.TYRE, joint=joint)  # fmt: skip
    face = centre + np.array([0.0, side * (0.5 * width + 0.004), 0.0])
    builder.add(cylinder(face, RIM_SHARE * radius, 0.008, axis=1, sides=16), palette.RIM_RGB,
                Material.PAINT, joint=joint, smooth=False)  # fmt: skip
    spoke_face = centre + np.array([0.0, side * (0.5 * width + 0.010), 0.0])
    for k in range(SPOKES):
        spoke = box((0.0, 0.0, 0.5 * RIM_SHARE * radius), (0.05, 0.006, RIM_SHARE * radius))
        turned = spoke @ rotation_y(np.float64(2 * np.pi * k / SPOKES)).T + spoke_face
        builder.add(turned, palette.SPOKE_RGB, Material.MATTE, joint=joint, smooth=False)


def wheels(builder: MeshBuilder, axles_x: list[float], radius: float, size: NDArray,
           z_bottom: float, inset: float = 0.03) -> None:  # fmt: skip
    """Two wheels per axle; the frontmost axle steers. Tyres stand on `z_bottom`."""
    half_width = 0.5 * size[1]
    front = max(axles_x)
    for x in axles_x:
        for side in (1, -1):
            y = side * (half_width - inset - 0.5 * TYRE_WIDTH_M - 0.012)
            centre = np.array([x, y, z_bottom + radius])
            wheel(builder, centre, radius, TYRE_WIDTH_M, x == front, side)


def lamps_and_bumpers(builder: MeshBuilder, size: NDArray, z_bottom: float, lamp_z: float,
                      tail_z: float) -> None:  # fmt: skip
    """Headlights, tail lights, bumpers and a grille at the box's ends."""
    length, width, height = size
    front, back = 0.5 * length, -0.5 * length
    depth = BODY_END * length + 0.02
    lamp = (depth, 0.20 * width, 0.07 * height)
    for side in (1, -1):
        y = side * 0.33 * width
        builder.add(box((front - 0.5 * depth, y, z_bottom + lamp_z * height), lamp),
                    palette.HEADLIGHT_RGB, Material.LAMP, Light.HEAD, smooth=False)  # fmt: skip
        builder.add(box((back + 0.5 * depth, y, z_bottom + tail_z * height), lamp),
                    palette.TAIL_RGB, Material.LAMP, Light.TAIL, smooth=False)  # fmt: skip
    bumper = (depth, 0.86 * width, 0.09 * height)
    bumper_z = z_bottom + max((lamp_z - 0.16) * height, 0.35)  # trucks' lamps sit low
    for x in (front - 0.5 * depth, back + 0.5 * depth):
        builder.add(box((x, 0.0, bumper_z), bumper), palette.TRIM_RGB, smooth=False)
    builder.add(box((front - 0.5 * depth, 0.0, z_bottom + lamp_z * height),
                    (depth, 0.3 * width, 0.06 * height)), palette.TRIM_RGB, smooth=False)  # fmt: skip


def mirrors(builder: MeshBuilder, x: float, z: float, size: NDArray, paint: tuple) -> None:
    half_width = 0.5 * size[1]
    for side in (1, -1):
        builder.add(box((x, side * (half_width - 0.05), z), (0.10, 0.10, 0.09)), paint,
                    Material.PAINT, smooth=False)  # fmt: skip


STYLES = {"sedan": SEDAN, "compact": HATCHBACK, "hatchback": HATCHBACK, "suv": SUV,
          "van": VAN, "minibus": MINIBUS}  # fmt: skip


def car_like(style: BodyStyle, size: NDArray, paint: tuple) -> ModelMesh:
    """A car or van of `style` filling a box of `size` (length, width, height), centred."""
    builder = MeshBuilder()
    length, _, height = size
    z_bottom = -0.5 * height
    x0, x1 = -0.5 * length + BODY_END * length, 0.5 * length - BODY_END * length
    hull(builder, style, x0, x1, size, paint, z_bottom)
    radius = style.wheel_radius * height
    wheels(builder, [-0.5 * length + a * length for a in style.axles], radius, size, z_bottom)
    lamps_and_bumpers(builder, size, z_bottom, style.lamp_z, style.tail_z)
    front_glass = max(s[0] for s in style.sections if s[3] > s[2] + 0.05)  # the A pillar
    mirrors(builder, x0 + (front_glass - 0.02) * (x1 - x0),
            z_bottom + style.sections[-1][2] * height + 0.12 * height, size, paint)  # fmt: skip
    return builder.build(wheel_radius_m=radius)


def truck(size: NDArray, paint: tuple, cargo: tuple, tractor: bool) -> ModelMesh:
    """A cab at the front and a cargo box (or, for a tractor, a trailer) behind it."""
    builder = MeshBuilder()
    length, width, height = size
    z_bottom = -0.5 * height
    cab_length = min(2.4, 0.3 * length)
    cab_x0 = 0.5 * length - BODY_END * length - cab_length
    cab_size = np.array([cab_length, width, 0.86 * height])
    hull(builder, CAB, cab_x0, 0.5 * length - BODY_END * length, cab_size, paint, z_bottom)
    radius = (0.13 if tractor else 0.15) * height
    gap = 0.35 if tractor else 0.15
    box_x1 = cab_x0 - gap
    box_bottom = z_bottom + 2 * radius + 0.12
    builder.add(box(((-0.5 * length + box_x1) / 2, 0.0, (box_bottom + 0.5 * height) / 2),
                    (box_x1 + 0.5 * length, width, 0.5 * height - box_bottom)), cargo,
                Material.PAINT, smooth=False)  # fmt: skip
    chassis_top = z_bottom + 2 * radius
    builder.add(box((0.0, 0.0, chassis_top - 0.12), (length * 0.96, 0.7 * width, 0.24)),
                palette.TRIM_RGB, smooth=False)  # fmt: skip
    front_axle = cab_x0 + 0.55 * cab_length
    rear = [-0.5 * length + 0.16 * length, -0.5 * length + 0.27 * length]
    axles = [front_axle, *(rear if tractor else rear[:1])]
    if tractor:
        axles.append(cab_x0 - 0.1)
    wheels(builder, axles, radius, size, z_bottom)
    lamps_and_bumpers(builder, size, z_bottom, 0.18, 0.22)
    mirrors(builder, cab_x0 + 0.85 * cab_length, z_bottom + 0.55 * height, size, paint)
    return builder.build(wheel_radius_m=radius)


def bus(size: NDArray, paint: tuple, articulated: bool) -> ModelMesh:
    """A city bus: a band of windows along both sides, a windscreen, doors on the right side
    (-y: traffic keeps right in the sources' countries), one body or two with a bellows."""
    builder = MeshBuilder()
    length, width, height = size
    z_bottom = -0.5 * height
    x0, x1 = -0.5 * length + BODY_END * length, 0.5 * length - BODY_END * length
    bodies = [(x0, x1)]
    if articulated:
        middle = x0 + 0.45 * (x1 - x0)
        bodies = [(x0, middle - 0.35), (middle + 0.35, x1)]
        builder.add(box((middle, 0.0, 0.05 * height), (0.8, 0.85 * width, 0.8 * height)),
                    palette.TRIM_RGB, smooth=False)  # fmt: skip
    for start, end in bodies:
        hull(builder, BUS, start, end, size, paint, z_bottom)
    depth = BODY_END * length + 0.02
    builder.add(box((0.5 * length - 0.5 * depth, 0.0, z_bottom + 0.66 * height),
                    (depth, 0.86 * width, 0.52 * height)), palette.GLASS_RGB, Material.GLASS,
                smooth=False)  # fmt: skip
    door_width = 1.1
    for door_x in (x1 - 1.6, 0.5 * (x0 + x1) - 0.6):
        builder.add(box((door_x, -0.5 * width + 0.015, z_bottom + 0.5 * height),
                        (door_width, 0.03, 0.78 * height)), palette.GLASS_RGB, Material.GLASS,
                    smooth=False)  # fmt: skip
    radius = BUS.wheel_radius * height
    axles = [x0 + 0.12 * (x1 - x0), x1 - 0.2 * (x1 - x0)]
    if articulated:
        axles.insert(1, x0 + 0.58 * (x1 - x0))
    wheels(builder, axles, radius, size, z_bottom)
    lamps_and_bumpers(builder, size, z_bottom, BUS.lamp_z, BUS.tail_z)
    mirrors(builder, x1 - 0.3, z_bottom + 0.75 * height, size, palette.TRIM_RGB)
    return builder.build(wheel_radius_m=radius)


# Where a vehicle's instance colours go: a shape is built once per blueprint and size with these
# in place of its paint and cargo colours (no colour is negative), and each instance's colours
# are put where they stand (`vehicle_model`). Building a car took 5 ms; a clip's set-up builds
# dozens of them, of a few blueprints.
PAINT_SLOT = (-1.0, -1.0, -1.0)
CARGO_SLOT = (-2.0, -2.0, -2.0)


@functools.lru_cache(maxsize=64)
def vehicle_shape(blueprint: str, size_m: tuple[float, float, float]) -> ModelMesh:
    """The model of a motor vehicle blueprint (`sim.actors.BLUEPRINTS`) filling `size_m`, with
    `PAINT_SLOT` and `CARGO_SLOT` for its instance colours."""
    size = np.asarray(size_m, dtype=np.float64)
    if blueprint in STYLES:
        return car_like(STYLES[blueprint], size, PAINT_SLOT)
    if blueprint in ("box_truck", "truck"):
        return truck(size, PAINT_SLOT, CARGO_SLOT, tractor=blueprint == "truck")
    if blueprint in ("bus", "articulated_bus"):
        return bus(size, PAINT_SLOT, blueprint == "articulated_bus")
    raise ValueError(f"blueprint {blueprint!r} is not a motor vehicle")


def vehicle_model(blueprint: str, size_m: tuple[float, float, float], instance: str) -> ModelMesh:
    """The model of a motor vehicle blueprint (`sim.actors.BLUEPRINTS`) filling `size_m`, its
    colours drawn from `instance` (a track id): `vehicle_shape`, painted. Its arrays but the
    colours are the shape's, shared with every instance of the blueprint (never written)."""
    shape = vehicle_shape(blueprint, tuple(size_m))
    rng = palette.instance_rng(instance)
    if blueprint in ("minibus", "bus", "articulated_bus"):
        paint, cargo = palette.pick(palette.BUS_COLOURS, rng), None
    else:
        paint = palette.car_colour(rng)
        cargo = (
            palette.pick(palette.CARGO_COLOURS, rng)
            if blueprint in ("box_truck", "truck")
            else None
        )
    colours = shape.colours.copy()
    for slot, rgb in ((PAINT_SLOT, paint), (CARGO_SLOT, cargo)):
        if rgb is not None:
            colours[(shape.colours == np.float32(slot[0])).all(axis=1)] = rgb
    return dataclasses.replace(shape, colours=colours)
