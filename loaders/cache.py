"""Feature caches: what a model reads from a split's samples, decoded once and kept as
memory-mapped arrays, so that training and open-loop evaluation read arrays at memory speed
instead of walking the logs sample by sample.

A model declares its features once (`FeatureSpec`: the sample fields it reads, its cameras and
their size); `build` writes them for one split, one clip per job over a process pool, into
`DATA/features/<spec key>/<scenario_id>-<log key>/`, one `.npy` file per field (`img` uint8
`(n, K, 3, H, W)`, the others as the Dataset returns them) plus `frames.npy`. The spec key names
the spec and the Dataset options it implies; the log key names the log's file (size, mtime) and
its collection record (look, frame-bytes version, renderer, options), so a cache is a pure
function of what it was built from: a re-collected log or another spec is another folder, never
a stale one reused. Each clip's folder is written under a temporary name and renamed when
complete, so a killed build resumes from the clips it finished.

`FeatureCache` reads a built split: the small fields in memory, images memory-mapped; a sample
(`cache[i]`) holds exactly what `DriveE2EDataset` returns for those fields (tested to the byte),
and `rows(indices)` gathers a batch. Why plain `.npy` files rather than a dataset library:
they need nothing beyond numpy, map straight into memory, and a batch is a fancy index; see
docs/benchmarks.md for the measured rates.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from drivee2e_data import splits
from drivee2e_data.errors import DriveE2EError
from drivee2e_data.loaders import sample as labels
from drivee2e_data.loaders.dataset import LOGS_FOLDER, DriveE2EDataset
from drivee2e_data.logs.reader import LogReader
from drivee2e_data.processes import process_running

CACHE_FOLDER = "features"
# what a clip's folder holds and how: a change here makes every cache another folder (2: images
# decoded only by JPEG reductions that divide the logged size, `images.reduction`)
CACHE_VERSION = 2
FRAMES_FILE = "frames.npy"
# the fields planners of the ego's state and the open-loop metrics read, all fixed in shape
EGO_FIELDS = (
    "gt_ego_his_trajs",
    "gt_ego_his_masks",
    "ego_status",
    "gt_ego_fut_cmd",
    "target_point",
    "gt_ego_fut_trajs",
    "gt_ego_fut_masks",
)


# what the open-loop metrics read beside the ego's future: its box, and every agent's future
# boxes (one row per annotated box: padded per batch, with `gt_boxes_mask`, as `collate` does)
SCORING_FIELDS = ("gt_ego_fut_trajs", "gt_ego_fut_masks", "ego_size", "ego_rear_axle_to_centre")
SCORING_BOX_FIELDS = ("gt_agent_fut_boxes", "gt_agent_fut_masks")
BOX_MASK = "gt_boxes_mask"


@dataclass(frozen=True)
class FeatureSpec:
    """What a model reads: fixed-shape sample fields, per-box fields (`box_fields`: one row per
    annotated box, padded per batch with `gt_boxes_mask`), and `cameras` decoded to
    `image_size` (width, height) as `img` when it reads images. `name` is for people (the
    folder's prefix)."""

    name: str
    fields: tuple[str, ...] = EGO_FIELDS
    cameras: tuple[str, ...] = ()
    image_size: tuple[int, int] | None = None
    frame_stride: int = 1
    history_s: float = 2.0
    future_s: float = 3.0
    box_fields: tuple[str, ...] = ()

    @property
    def reads_images(self) -> bool:
        return bool(self.cameras)

    @property
    def horizons(self) -> labels.Horizons:
        return labels.Horizons.of(self.history_s, self.future_s)

    def all_fields(self) -> tuple[str, ...]:
        fields = (*self.fields, *self.box_fields)
        return (*fields, "img") if self.reads_images else fields

    def dataset(self, root: Path, split: str, split_name: str = "default") -> DriveE2EDataset:
        """The log-reading Dataset this spec reads from (the reference the cache equals)."""
        return DriveE2EDataset(
            root,
            split,
            split_name,
            cameras=self.cameras,
            image_size=self.image_size,
            with_map=False,
            frame_stride=self.frame_stride,
            history_s=self.history_s,
            future_s=self.future_s,
        )

    def key(self) -> str:
        """The spec's folder name: its name and a hash of everything that shapes its arrays."""
        document = json.dumps({"version": CACHE_VERSION, **asdict(self)}, sort_keys=True)
        return f"{self.name}-{hashlib.sha256(document.encode()).hexdigest()[:12]}"


# what `drivee2e openloop` scores a predictions file with
SCORING = FeatureSpec("scoring", SCORING_FIELDS, box_fields=SCORING_BOX_FIELDS)

_log_keys: dict[tuple[str, int, int], str] = {}  # this process's, by (path, size, mtime)


def log_key(path: Path) -> str:
    """A log's identity: its file (size, modification time) and its collection record."""
    status = os.stat(path)
    memo = (str(path), status.st_size, status.st_mtime_ns)
    if memo not in _log_keys:
        with LogReader(path) as log:
            record = json.dumps(log.collection, sort_keys=True)
        document = f"{status.st_size}:{status.st_mtime_ns}:{record}"
        _log_keys[memo] = hashlib.sha256(document.encode()).hexdigest()[:12]
    return _log_keys[memo]


def _split_clips(root: Path, split: str, split_name: str) -> list[splits.ClipRow]:
    manifest = splits.split_path(root, split_name)
    return [r for r in splits.read_manifest(manifest) if split == "all" or r.split == split]


def spec_folder(root: Path, spec: FeatureSpec) -> Path:
    return Path(root) / CACHE_FOLDER / spec.key()


def clip_folder(root: Path, spec: FeatureSpec, scenario_id: str, key: str) -> Path:
    return spec_folder(root, spec) / f"{scenario_id}-{key}"


@dataclass
class BuildReport:
    """What `build` did: clips written now, clips found built, samples in the split."""

    folder: Path
    written: list[str] = field(default_factory=list)
    reused: list[str] = field(default_factory=list)
    samples: int = 0


def build(
    root: Path,
    spec: FeatureSpec,
    split: str,
    split_name: str = "default",
    workers: int = 1,
    on_samples: Callable[[int], None] | None = None,
) -> BuildReport:
    """Write the features of every clip of one split that is not cached yet for its current
    log; `on_samples(n)` as each clip's n samples are done (or found done)."""
    root = Path(root)
    report = BuildReport(spec_folder(root, spec))
    todo = []
    for row in _split_clips(root, split, split_name):
        log = root / LOGS_FOLDER / f"{row.scenario_id}.mcap"
        folder = clip_folder(root, spec, row.scenario_id, log_key(log)) if log.is_file() else None
        if folder is not None and folder.is_dir():
            report.reused.append(row.scenario_id)
            count = len(np.load(folder / FRAMES_FILE, mmap_mode="r"))
            report.samples += count
            if on_samples is not None:
                on_samples(count)
        else:
            todo.append(row.scenario_id)
    if not todo:
        return report
    dataset = spec.dataset(root, split, split_name)  # indexes and checks every log
    counts = {s: len(i) for s, i in _samples_by_clip(dataset).items()}
    report.samples += sum(counts[s] for s in todo)
    report.folder.mkdir(parents=True, exist_ok=True)
    _remove_abandoned(report.folder)
    _write_spec(report.folder, spec)
    jobs = [(root, spec, split, split_name, s, log_key(dataset.log_path(s))) for s in todo]
    if workers <= 1 or len(jobs) <= 1:
        for job in jobs:
            scenario_id = _build_clip(*job, dataset=dataset)
            report.written.append(scenario_id)
            if on_samples is not None:
                on_samples(counts[scenario_id])
    else:
        with ProcessPoolExecutor(max_workers=min(workers, len(jobs))) as pool:
            futures = [pool.submit(_build_clip, *job) for job in jobs]
            for future in as_completed(futures):
                scenario_id = future.result()
                report.written.append(scenario_id)
                if on_samples is not None:
                    on_samples(counts[scenario_id])
    report.written.sort()
    return report


def _samples_by_clip(dataset: DriveE2EDataset) -> dict[str, list[int]]:
    """Each clip's dataset indices, in dataset order."""
    by_clip: dict[str, list[int]] = {}
    for index, (scenario_id, _frame) in enumerate(dataset.samples):
        by_clip.setdefault(scenario_id, []).append(index)
    return by_clip


def _write_spec(folder: Path, spec: FeatureSpec) -> None:
    path = folder / "spec.json"
    if not path.is_file():
        document = {"version": CACHE_VERSION, **asdict(spec)}
        temporary = path.with_name(f".spec.{os.getpid()}.tmp")
        temporary.write_text(json.dumps(document, indent=1))
        os.replace(temporary, path)


# each pool worker builds its own Dataset once per split (indexing opens every log)
_datasets: dict[tuple[str, str, str, str], DriveE2EDataset] = {}


def _build_clip(
    root: Path,
    spec: FeatureSpec,
    split: str,
    split_name: str,
    scenario_id: str,
    key: str,
    dataset: DriveE2EDataset | None = None,
) -> str:
    """One clip's features written into its folder (under a temporary name, then renamed)."""
    if dataset is None:
        cached = (str(root), spec.key(), split, split_name)
        if cached not in _datasets:
            _datasets[cached] = spec.dataset(root, split, split_name)
        dataset = _datasets[cached]
    indices = _samples_by_clip(dataset)[scenario_id]
    columns: dict[str, list[Any]] = {name: [] for name in spec.all_fields()}
    for index in indices:
        sample = dataset[index]
        for name in columns:
            if name not in sample:
                raise DriveE2EError(f"feature {name!r} of spec {spec.name!r} is no sample field")
            columns[name].append(np.asarray(sample[name]))
    final = clip_folder(root, spec, scenario_id, key)
    temporary = final.with_name(f".{final.name}.{os.getpid()}.tmp")
    if temporary.exists():
        shutil.rmtree(temporary)
    temporary.mkdir(parents=True)
    frames = np.array([dataset.samples[i][1] for i in indices], np.int64)
    np.save(temporary / FRAMES_FILE, frames)
    for name, values in columns.items():
        if name in spec.box_fields:  # rows of every sample, one after another, and where
            counts = np.array([len(v) for v in values], np.int64)
            np.save(temporary / f"{name}.offsets.npy", np.concatenate([[0], np.cumsum(counts)]))
            np.save(temporary / f"{name}.npy", np.concatenate(values))
        else:
            np.save(temporary / f"{name}.npy", np.stack(values))
    _fsync_folder(temporary)
    if final.exists():  # another process built it meanwhile: keep theirs (the same bytes)
        shutil.rmtree(temporary)
    else:
        os.replace(temporary, final)
    for older in final.parent.glob(f"{scenario_id}-*"):  # built from an earlier log
        if older != final and older.is_dir():
            shutil.rmtree(older, ignore_errors=True)
    return scenario_id


def _remove_abandoned(folder: Path) -> None:
    """Temporary clip folders of builds that were killed (their process is gone)."""
    for temporary in folder.glob(".*.tmp"):
        pid = temporary.name.rsplit(".", 2)[-2]
        if pid.isdigit() and not process_running(int(pid)):
            shutil.rmtree(temporary, ignore_errors=True)


def _fsync_folder(folder: Path) -> None:
    for path in folder.iterdir():
        with open(path, "rb") as handle:
            os.fsync(handle.fileno())


class FeatureCache(torch.utils.data.Dataset):
    """The cached features of one split: `cache[i]` is sample i of `spec.dataset(...)` for the
    spec's fields (tensors, as the Dataset returns them); `rows(indices)` a batch of them.

    Raises `DriveE2EError` naming what to run when a clip is not built for its current log.
    Images stay on disk, memory-mapped in each process that reads them (a DataLoader worker
    maps its own)."""

    def __init__(
        self, root: Path, spec: FeatureSpec, split: str, split_name: str = "default"
    ) -> None:
        self.root, self.spec, self.split = Path(root), spec, split
        self.manifest = splits.split_path(self.root, split_name)
        self.horizons = spec.horizons
        self.samples: list[tuple[str, int]] = []
        self.categories: list[str] = []
        columns: dict[str, list[NDArray[Any]]] = {name: [] for name in spec.fields}
        boxes: dict[str, list[NDArray[Any]]] = {name: [] for name in spec.box_fields}
        counts: list[NDArray[np.int64]] = []
        self.image_files: list[Path] = []
        self._image_of: list[tuple[int, int]] = []  # sample -> (clip, row)
        for row in _split_clips(self.root, split, split_name):
            log = self.root / LOGS_FOLDER / f"{row.scenario_id}.mcap"
            if not log.is_file():
                raise DriveE2EError(
                    f"{self.manifest}: clip {row.scenario_id!r} has no collected log {log}"
                )
            folder = clip_folder(self.root, spec, row.scenario_id, log_key(log))
            if not folder.is_dir():
                raise DriveE2EError(
                    f"{folder}: features of clip {row.scenario_id!r} are not cached for its "
                    f"current log; run drivee2e cache {self.root} --model {spec.name} "
                    f"--split {split}"
                )
            frames = np.load(folder / FRAMES_FILE)
            self.samples.extend((row.scenario_id, int(f)) for f in frames)
            self.categories.extend([row.category] * len(frames))
            for name in spec.fields:
                columns[name].append(np.load(folder / f"{name}.npy"))
            for name in spec.box_fields:
                boxes[name].append(np.load(folder / f"{name}.npy"))
            if spec.box_fields:
                counts.append(np.diff(np.load(folder / f"{spec.box_fields[0]}.offsets.npy")))
            if spec.reads_images:
                clip = len(self.image_files)
                self.image_files.append(folder / "img.npy")
                self._image_of.extend((clip, k) for k in range(len(frames)))
        self.arrays = {
            name: torch.from_numpy(np.concatenate(parts)) if parts else torch.zeros(0)
            for name, parts in columns.items()
        }
        self.box_arrays = {
            name: torch.from_numpy(np.concatenate(parts)) for name, parts in boxes.items() if parts
        }
        box_counts = np.concatenate(counts) if counts else np.zeros(len(self.samples), np.int64)
        self.box_offsets = np.concatenate([[0], np.cumsum(box_counts)])
        self._maps: list[NDArray[np.uint8]] = []
        self._pid = -1

    def __len__(self) -> int:
        return len(self.samples)

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_maps"], state["_pid"] = [], -1  # a worker maps the files itself
        return state

    def _images(self) -> list[NDArray[np.uint8]]:
        if self._pid != os.getpid():
            self._maps = [np.load(path, mmap_mode="r") for path in self.image_files]
            self._pid = os.getpid()
        return self._maps

    def __getitem__(self, index: int) -> dict[str, Any]:
        sample: dict[str, Any] = {name: values[index] for name, values in self.arrays.items()}
        first, last = self.box_offsets[index], self.box_offsets[index + 1]
        for name, values in self.box_arrays.items():
            sample[name] = values[first:last]
        if self.spec.reads_images:
            clip, row = self._image_of[index]
            sample["img"] = torch.from_numpy(np.array(self._images()[clip][row]))
        sample["category"] = self.categories[index]
        return sample

    def rows(self, indices: Sequence[int] | torch.Tensor) -> dict[str, Any]:
        """The spec's fields of these samples, stacked: a batch (per-box fields padded to the
        batch's most boxes with zeros and `gt_boxes_mask`, as `collate` pads them), with
        `category` as a list."""
        index = torch.as_tensor(indices, dtype=torch.int64)
        batch: dict[str, Any] = {name: values[index] for name, values in self.arrays.items()}
        if self.box_arrays:
            batch.update(self._padded_boxes(index.tolist()))
        if self.spec.reads_images:
            batch["img"] = torch.from_numpy(self.gather_images(index.tolist()))
        batch["category"] = [self.categories[i] for i in index.tolist()]
        return batch

    def _padded_boxes(self, indices: list[int]) -> dict[str, torch.Tensor]:
        starts, ends = self.box_offsets[indices], self.box_offsets[np.asarray(indices) + 1]
        most = int((ends - starts).max()) if indices else 0
        mask = torch.zeros((len(indices), most), dtype=torch.bool)
        padded: dict[str, torch.Tensor] = {}
        for name, values in self.box_arrays.items():
            padded[name] = values.new_zeros((len(indices), most, *values.shape[1:]))
        for k, (start, end) in enumerate(zip(starts.tolist(), ends.tolist(), strict=True)):
            mask[k, : end - start] = True
            for name, values in self.box_arrays.items():
                padded[name][k, : end - start] = values[start:end]
        return {**padded, BOX_MASK: mask}

    def gather_images(self, indices: Sequence[int]) -> NDArray[np.uint8]:
        """`(len, K, 3, H, W)` the images of these samples, read from their memory maps."""
        images = self._images()
        out = np.empty((len(indices), *images[0].shape[1:]), np.uint8)
        for k, index in enumerate(indices):
            clip, row = self._image_of[index]
            out[k] = images[clip][row]
        return out

    def camera_full_size(self) -> tuple[int, int]:
        """(width, height) the logs' first camera of the spec was collected at."""
        with LogReader(self.root / LOGS_FOLDER / f"{self.samples[0][0]}.mcap") as log:
            calibration = log.rig["cameras"][self.spec.cameras[0]]
        return int(calibration["width"]), int(calibration["height"])


def cached(
    root: Path,
    spec: FeatureSpec,
    split: str,
    split_name: str = "default",
    workers: int = 1,
    on_samples: Callable[[int], None] | None = None,
) -> FeatureCache:
    """The split's feature cache, built first where any clip is missing (`build`)."""
    build(root, spec, split, split_name, workers, on_samples)
    return FeatureCache(root, spec, split, split_name)
