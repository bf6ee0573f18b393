"""The torch data module: nuScenes-compatible samples read from the collected MCAP logs, split
2:1:1 by the manifests under `splits/`. Needs neither the simulator nor a GPU.
"""

from typing import Any

from drivee2e_data.loaders.clip import CLASSES, ClipLabels, read_clip
from drivee2e_data.loaders.collate import collate, decode_jpegs
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


def __getattr__(name: str) -> Any:
    # the data module on first use: it imports Lightning where installed, and Lightning
    # imports torchmetrics and torchvision, 8.7 s on an H100-class host, which every user of
    # the cache or the Dataset (each closed-loop worker's agent) had paid at import
    if name == "DriveE2EDataModule":
        from drivee2e_data.loaders.datamodule import DriveE2EDataModule

        return DriveE2EDataModule
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
