"""Per-frame box annotations: 3D corners, the share of a box's projected area a camera sees
(from the segmentation mask or the depth image, binned as nuScenes does), and sensor points
inside a box.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import shapely
from numpy.typing import NDArray

from drivee2e_data.scenario import Track
from drivee2e_data.sensors.camera import FAR_M, NEAR_M, CameraFrame, DrawnView, camera_to_world
from drivee2e_data.sim.world import depth_step_m

# nuScenes visibility levels: 1: 0-40%, 2: 40-60%, 3: 60-80%, 4: 80-100% of the box seen
VISIBILITY_BINS = (0.4, 0.6, 0.8)


def box_corners_3d(
    track: Track, frame: int, size_m: tuple[float, float, float] | None = None
) -> NDArray[np.float64]:
    """(8, 3) world corners of the track's box at `frame` (optionally with another size, e.g. the
    blueprint's), bottom face first."""
    length, width, height = size_m or (
        track.length_m[frame],
        track.width_m[frame],
        track.height_m[frame],
    )
    ground = track.z_m[frame] - 0.5 * track.height_m[frame]
    corners = np.array(
        [
            [sx * length / 2, sy * width / 2, sz * height]
            for sz in (0, 1)
            for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1))
        ]
    )
    c, s = np.cos(track.yaw_rad[frame]), np.sin(track.yaw_rad[frame])
    rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return corners @ rotation.T + np.array([track.x_m[frame], track.y_m[frame], ground])


def projected_area(
    frame: CameraFrame, corners_world: NDArray[np.float64], ego_to_world: NDArray[np.float64]
) -> shapely.Geometry:
    """The box's projection clipped to the image, as a polygon in pixels (empty when behind,
    or when less than a polygon shows): `image_outline` of its corners in front."""
    in_front, pixels = _image_points(frame, corners_world[None], ego_to_world)
    if not _over_image(frame, in_front, pixels)[0]:
        return shapely.Polygon()  # behind, or wholly beside the image: no hull, no clip
    camera = frame.camera
    outline = image_outline(pixels[0][in_front[0]], camera.width, camera.height)
    return shapely.Polygon() if outline is None else shapely.Polygon(outline)


def _image_points(
    frame: DrawnView | CameraFrame,
    corners_world: NDArray[np.float64],
    ego_to_world: NDArray[np.float64],
) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
    """Boxes' corners `(B, 8, 3)` in the camera's image: which lie in front of it `(B, 8)` and
    their pixels `(B, 8, 2)` (meaningless where behind)."""
    camera = frame.camera
    to_world = camera_to_world(camera, ego_to_world)
    # a rigid transform's inverse: rotation transposed
    points = (corners_world - to_world[:3, 3]) @ to_world[:3, :3]
    with np.errstate(divide="ignore", invalid="ignore"):
        pixels = points @ camera.intrinsic.T
        return points[..., 2] > 0.1, pixels[..., :2] / pixels[..., 2:3]


def _over_image(
    frame: DrawnView | CameraFrame, in_front: NDArray[np.bool_], pixels: NDArray[np.float64]
) -> NDArray[np.bool_]:
    """(B,) whether each box (`_image_points`) may show in the image: a corner in front of the
    camera, and the bounding rectangle of those over the image."""
    camera = frame.camera
    low = np.where(in_front[..., None], pixels, np.inf).min(axis=1)
    high = np.where(in_front[..., None], pixels, -np.inf).max(axis=1)
    beside = (
        (high[:, 0] <= 0) | (high[:, 1] <= 0)
        | (low[:, 0] >= camera.width) | (low[:, 1] >= camera.height)
    )  # fmt: skip
    return in_front.any(axis=1) & ~beside


def visible_share(
    frame: CameraFrame,
    body: int,
    corners_world: NDArray[np.float64],
    ego_to_world: NDArray[np.float64],
) -> float:
    """Share of the box's projected area (in the image) not hidden by something in front of
    the box, counted in the view as drawn. A pixel is hidden when what it shows is not the body
    (by the body mask where the view has one, else by depth: the point its depth puts in the
    world lies outside the box, see `DEPTH_MARGIN_M`) and lies nearer than where the pixel's
    ray enters the box. A pixel that sees past the agent's model through its box (between a
    walker's legs, over a car's bonnet) is not hidden: the models fill their boxes only
    partly, and visibility is about occlusion, as nuScenes' annotators judge it. An agent none
    of whose own pixels shows is not visible (0)."""
    return float(visible_shares(frame, [body], corners_world[None], ego_to_world)[0])


@dataclass(frozen=True)
class DepthPixels:
    """The pixels of a view box visibility reads the depth at (`depth_pixels`): of each box
    among those asked that may show (`boxes`, their indices), `counts` pixels, laid end to end
    in `rows` and `columns` (of the view as drawn)."""

    boxes: NDArray[np.intp]  # (K,)
    counts: NDArray[np.intp]  # (K,)
    rows: NDArray[np.intp]  # (N,)
    columns: NDArray[np.intp]  # (N,)

    @property
    def texels(self) -> NDArray[np.int32]:
        """(N, 2) column and row of each pixel: what the renderer gathers (`render`'s
        `depth_at`)."""
        return np.stack([self.columns, self.rows], axis=1).astype(np.int32)


def depth_pixels(
    view: DrawnView | CameraFrame,
    corners_world: NDArray[np.float64],
    ego_to_world: NDArray[np.float64],
) -> DepthPixels:
    """The pixels `visible_shares` tests for boxes `corners_world` (B, 8, 3) in a camera's view:
    each box's covered pixels (`_covered_pixels`), evenly thinned to `DEPTH_SAMPLES`. Geometry
    alone: known before the view is drawn, so that the renderer reads the depth at these alone
    (`camera.render`'s `depth_at`)."""
    in_front, pixels = _image_points(view, corners_world, ego_to_world)
    may_show = _over_image(view, in_front, pixels)
    boxes, picked = [], []
    for k, shows in enumerate(may_show):
        found = _covered_pixels(view, pixels[k][in_front[k]]) if shows else None
        if found is None:
            continue
        # a share needs no more than a few thousand of a near box's pixels: an even subsample
        rows, columns = found
        step = max(1, len(rows) // DEPTH_SAMPLES)
        boxes.append(k)
        picked.append((rows[::step], columns[::step]))
    if not boxes:
        empty = np.zeros(0, np.intp)
        return DepthPixels(empty, empty, empty, empty)
    return DepthPixels(
        np.array(boxes, np.intp),
        np.array([len(rows) for rows, _ in picked], np.intp),
        np.concatenate([rows for rows, _ in picked]),
        np.concatenate([columns for _, columns in picked]),
    )


def visible_shares(
    frame: CameraFrame,
    bodies: Sequence[int],
    corners_world: NDArray[np.float64],
    ego_to_world: NDArray[np.float64],
    pixels: DepthPixels | None = None,
) -> NDArray[np.float64]:
    """`visible_share` of each of B boxes (`bodies` (B,), `corners_world` (B, 8, 3)) in one
    view: the boxes' pixels gathered and tested together (a frame asks this of six views and
    up to a hundred boxes, and one box at a time the work was numpy's per-call overhead).
    `pixels`: `depth_pixels` of these boxes, as the view was drawn with (its `depth_samples`
    are the depth there); made here if not given."""
    shares = np.zeros(len(bodies))
    if pixels is None:
        if frame.depth_samples is not None:
            raise ValueError("a view drawn with depth samples needs the pixels they were read at")
        pixels = depth_pixels(frame, corners_world, ego_to_world)
    if not len(pixels.boxes):
        return shares
    boxes, counts, rows, columns = pixels.boxes, pixels.counts, pixels.rows, pixels.columns
    ends = np.cumsum(counts)
    box = np.repeat(np.arange(len(boxes)), counts)  # each pixel's box, among `boxes`
    scale_x, scale_y = frame.drawn_per_camera_px
    intrinsic = frame.camera.intrinsic
    if frame.depth_samples is not None:  # read at these pixels alone (`render`'s depth_at)
        depth = frame.depth_samples.astype(np.float64)
    else:
        depth = frame.depth_m[rows, columns].astype(np.float64)
    # rays as (3, N) rows of x, y, z (camera z = 1), so that every step below runs over
    # contiguous rows rather than across the short axis of (N, 3)
    rays = np.stack(
        [
            ((columns + 0.5) / scale_x - intrinsic[0, 2]) / intrinsic[0, 0],
            ((rows + 0.5) / scale_y - intrinsic[1, 2]) / intrinsic[1, 1],
            np.ones(len(rows)),
        ]
    )
    to_world = camera_to_world(frame.camera, ego_to_world)
    rays_world = to_world[:3, :3] @ rays
    margin = DEPTH_MARGIN_M + depth_resolution_m(frame, depth)
    origins, units, lengths = _box_frames(corners_world[boxes])
    # per pixel, in its box's frame: the camera (start), the ray's direction (along), the size
    start, along, size = (np.empty((3, len(rows))) for _ in range(3))
    camera_in_boxes = np.einsum("bij,bj->bi", units, to_world[:3, 3] - origins)
    for k, (first, end) in enumerate(zip(ends - counts, ends, strict=True)):
        along[:, first:end] = units[k] @ rays_world[:, first:end]
        start[:, first:end] = camera_in_boxes[k][:, None]
        size[:, first:end] = lengths[k][:, None]
    if frame.mask is not None:
        on_body = frame.mask[rows, columns] == np.asarray(bodies)[boxes][box]
    else:
        # where the pixel's depth puts its surface, in the box's frame
        metres = start + depth * along
        on_body = (
            (metres[0] >= -margin) & (metres[1] >= -margin) & (metres[2] >= ABOVE_BOTTOM_M)
            & (metres[0] <= size[0] + margin) & (metres[1] <= size[1] + margin)
            & (metres[2] <= size[2] + margin)
        )  # fmt: skip
    entry = _entry_depths(start, along, size)
    through = np.isfinite(entry)  # a pixel on the outline's edge may pass beside the box
    hidden = through & ~on_body & (depth < entry - margin)
    seen = np.bincount(box, weights=through & on_body, minlength=len(boxes))
    passing = np.bincount(box, weights=through, minlength=len(boxes))
    hidden_count = np.bincount(box, weights=hidden, minlength=len(boxes))
    # nothing of the agent drawn: not seen, whatever shows through its box
    with np.errstate(divide="ignore", invalid="ignore"):
        share = np.where(seen > 0, 1.0 - hidden_count / passing, 0.0)
    shares[boxes] = share
    return shares


FLOAT_DEPTH_STEP = 2.0**-22  # float32's relative step (two units in the last place), with margin


def depth_resolution_m(frame: CameraFrame, depth_m: NDArray[np.float64]) -> NDArray[np.float64]:
    """How finely the view's depth resolves a surface at each depth `depth_m`: float32's step
    for the GL renderer's depth (written by the shader: micrometres at 100 m), a 16-bit depth
    buffer's (`world.depth_step_m`: centimetres at 30 m, decimetres at 100 m) for pybullet's
    renderers."""
    if frame.float_depth:
        return depth_m * FLOAT_DEPTH_STEP
    return depth_step_m(depth_m, NEAR_M, FAR_M)


def _entry_depths(
    start: NDArray[np.float64], along: NDArray[np.float64], size: NDArray[np.float64]
) -> NDArray[np.float64]:
    """(N,) the depth (camera z, as the rays are scaled: z = 1) at which each ray enters its
    box (slab test), given (3, N) in the box's frame: the camera (`start`), the ray's direction
    (`along`) and the box's size; inf for rays that miss it."""
    near = np.full(start.shape[1], -np.inf)
    far = np.full(start.shape[1], np.inf)
    misses = np.zeros(start.shape[1], bool)
    for axis in range(3):
        moving = along[axis] != 0
        with np.errstate(divide="ignore", invalid="ignore"):
            low = (0.0 - start[axis]) / along[axis]
            high = (size[axis] - start[axis]) / along[axis]
        np.maximum(near, np.where(moving, np.minimum(low, high), -np.inf), out=near)
        np.minimum(far, np.where(moving, np.maximum(low, high), np.inf), out=far)
        # a ray parallel to a slab misses the box unless it runs inside that slab
        misses |= ~moving & ((start[axis] < 0) | (start[axis] > size[axis]))
    return np.where((near <= far) & ~misses, np.maximum(near, 0.0), np.inf)


# a surface point belongs to a box within this much (plus the depth's resolution there,
# `depth_resolution_m`: float for the GL renderer, 16 bits for pybullet's) of its sides and
# top, and at least ABOVE_BOTTOM_M above its bottom face (the road is not the box)
DEPTH_MARGIN_M = 0.05
ABOVE_BOTTOM_M = 0.02
DEPTH_SAMPLES = 4000  # pixels per box at most for the share by depth


def _covered_pixels(
    frame: DrawnView | CameraFrame, corners_px: NDArray[np.float64]
) -> tuple[NDArray[np.intp], NDArray[np.intp]] | None:
    """Rows and columns (of the view as drawn) inside the projection of a box whose corners in
    front of the camera project to `corners_px` `(K, 2)` (camera pixels); None if none. A
    large projection is sampled on a grid of every `stride`-th pixel each way, keeping at least
    4 * `DEPTH_SAMPLES` of its pixels (the share is then thinned to `DEPTH_SAMPLES` as any box's
    is): filling a near bus's half million pixels to keep four thousand of them was most of
    box visibility's time."""
    camera = frame.camera
    vertices = image_outline(corners_px, camera.width, camera.height)
    if vertices is None:
        return None
    scale_x, scale_y = frame.drawn_per_camera_px
    if (scale_x, scale_y) != (1.0, 1.0):  # drawn smaller (pybullet's EGL renderer)
        vertices = [(x * scale_x, y * scale_y) for x, y in vertices]
    area = polygon_area(vertices)
    if area < 1.0:
        return None
    height, width = frame.drawn_shape
    xs, ys = [x for x, _ in vertices], [y for _, y in vertices]
    x0, y0 = int(np.floor(min(xs))), int(np.floor(min(ys)))
    x1 = min(int(np.ceil(max(xs))), width)
    y1 = min(int(np.ceil(max(ys))), height)
    if x1 <= x0 or y1 <= y0:
        return None
    stride = max(1, int(np.sqrt(area / (4 * DEPTH_SAMPLES))))
    inside = np.zeros((-(-(y1 - y0) // stride), -(-(x1 - x0) // stride)), np.uint8)
    # grid cell k stands for pixel k * stride, whose centre k * stride + 0.5 lands on the
    # cell's centre k + 0.5; 4 bits of sub-pixel precision
    outline = ((np.array(vertices) - (x0 + 0.5, y0 + 0.5)) / stride + 0.5) * 16
    cv2.fillPoly(inside, [np.round(outline).astype(np.int32)], 1, lineType=cv2.LINE_8, shift=4)
    rows, columns = np.nonzero(inside)
    if len(rows) == 0:
        return None
    return rows * stride + y0, columns * stride + x0


def image_outline(
    points_px: NDArray[np.float64], width: float, height: float
) -> list[tuple[float, float]] | None:
    """The convex hull of `points_px` `(K, 2)` clipped to the image `[0, width] x [0, height]`,
    as its M >= 3 vertices (x, y) in order around it; None when less than a polygon is left.
    Shapely's hull and intersection give the same polygon in twice the time for a box's eight
    corners (its objects cost more than the geometry): a frame asks this of hundreds of
    boxes."""
    hull = _convex_hull([(float(x), float(y)) for x, y in points_px])
    if len(hull) < 3:
        return None
    # Sutherland-Hodgman against the image's four sides, each as (axis, bound, keep low side)
    for axis, bound, low_side in ((0, 0.0, False), (0, width, True), (1, 0.0, False),
                                  (1, height, True)):  # fmt: skip
        clipped = []
        previous = hull[-1]
        previous_in = (previous[axis] <= bound) if low_side else (previous[axis] >= bound)
        for point in hull:
            point_in = (point[axis] <= bound) if low_side else (point[axis] >= bound)
            if point_in != previous_in:
                t = (bound - previous[axis]) / (point[axis] - previous[axis])
                crossing = [previous[0] + t * (point[0] - previous[0]),
                            previous[1] + t * (point[1] - previous[1])]  # fmt: skip
                crossing[axis] = bound
                clipped.append((crossing[0], crossing[1]))
            if point_in:
                clipped.append(point)
            previous, previous_in = point, point_in
        hull = clipped
        if len(hull) < 3:
            return None
    return hull


def _convex_hull(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Andrew's monotone chain over a few points: the hull's vertices, no three collinear."""
    points = sorted(set(points))
    if len(points) < 3:
        return points

    def turn(o: tuple[float, float], a: tuple[float, float], b: tuple[float, float]) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list[tuple[float, float]] = []
    for point in points:
        while len(lower) >= 2 and turn(lower[-2], lower[-1], point) <= 0:
            lower.pop()
        lower.append(point)
    upper: list[tuple[float, float]] = []
    for point in reversed(points):
        while len(upper) >= 2 and turn(upper[-2], upper[-1], point) <= 0:
            upper.pop()
        upper.append(point)
    return lower[:-1] + upper[:-1]


def polygon_area(vertices: Sequence[tuple[float, float]]) -> float:
    """Area of a simple polygon given by its vertices (x, y) in order (shoelace), whichever
    way round."""
    twice = 0.0
    previous = vertices[-1]
    for point in vertices:
        twice += previous[0] * point[1] - previous[1] * point[0]
        previous = point
    return 0.5 * abs(twice)


def _box_frame(
    corners_world: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """A box (corners bottom face first) as its corner at (-l/2, -w/2, bottom) `(3,)`, its unit
    axes along length, width and height `(3, 3)` and its size along them `(3,)`."""
    origins, units, lengths = _box_frames(corners_world[None])
    return origins[0], units[0], lengths[0]


def _box_frames(
    corners_world: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """`_box_frame` of B boxes `(B, 8, 3)`: corners `(B, 3)`, axes `(B, 3, 3)`, sizes `(B, 3)`."""
    origins = corners_world[:, 2]
    axes = np.stack(
        [corners_world[:, 1] - origins, corners_world[:, 3] - origins,
         corners_world[:, 6] - origins], axis=1
    )  # fmt: skip
    lengths = np.linalg.norm(axes, axis=2)
    return origins, axes / lengths[..., None], lengths


def _box_metres(
    points_world: NDArray[np.float64], corners_world: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Points `(N, 3)` in metres along the box's axes from its corner, and the box's size."""
    origin, units, lengths = _box_frame(corners_world)
    return (points_world - origin) @ units.T, lengths


def visibility_level(share: float) -> int:
    """nuScenes visibility token 1-4 for a seen share; 0 for a box not seen at all."""
    if share <= 0.0:
        return 0
    return 1 + int(np.searchsorted(VISIBILITY_BINS, share, side="right"))


def points_in_box(
    points_world: NDArray[np.float64], corners_world: NDArray[np.float64], margin_m: float = 0.0
) -> int:
    """How many points `(N, 3)` lie inside the box with these 8 corners (bottom face first),
    grown by `margin_m` on every face."""
    metres, lengths = _box_metres(points_world, corners_world)
    return int(np.all((metres >= -margin_m) & (metres <= lengths + margin_m), axis=1).sum())
