"""Mesa 25's libraries fetched from Debian (bookworm-backports) into a folder `mesa.activate` uses.

Only the packages llvmpipe's EGL needs are fetched (`PACKAGES`); the rest of their dependencies
(LLVM 15, X and Wayland client libraries, expat, zstd) are the system's, as Debian 12 ships them.
The index comes over HTTPS and is checked against the suite's `InRelease` (its signature too,
with `gpgv` and Debian's archive keyring where both are installed); every package against the
index's SHA-256. The folder is made under a temporary name, checked by drawing with it in a
fresh process, and only then renamed into place: a failed fetch leaves the old folder (or none).
"""

from __future__ import annotations

import hashlib
import io
import json
import lzma
import os
import platform
import re
import shutil
import subprocess
import sys
import tarfile
import tempfile
import urllib.request
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from drivee2e_data.errors import DriveE2EError
from drivee2e_data.sim import mesa

MIRROR = "https://deb.debian.org/debian"
SUITE = "bookworm-backports"  # Mesa 25.0 built for Debian 12 (LLVM 15, glibc 2.36)
# in load order: each library's dependencies among them come before it
PACKAGES = ("libdrm2", "libdrm-amdgpu1", "libdrm-intel1", "libgbm1", "mesa-libgallium",
            "libegl-mesa0")  # fmt: skip
DEBIAN_ARCHITECTURES = {"x86_64": "amd64", "aarch64": "arm64"}
KEYRING = Path("/usr/share/keyrings/debian-archive-keyring.gpg")
# a library's own name (its soname): libdrm.so.2, libgallium-25.0.7-2~bpo12+1.so; not the
# versioned files the sonames link to (libdrm.so.2.123.0)
SONAME = re.compile(r"^lib[^/]*\.so(\.\d+)?$")
TIMEOUT_S = 60.0


class MesaFetchError(DriveE2EError):
    """Mesa's packages could not be fetched, checked, unpacked or drawn with."""


@dataclass(frozen=True)
class Package:
    """One binary package of a Debian `Packages` index."""

    name: str
    version: str
    filename: str  # its path under the mirror
    sha256: str


def parse_packages(text: str, wanted: tuple[str, ...], source: str = "Packages") -> dict:
    """`wanted` packages of a Debian `Packages` index (`text`), by name: the highest version
    where several are listed. A wanted package missing, or a stanza of one without its
    `Filename`, `SHA256` or `Version`, is an error naming `source` and the package."""
    found: dict[str, Package] = {}
    for stanza in text.split("\n\n"):
        fields = dict(re.findall(r"^([A-Za-z0-9-]+): ?(.*)$", stanza, flags=re.M))
        name = fields.get("Package")
        if name not in wanted:
            continue
        missing = [key for key in ("Version", "Filename", "SHA256") if not fields.get(key)]
        if missing:
            raise MesaFetchError(f"{source}: package {name} has no {', '.join(missing)}")
        package = Package(name, fields["Version"], fields["Filename"], fields["SHA256"].lower())
        if name not in found or _version_key(package.version) > _version_key(found[name].version):
            found[name] = package
    absent = [name for name in wanted if name not in found]
    if absent:
        raise MesaFetchError(f"{source}: no package {', '.join(absent)}")
    return found


def _version_key(version: str) -> tuple:
    """A sort key for the Debian versions one index lists (digits compared as numbers)."""
    return tuple(int(part) if part.isdigit() else part for part in re.split(r"(\d+)", version))


def index_hash(release: str, path: str, source: str = "InRelease") -> str:
    """The SHA-256 a suite's `Release`/`InRelease` text gives for the index at `path`
    (relative to the suite's folder)."""
    section = release.split("SHA256:", 1)
    if len(section) < 2:
        raise MesaFetchError(f"{source}: no SHA256 section")
    for line in section[1].splitlines()[1:]:
        if not line.startswith(" "):
            break
        parts = line.split()
        if len(parts) == 3 and parts[2] == path:
            return parts[0].lower()
    raise MesaFetchError(f"{source}: no SHA256 for {path}")


def deb_members(data: bytes, source: str) -> dict[str, bytes]:
    """The members of a .deb (an `ar` archive) by name."""
    if not data.startswith(b"!<arch>\n"):
        raise MesaFetchError(f"{source}: not a Debian package (no ar header)")
    members, offset = {}, 8
    while offset + 60 <= len(data):
        header = data[offset : offset + 60]
        name = header[:16].decode("ascii", "replace").strip().rstrip("/")
        try:
            size = int(header[48:58].decode("ascii").strip())
        except ValueError:
            raise MesaFetchError(f"{source}: member at byte {offset} has no size") from None
        members[name] = data[offset + 60 : offset + 60 + size]
        offset += 60 + size + (size % 2)  # members start on even offsets
    return members


def _data_tar(members: dict[str, bytes], source: str) -> tarfile.TarFile:
    """The package's file tree (data.tar.xz, .gz or .zst)."""
    for name, payload in members.items():
        if name == "data.tar.xz":
            return tarfile.open(fileobj=io.BytesIO(lzma.decompress(payload)))
        if name == "data.tar.gz":
            return tarfile.open(fileobj=io.BytesIO(payload), mode="r:gz")
        if name == "data.tar.zst":
            import zstandard

            reader = zstandard.ZstdDecompressor().stream_reader(io.BytesIO(payload))
            return tarfile.open(fileobj=io.BytesIO(reader.read()))
    raise MesaFetchError(f"{source}: no data.tar member (has {', '.join(members) or 'none'})")


def unpack_libraries(data: bytes, multiarch: str, target: Path, source: str) -> list[str]:
    """The shared libraries of a package's `usr/lib/<multiarch>/` folder (not its subfolders)
    written into `target`, symbolic links kept as links; returns the sonames among them."""
    prefix = f"usr/lib/{multiarch}/"
    sonames = []
    with _data_tar(deb_members(data, source), source) as archive:
        for member in archive.getmembers():
            name = member.name.removeprefix("./")
            if not name.startswith(prefix) or "/" in name[len(prefix) :]:
                continue
            base = name[len(prefix) :]
            if ".so" not in base:
                continue
            path = target / base
            if member.issym():
                if "/" in member.linkname:
                    raise MesaFetchError(f"{source}: {name} links out of its folder")
                path.unlink(missing_ok=True)
                path.symlink_to(member.linkname)
            elif member.isfile():
                with archive.extractfile(member) as reader:
                    path.write_bytes(reader.read())
                path.chmod(0o755)
            else:
                continue
            if SONAME.match(base):
                sonames.append(base)
    return sonames


def _download(url: str) -> bytes:
    try:
        with urllib.request.urlopen(url, timeout=TIMEOUT_S) as response:
            return response.read()
    except OSError as error:
        raise MesaFetchError(f"{url}: download failed ({error})") from None


def _checked(data: bytes, sha256: str, source: str) -> bytes:
    digest = hashlib.sha256(data).hexdigest()
    if digest != sha256:
        raise MesaFetchError(f"{source}: SHA-256 {digest}, expected {sha256} from the index")
    return data


def _verified_release(signed: bytes, source: str, keyring: Path | None) -> str:
    """The `InRelease` text, its signature checked with gpgv where gpgv and `keyring` are."""
    gpgv = shutil.which("gpgv")
    if gpgv is not None and keyring is not None and keyring.is_file():
        with tempfile.NamedTemporaryFile(suffix=".InRelease") as handle:
            handle.write(signed)
            handle.flush()
            result = subprocess.run([gpgv, "--keyring", str(keyring), handle.name],
                                    capture_output=True, text=True)  # fmt: skip
        if result.returncode != 0:
            raise MesaFetchError(f"{source}: signature not valid ({result.stderr.strip()})")
    return signed.decode("utf-8", "replace")


PROBE = (
    "import sys\n"
    "from drivee2e_data.sim import gl_context, mesa\n"
    "if mesa.activate() is None: sys.exit('not activated: ' + mesa.describe())\n"
    "print(gl_context.gl_driver() or sys.exit('no GL context (moderngl over EGL)'))\n"
)


def probe(folder: Path) -> str:
    """Draw nothing but make a context with the Mesa in `folder`, in a fresh process; its
    renderer and version strings. An error where it would not be used or does not load."""
    environment = {**os.environ, mesa.MESA_VARIABLE: str(folder)}
    result = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True,
                            env=environment, timeout=120)  # fmt: skip
    if result.returncode != 0:
        lines = (result.stderr or result.stdout).strip().splitlines()
        raise MesaFetchError(f"Mesa in {folder} makes no context: {lines[-1] if lines else '?'}")
    return result.stdout.strip()


def fetch(
    folder: Path | None = None,
    mirror: str = MIRROR,
    suite: str = SUITE,
    download: Callable[[str], bytes] = _download,
    check: Callable[[Path], str] = probe,
    keyring: Path | None = KEYRING,
) -> tuple[mesa.PrivateMesa, str]:
    """Fetch, check and unpack Mesa's EGL libraries into `folder` (default
    `mesa.default_folder()`), replacing what it held only once the new one made a context
    (`check`). Returns the Mesa and its GL renderer and version strings. `download` (a URL's
    bytes) and `keyring` (None: the suite's signature is not checked) are for tests."""
    folder = mesa.default_folder() if folder is None else Path(folder)
    machine = platform.machine()
    if machine not in DEBIAN_ARCHITECTURES or not sys.platform.startswith("linux"):
        raise MesaFetchError(f"Debian's Mesa packages are for Linux on "
                             f"{', '.join(DEBIAN_ARCHITECTURES)}, not {sys.platform} {machine}")  # fmt: skip
    architecture = DEBIAN_ARCHITECTURES[machine]
    multiarch = f"{machine}-linux-gnu"
    base = f"{mirror.rstrip('/')}/dists/{suite}"
    release = _verified_release(download(f"{base}/InRelease"), f"{base}/InRelease", keyring)
    index_path = f"main/binary-{architecture}/Packages.xz"
    index = _checked(download(f"{base}/{index_path}"), index_hash(release, index_path),
                     f"{base}/{index_path}")  # fmt: skip
    packages = parse_packages(lzma.decompress(index).decode("utf-8", "replace"), PACKAGES,
                              f"{base}/{index_path}")  # fmt: skip
    folder.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=folder.parent))
    old = None
    try:
        staging.chmod(0o755)  # mkdtemp makes it private
        (staging / "lib").mkdir()
        libraries = []
        for name in PACKAGES:
            package = packages[name]
            url = f"{mirror.rstrip('/')}/{package.filename}"
            data = _checked(download(url), package.sha256, url)
            libraries += unpack_libraries(data, multiarch, staging / "lib", url)
        # the loader (libgallium, libEGL_mesa) last, as PACKAGES orders them
        version = packages["mesa-libgallium"].version.split("-")[0].split("~")[0]
        manifest = {
            "version": version,
            "libraries": libraries,
            "suite": suite,
            "packages": {name: [p.version, p.sha256] for name, p in packages.items()},
        }
        (staging / mesa.MANIFEST).write_text(json.dumps(manifest, indent=1) + "\n")
        _write_vendor_file(staging)
        description = check(staging)
        if f"Mesa {version}" not in description:
            raise MesaFetchError(f"Mesa in {staging} made a context of {description!r}, "
                                 f"expected Mesa {version}")  # fmt: skip
        if folder.exists():
            old = folder.with_name(f".{folder.name}.old-{os.getpid()}")
            folder.rename(old)
        staging.rename(folder)
        _write_vendor_file(folder)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        if old is not None and old.exists() and not folder.exists():
            old.rename(folder)  # moved aside, the new one never in place: the old one back
        raise
    found = mesa.read_private(folder)
    assert found is not None
    return found, description


def _write_vendor_file(folder: Path) -> None:
    """glvnd's vendor file naming the folder's libEGL_mesa by its full path (atomically)."""
    record = {"file_format_version": "1.0.0",
              "ICD": {"library_path": str(folder.resolve() / "lib" / "libEGL_mesa.so.0")}}  # fmt: skip
    temporary = folder / f".{mesa.VENDOR_FILE}.tmp"
    temporary.write_text(json.dumps(record, indent=1) + "\n")
    temporary.replace(folder / mesa.VENDOR_FILE)
