"""Topic names of a clip's log (ARCHITECTURE.md, "The MCAP contract") and which are per frame."""

from __future__ import annotations

CAMERAS = (
    "CAM_FRONT",
    "CAM_FRONT_RIGHT",
    "CAM_FRONT_LEFT",
    "CAM_BACK",
    "CAM_BACK_LEFT",
    "CAM_BACK_RIGHT",
)
RADARS = (
    "RADAR_FRONT",
    "RADAR_FRONT_LEFT",
    "RADAR_FRONT_RIGHT",
    "RADAR_BACK_LEFT",
    "RADAR_BACK_RIGHT",
)
LIDAR = "/LIDAR_TOP"
TF = "/tf"
GNSS = "/gnss"
IMU = "/imu"
EGO_STATE = "/ego/state"
OBJECTS = "/annotations/objects"
SCENE = "/annotations/scene"
TRAFFIC_LIGHTS = "/traffic_lights"
BEV = "/bev"
MAP = "/map"  # once, at the first frame

# frame ids of /tf: the world, the ego (rear axle), each sensor by its name
WORLD_FRAME = "world"
EGO_FRAME = "ego"

# metadata record names
SCENARIO_METADATA = "drivee2e.scenario"
RIG_METADATA = "drivee2e.rig"
COLLECTION_METADATA = "drivee2e.collection"
FRAMES_METADATA = "drivee2e.frames"  # written last: first frame, count, times
CAMERA_LABELS_METADATA = "drivee2e.camera_labels"  # only in logs collected with camera labels


def image_topic(camera: str) -> str:
    return f"/{camera}/image_compressed"


def camera_label_topic(camera: str, kind: str) -> str:
    """`/CAM_FRONT/depth`, `/CAM_FRONT/semantic`, `/CAM_FRONT/instance` (PNG images)."""
    return f"/{camera}/{kind}"


def camera_info_topic(camera: str) -> str:
    return f"/{camera}/camera_info"


def exposure_topic(camera: str) -> str:
    """`/CAM_FRONT/exposure`: the camera's exposure at each sensor frame (look 10 on)."""
    return f"/{camera}/exposure"


def radar_topic(radar: str) -> str:
    return f"/{radar}"


# what a log carries at every frame, also between sensor frames (`collect --sensor-hz 2`)
STATE_TOPICS = (TF, GNSS, IMU, EGO_STATE, TRAFFIC_LIGHTS)
SENSOR_RATES_HZ = (10, 5, 2, 1)  # 10 Hz frames; sensors at every, 2nd, 5th or 10th
FRAME_RATE_HZ = 10


def sensor_every(sensor_hz: int) -> int:
    """Sensors at every n-th frame for sensors at `sensor_hz` (one of `SENSOR_RATES_HZ`)."""
    if sensor_hz not in SENSOR_RATES_HZ:
        rates = ", ".join(map(str, SENSOR_RATES_HZ))
        raise ValueError(f"sensor_hz {sensor_hz}: expected one of {rates}")
    return FRAME_RATE_HZ // sensor_hz


def per_frame_topics(cameras: tuple[str, ...] = CAMERAS, exposure: bool = True) -> tuple[str, ...]:
    """Every topic a log carries at every frame, given the cameras it records (and whether it
    records their exposure: logs of looks before 10 do not)."""
    return (
        *(image_topic(c) for c in cameras),
        *(camera_info_topic(c) for c in cameras),
        *(exposure_topic(c) for c in cameras if exposure),
        LIDAR,
        *(radar_topic(r) for r in RADARS),
        TF,
        GNSS,
        IMU,
        EGO_STATE,
        OBJECTS,
        SCENE,
        TRAFFIC_LIGHTS,
        BEV,
    )
