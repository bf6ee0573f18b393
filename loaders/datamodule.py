"""`DriveE2EDataModule`: the train/val/test DataLoaders of one split set. A Lightning
`LightningDataModule` when Lightning is installed (`pip install 'drivee2e-data[lightning]'`),
a plain class with the same methods otherwise.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from torch.utils.data import DataLoader, DistributedSampler

from drivee2e_data.loaders.collate import collate, decode_jpegs
from drivee2e_data.loaders.dataset import DriveE2EDataset

try:  # Lightning is optional
    from lightning.pytorch import LightningDataModule as _Base
except ImportError:
    try:
        from pytorch_lightning import LightningDataModule as _Base
    except ImportError:
        _Base = object


class DriveE2EDataModule(_Base):  # type: ignore[misc, valid-type]
    """DataLoaders over `DriveE2EDataset(root, split, split_name, **dataset_options)`.

    Training shuffles (seeded by `seed`); every loader keeps its workers alive between epochs
    when `num_workers > 0`. Under `torch.distributed` (without Lightning, which adds its own
    sampler) each loader gets a `DistributedSampler`.
    """

    def __init__(
        self,
        root: str | Path,
        split_name: str = "default",
        batch_size: int = 4,
        num_workers: int = 2,
        seed: int = 0,
        **dataset_options: Any,
    ) -> None:
        super().__init__()
        self.root, self.split_name = Path(root), split_name
        self.batch_size, self.num_workers, self.seed = batch_size, num_workers, seed
        self.dataset_options = dataset_options
        self.datasets: dict[str, DriveE2EDataset] = {}

    def setup(self, stage: str | None = None) -> None:
        """Index the splits a stage needs (fit: train and val; validate, test; None: all)."""
        wanted = {"fit": ("train", "val"), "validate": ("val",), "test": ("test",)}.get(
            stage or "", ("train", "val", "test")
        )
        for split in wanted:
            self._dataset(split)

    def _dataset(self, split: str) -> DriveE2EDataset:
        if split not in self.datasets:
            self.datasets[split] = DriveE2EDataset(
                self.root, split, self.split_name, **self.dataset_options
            )
        return self.datasets[split]

    def _loader(self, split: str, shuffle: bool) -> DataLoader:
        dataset = self._dataset(split)  # a loader may be asked for without setup
        sampler = None
        lightning = _Base is not object
        if (
            not lightning
            and torch.distributed.is_available()
            and torch.distributed.is_initialized()
        ):
            sampler = DistributedSampler(dataset, shuffle=shuffle, seed=self.seed)
        generator = torch.Generator().manual_seed(self.seed)
        return DataLoader(
            dataset,
            batch_size=self.batch_size,
            shuffle=shuffle and sampler is None,
            sampler=sampler,
            num_workers=self.num_workers,
            persistent_workers=self.num_workers > 0,
            collate_fn=collate,
            generator=generator,
        )

    def train_dataloader(self) -> DataLoader:
        return self._loader("train", shuffle=True)

    def val_dataloader(self) -> DataLoader:
        return self._loader("val", shuffle=False)

    def test_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)

    def decode(self, batch: dict[str, Any], device: str | torch.device = "cuda") -> dict[str, Any]:
        """For `decode="none"`: the batch's JPEGs decoded on `device` into `img`."""
        if "img_jpeg" not in batch:
            return batch
        dataset = next(iter(self.datasets.values()))
        first = dataset.log_info[dataset.samples[0][0]]["cameras"][dataset.cameras[0]]
        return decode_jpegs(batch, first["full_size"], dataset.image_size, device)

    def on_after_batch_transfer(self, batch: dict[str, Any], dataloader_idx: int) -> dict[str, Any]:
        """Lightning's hook on the training device: decode JPEGs there (nvJPEG on CUDA)."""
        device = batch["gt_ego_fut_trajs"].device
        return self.decode(batch, device)
