"""What worlds reuse rather than make again: twin plans, kept in this process (by their map
file) and, for the workers of one collection, in a folder they share with the actors' shape
files.

A twin's plan is most of a new world's set-up (0.52 of 0.66 s for the twin on 2 cores, where
reading a plan back takes 0.03 s) and the same for every clip of its map, so the workers of a
run plan each map once between them instead of once per world each; an actor's collision shape
files, written by the worker that first shows the actor, serve any worker that takes a piece of
its clip later.
"""

from __future__ import annotations

import collections
import pickle
import zlib
from pathlib import Path

from drivee2e_data import store
from drivee2e_data.hdmap import IntersectionMap
from drivee2e_data.sim.twin_plan import TwinPlan, plan_twin

# plans kept in a process, the most recently used: a plan is about 17 MB (two thirds of it the
# ground's wear raster), and a worker rarely goes back to more maps than this
KEPT_PLANS = 4
PLAN_SUFFIX = ".plan"

_kept: collections.OrderedDict[tuple[str, int, int], TwinPlan] = collections.OrderedDict()
_shared: Path | None = None


def share_in(folder: Path | None) -> None:
    """Read and write plans and actors' shape files in `folder` from now on (None: plans kept in
    this process only, shape files in each twin's folder). The folder is one run's: the maps'
    files must not change while it is in use."""
    global _shared
    _shared = None if folder is None else Path(folder)


def shared_folder() -> Path | None:
    """The folder `share_in` named, if any."""
    return _shared


def twin_plan(root: Path, intersection_map: IntersectionMap) -> TwinPlan:
    """The twin plan of `intersection_map`, read from `root`'s `maps/<map_id>.json`: one kept
    here if the file is unchanged since, else the shared folder's (`share_in`), else planned
    now (and written to the shared folder for the others)."""
    path = store.map_path(Path(root), intersection_map.map_id)
    stat = path.stat()
    key = (str(path.resolve()), stat.st_mtime_ns, stat.st_size)
    plan = _kept.get(key)
    if plan is None:
        shared = _shared_path(key, intersection_map.map_id)
        found = shared is not None and shared.exists()
        plan = _read(shared) if found else None
        if plan is None:
            plan = plan_twin(intersection_map)
            # written unless another worker wrote it meanwhile (at a run's start several plan
            # a map at once); a damaged one is replaced
            if shared is not None and (found or not shared.exists()):
                _write(shared, plan)
        _kept[key] = plan
        while len(_kept) > KEPT_PLANS:
            _kept.popitem(last=False)
    _kept.move_to_end(key)
    return plan


def forget_plans() -> None:
    """Drop the plans kept in this process."""
    _kept.clear()


def _shared_path(key: tuple[str, int, int], map_id: str) -> Path | None:
    if _shared is None:
        return None
    return _shared / f"{map_id}-{zlib.crc32(repr(key).encode()):08x}{PLAN_SUFFIX}"


def _read(path: Path) -> TwinPlan | None:
    """The plan in `path`, or None where there is none (yet) or it does not read as one."""
    try:
        plan = pickle.loads(path.read_bytes())
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ValueError):
        return None
    return plan if isinstance(plan, TwinPlan) else None


def _write(path: Path, plan: TwinPlan) -> None:
    """Write `plan` to `path` whole or not at all (`store.write_bytes_atomic`: another worker
    writing the same plan at once only replaces it with equal bytes). A folder gone or full
    only costs the others the planning."""
    try:
        store.write_bytes_atomic(path, pickle.dumps(plan, protocol=pickle.HIGHEST_PROTOCOL))
    except OSError:
        pass
