"""A newer Mesa for the GL renderer on a CPU: found, checked and made EGL's driver in this process.

Mesa's llvmpipe draws the cameras where there is no GPU, and on the 2-core machine the cameras
are four fifths of a frame. Debian 12's own Mesa (22.3) takes 1.2-1.3x the time of Mesa 25 (from
bookworm-backports, the same LLVM 15) for the same images, which differ in at most 0.02% of
their pixels (where a triangle's edge falls on a pixel centre: docs/benchmarks.md).
`drivee2e mesa --fetch` (`mesa_fetch`) puts Mesa 25's libraries in a folder of the environment;
`activate` makes them EGL's driver before this process makes its first EGL call, by loading
them by path (so that no `LD_LIBRARY_PATH` is needed at the process's start) and pointing
glvnd's vendor list at them.

It stays out of the way of a GPU: nothing happens where the user chose EGL vendors themselves
(`__EGL_VENDOR_LIBRARY_FILENAMES` or `__EGL_VENDOR_LIBRARY_DIRS`), where a vendor other than
Mesa is installed (NVIDIA's), or with `DRIVEE2E_MESA=system`. `DRIVEE2E_MESA=PATH` names
another folder; the default is `<sys.prefix>/mesa` (the project's `.venv/mesa`).
"""

from __future__ import annotations

import ctypes
import functools
import json
import logging
import os
import sys
from dataclasses import dataclass
from pathlib import Path

LOG = logging.getLogger(__name__)
MESA_VARIABLE = "DRIVEE2E_MESA"  # a folder, or "system" for the system's Mesa
VENDOR_VARIABLES = ("__EGL_VENDOR_LIBRARY_FILENAMES", "__EGL_VENDOR_LIBRARY_DIRS")
# where glvnd looks for EGL vendor files when neither variable is set
VENDOR_DIRS = (Path("/etc/glvnd/egl_vendor.d"), Path("/usr/share/glvnd/egl_vendor.d"))
MANIFEST = "mesa.json"  # written by mesa_fetch: version, libraries in load order, packages
VENDOR_FILE = "egl_vendor.json"  # glvnd's vendor file naming the folder's libEGL_mesa
# libraries that must not already be loaded from elsewhere: the folder's are newer
SHARED_SONAMES = ("libdrm.so.2", "libgbm.so.1")


@dataclass(frozen=True)
class PrivateMesa:
    """A Mesa unpacked by `mesa_fetch`: its folder, version and libraries in load order."""

    folder: Path
    version: str
    libraries: tuple[str, ...]

    @property
    def vendor_file(self) -> Path:
        return self.folder / VENDOR_FILE


def default_folder() -> Path:
    """Where `drivee2e mesa --fetch` puts Mesa unless told otherwise: `<sys.prefix>/mesa`."""
    return Path(sys.prefix) / "mesa"


def chosen_folder() -> Path | None:
    """The folder `DRIVEE2E_MESA` names, the default one without it, None for "system"."""
    value = os.environ.get(MESA_VARIABLE, "").strip()
    if value.lower() == "system":
        return None
    return Path(value).expanduser().resolve() if value else default_folder()


def read_private(folder: Path) -> PrivateMesa | None:
    """The Mesa unpacked in `folder`, None where there is none (no manifest). A manifest that
    does not say what it should, or names a library the folder lacks, is an error naming the
    file and the key."""
    manifest = folder / MANIFEST
    if not manifest.is_file():
        return None
    try:
        record = json.loads(manifest.read_text())
        version, libraries = str(record["version"]), tuple(record["libraries"])
    except (ValueError, KeyError, TypeError) as error:
        raise ValueError(
            f"{manifest}: expected JSON with 'version' and 'libraries' ({error})"
        ) from None
    for name in libraries:
        if not (folder / "lib" / name).exists():
            raise ValueError(f"{manifest}: 'libraries' names {name}, not in {folder / 'lib'}")
    return PrivateMesa(folder, version, libraries)


def other_vendors() -> list[str]:
    """EGL vendor files of glvnd's default folders that are not Mesa's (NVIDIA's, say)."""
    found = []
    for folder in VENDOR_DIRS:
        if folder.is_dir():
            found += [path.name for path in sorted(folder.glob("*.json"))
                      if "mesa" not in path.name.lower()]  # fmt: skip
    return found


def why_not(folder: Path | None) -> str | None:
    """Why `activate` would leave EGL's vendors alone (None: it would not)."""
    if folder is None:
        return f"{MESA_VARIABLE}=system"
    if not sys.platform.startswith("linux"):
        return "not Linux"
    # a parent process's `activate` set the first to the folder's own vendor file: not a choice
    own = str(folder / VENDOR_FILE)
    chosen = [name for name in VENDOR_VARIABLES if (os.environ.get(name) or own) != own]
    if chosen:
        return f"EGL vendors chosen by {chosen[0]}"
    others = other_vendors()
    if others:
        return f"another EGL vendor is installed ({', '.join(others)})"
    return None


def _loaded_elsewhere(mesa: PrivateMesa) -> list[str]:
    """Libraries of `SHARED_SONAMES` this process already loaded from outside `mesa`'s folder:
    loading the folder's own then would leave the newer Mesa bound to the older copy."""
    try:
        maps = Path("/proc/self/maps").read_text()
    except OSError:
        return []
    lib = str((mesa.folder / "lib").resolve())
    paths = {line.split()[-1] for line in maps.splitlines() if "/" in line}
    return [path for path in sorted(paths)
            if Path(path).name.startswith(SHARED_SONAMES) and not path.startswith(lib)]  # fmt: skip


def _candidate() -> tuple[PrivateMesa | None, str, bool]:
    """The fetched Mesa this process would load; else None, why not, and whether that is a
    broken folder (worth a warning) rather than a choice or nothing fetched."""
    folder = chosen_folder()
    reason = why_not(folder)
    if reason is not None or folder is None:
        return None, reason or "", False
    try:
        found = read_private(folder)
    except ValueError as error:
        return None, str(error), True
    if found is None:
        return None, f"none fetched into {folder}: drivee2e mesa --fetch", False
    return found, "", False


@functools.cache
def activate() -> PrivateMesa | None:
    """Make the chosen folder's Mesa the driver of this process's EGL, once, before any EGL call
    (every entry to EGL in the project calls this first). Returns it, or None where the
    system's stays (`why_not`, no folder or no manifest, or the libraries would not load: said
    in the log, never an error: the system's Mesa draws the same images but for a few pixels)."""
    mesa, reason, broken = _candidate()
    if mesa is None:
        (LOG.warning if broken else LOG.debug)("the system's Mesa is used: %s", reason)
        return None
    clashes = _loaded_elsewhere(mesa)
    if clashes:
        LOG.warning("the system's Mesa is used: %s already loaded", ", ".join(clashes))
        return None
    try:
        for name in mesa.libraries:  # dependencies first: each found by its soname after
            ctypes.CDLL(str(mesa.folder / "lib" / name), mode=ctypes.RTLD_GLOBAL)
    except OSError as error:
        LOG.warning("the system's Mesa is used: Mesa %s in %s does not load (%s)",
                    mesa.version, mesa.folder, error)  # fmt: skip
        return None
    os.environ[VENDOR_VARIABLES[0]] = str(mesa.vendor_file)
    LOG.debug("EGL's driver: Mesa %s from %s", mesa.version, mesa.folder)
    return mesa


def describe() -> str:
    """One line for the user: which Mesa this process's EGL uses (`activate`d here) and why."""
    found = activate()
    if found is not None:
        return f"Mesa {found.version} from {found.folder}"
    mesa, reason, _ = _candidate()
    if mesa is not None:
        reason = f"Mesa {mesa.version} in {mesa.folder} did not load"
    return f"the system's Mesa ({reason})"
