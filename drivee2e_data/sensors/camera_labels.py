"""Dense per-camera labels from the same render as the RGB: metric depth, a semantic class and
an agent instance per pixel, kept at 1/`scale` of the camera's resolution (nearest pixel
centres) and written as lossless PNGs.

- depth: uint16 millimetres along the optical axis (the camera's z); 0 where nothing was hit
  (sky) or beyond 65.535 m.
- semantic: uint8 index into `SEMANTIC_CLASSES` (fixed; documented in docs/logs.md).
- instance: uint16, 0 for no agent, else 1 + the agent's index in the clip's track list; the
  log's `drivee2e.camera_labels` metadata maps each index to its track id (the boxes'
  instance ids).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.arrays import nearest_indices
from drivee2e_data.scenario import AgentClass

LABEL_KINDS = ("depth", "semantic", "instance")
DEFAULT_LABEL_SCALE = 4
SEMANTIC_CLASSES: tuple[str, ...] = (
    "other",
    "road",
    "lane_marking",
    "crosswalk",
    "stop_line",
    "sidewalk",
    "building",
    "vegetation",
    "pole",
    "traffic_light",
    *(c.value for c in AgentClass),
    "sky",
)
# the twin's surface kinds (sim.twin) as semantic classes; ground and obstacles are "other"
_KIND_CLASS = {
    "road": "road",
    "road_mark": "lane_marking",
    "crosswalk": "crosswalk",
    "stop_line": "stop_line",
    "sidewalk": "sidewalk",
    "building": "building",
    "vegetation": "vegetation",
    "pole": "pole",
    "signal": "traffic_light",
}
SKY = SEMANTIC_CLASSES.index("sky")
MAX_DEPTH_MM = 65535


@dataclass(frozen=True)
class LabelTables:
    """Per pybullet body id: its semantic class and instance value (index 0 is body -1,
    nothing)."""

    semantic: NDArray[np.uint8]
    instance: NDArray[np.uint16]

    @classmethod
    def build(
        cls,
        surface_kinds: dict[int, str],
        agent_bodies: dict[str, int],
        agent_classes: dict[str, AgentClass],
        instance_index: dict[str, int],
    ) -> LabelTables:
        largest = max([*surface_kinds, *agent_bodies.values(), 0])
        semantic = np.zeros(largest + 2, np.uint8)
        instance = np.zeros(largest + 2, np.uint16)
        semantic[0] = SKY
        for body, kind in surface_kinds.items():
            semantic[body + 1] = SEMANTIC_CLASSES.index(_KIND_CLASS.get(kind, "other"))
        for track_id, body in agent_bodies.items():
            semantic[body + 1] = SEMANTIC_CLASSES.index(agent_classes[track_id].value)
            instance[body + 1] = instance_index[track_id] + 1
        return cls(semantic, instance)


def label_images(
    depth_m: NDArray[np.float32],
    body_mask: NDArray[np.int32],
    tables: LabelTables,
    scale: int,
    kinds: tuple[str, ...] = LABEL_KINDS,
    size: tuple[int, int] | None = None,
) -> dict[str, NDArray]:
    """The label images of one rendered view at 1/`scale` of the camera's `size` (width,
    height; None: the arrays' own), by kind: each label pixel takes the drawn pixel under the
    centre of the camera pixel it stands for."""
    offset = scale // 2
    width, height = size or body_mask.shape[::-1]
    rows = nearest_indices(height, body_mask.shape[0])[offset::scale, None]
    columns = nearest_indices(width, body_mask.shape[1])[offset::scale]
    mask = body_mask[rows, columns]
    lookup = np.clip(mask + 1, 0, len(tables.semantic) - 1)
    result: dict[str, NDArray] = {}
    if "depth" in kinds:
        depth = depth_m[rows, columns]
        millimetres = np.rint(depth * 1000.0)
        millimetres[(mask < 0) | (millimetres > MAX_DEPTH_MM)] = 0
        result["depth"] = millimetres.astype(np.uint16)
    if "semantic" in kinds:
        result["semantic"] = tables.semantic[lookup]
    if "instance" in kinds:
        result["instance"] = tables.instance[lookup]
    return result


def encode_png(image: NDArray) -> bytes:
    """Lossless PNG (8- or 16-bit, one channel), fast compression."""
    import cv2

    ok, encoded = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise ValueError("PNG encoding failed")
    return encoded.tobytes()


def decode_png(data: bytes) -> NDArray:
    import cv2

    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError("not a decodable PNG")
    return image
