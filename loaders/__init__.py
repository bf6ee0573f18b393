"""The torch data module: nuScenes-compatible samples read from the collected MCAP logs, split
2:1:1 by the manifests under `splits/`. Needs neither the simulator nor a GPU.
"""

from drivee2e_data.loaders.clip import CLASSES, ClipLabels, read_clip
from drivee2e_data.loaders.collate import collate, decode_jpegs
from drivee2e_data.loaders.datamodule import DriveE2EDataModule
from drivee2e_data.loaders.dataset import DriveE2EDataset

__all__ = [
    "CLASSES",
    "ClipLabels",
    "DriveE2EDataModule",
    "DriveE2EDataset",
    "collate",
    "decode_jpegs",
    "read_clip",
]
