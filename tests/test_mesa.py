"""The fetched Mesa: Debian's index and packages read, the folder made or left alone, the guards
that keep it off a GPU's EGL, and (where one was fetched) the images it draws."""

from __future__ import annotations

import hashlib
import io
import json
import lzma
import os
import subprocess
import sys
import tarfile
from pathlib import Path

import numpy as np
import pytest
from conftest import copy_clips

from drivee2e_data import cli, store
from drivee2e_data.sim import mesa, mesa_fetch

MULTIARCH = "x86_64-linux-gnu"
MIRROR = "https://mirror.test/debian"


def _ar(members: dict[str, bytes]) -> bytes:
    """An `ar` archive (a .deb's container) of `members`."""
    out = io.BytesIO()
    out.write(b"!<arch>\n")
    for name, payload in members.items():
        header = f"{name:<16}{0:<12}{0:<6}{0:<6}{'100644':<8}{len(payload):<10}`\n"
        out.write(header.encode("ascii") + payload + (b"\n" if len(payload) % 2 else b""))
    return out.getvalue()


def _tar_xz(files: dict[str, bytes], links: dict[str, str]) -> bytes:
    raw = io.BytesIO()
    with tarfile.open(fileobj=raw, mode="w") as archive:
        for name, payload in files.items():
            info = tarfile.TarInfo(name)
            info.size = len(payload)
            archive.addfile(info, io.BytesIO(payload))
        for name, target in links.items():
            info = tarfile.TarInfo(name)
            info.type, info.linkname = tarfile.SYMTYPE, target
            archive.addfile(info)
    return lzma.compress(raw.getvalue())


def _deb(library: str, payload: bytes) -> bytes:
    """A package holding `library`.1.2.3, its soname link `library`.1, a driver in a subfolder
    and a document: only the first two are libraries of the multiarch folder."""
    prefix = f"./usr/lib/{MULTIARCH}/"
    files = {prefix + f"{library}.1.2.3": payload, prefix + "dri/driver_dri.so": b"driver"}
    files["./usr/share/doc/readme"] = b"doc"
    data = _tar_xz(files, {prefix + f"{library}.1": f"{library}.1.2.3"})
    return _ar({"debian-binary": b"2.0\n", "control.tar.xz": _tar_xz({}, {}), "data.tar.xz": data})


def test_deb_libraries_unpacked_with_their_soname_links(tmp_path: Path) -> None:
    sonames = mesa_fetch.unpack_libraries(_deb("libfoo.so", b"ELF!"), MULTIARCH, tmp_path, "foo")
    assert sonames == ["libfoo.so.1"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["libfoo.so.1", "libfoo.so.1.2.3"]
    assert (tmp_path / "libfoo.so.1").is_symlink()
    assert (tmp_path / "libfoo.so.1").read_bytes() == b"ELF!"
    with pytest.raises(mesa_fetch.MesaFetchError, match=r"broken\.deb: not a Debian package"):
        mesa_fetch.unpack_libraries(b"<html>", MULTIARCH, tmp_path, "broken.deb")


def test_packages_index_read_highest_version_and_what_is_missing() -> None:
    index = (
        "Package: libgbm1\nVersion: 25.0.7-2~bpo12+1\nFilename: pool/a.deb\nSHA256: AB\n\n"
        "Package: libgbm1\nVersion: 25.0.10-1\nFilename: pool/b.deb\nSHA256: cd\n\n"
        "Package: other\nVersion: 1\nFilename: pool/o.deb\nSHA256: ef\n"
    )
    found = mesa_fetch.parse_packages(index, ("libgbm1",), "Packages.xz")
    assert found["libgbm1"] == mesa_fetch.Package("libgbm1", "25.0.10-1", "pool/b.deb", "cd")
    with pytest.raises(mesa_fetch.MesaFetchError, match=r"Packages\.xz: no package libdrm2"):
        mesa_fetch.parse_packages(index, ("libgbm1", "libdrm2"), "Packages.xz")
    with pytest.raises(mesa_fetch.MesaFetchError, match="package libgbm1 has no SHA256"):
        mesa_fetch.parse_packages("Package: libgbm1\nVersion: 1\nFilename: x", ("libgbm1",))


def test_release_hash_of_an_index() -> None:
    release = (
        "Suite: bookworm-backports\nMD5Sum:\n 00 1 main/binary-amd64/Packages.xz\n"
        "SHA256:\n 11aa 10 main/binary-amd64/Packages\n 22BB 20 main/binary-amd64/Packages.xz\n"
        "-----BEGIN PGP SIGNATURE-----\n"
    )
    assert mesa_fetch.index_hash(release, "main/binary-amd64/Packages.xz") == "22bb"
    with pytest.raises(mesa_fetch.MesaFetchError, match="InRelease: no SHA256 for main/x"):
        mesa_fetch.index_hash(release, "main/x")


def _mirror(corrupt: str | None = None) -> dict[str, bytes]:
    """A mirror's files for the packages `fetch` wants: URL -> bytes (`corrupt`: a package whose
    bytes differ from what the index says)."""
    files, stanzas = {}, []
    for name in mesa_fetch.PACKAGES:
        library = "libgallium-25.0.7.so" if name == "mesa-libgallium" else f"lib{name}.so"
        deb = _deb(library, name.encode())
        filename = f"pool/main/{name}.deb"
        stanzas.append(f"Package: {name}\nVersion: 25.0.7-2~bpo12+1\nFilename: {filename}\n"
                       f"SHA256: {hashlib.sha256(deb).hexdigest()}\n")  # fmt: skip
        files[f"{MIRROR}/{filename}"] = deb + (b"x" if name == corrupt else b"")
    index = lzma.compress("\n".join(stanzas).encode())
    path = "main/binary-amd64/Packages.xz"
    base = f"{MIRROR}/dists/{mesa_fetch.SUITE}"
    files[f"{base}/{path}"] = index
    release = f"SHA256:\n {hashlib.sha256(index).hexdigest()} {len(index)} {path}\n"
    files[f"{base}/InRelease"] = release.encode()
    return files


@pytest.mark.skipif(os.uname().machine != "x86_64", reason="the fake packages are x86_64's")
def test_fetch_makes_the_folder_only_when_every_package_checks(tmp_path: Path, monkeypatch) -> None:
    folder = tmp_path / "mesa"
    checked: list[Path] = []

    def check(staging: Path) -> str:
        checked.append(staging)
        assert (staging / mesa.MANIFEST).is_file()  # checked before it is renamed into place
        return "llvmpipe | 4.5 (Core Profile) Mesa 25.0.7-2~bpo12+1"

    files = _mirror()
    found, description = mesa_fetch.fetch(folder, MIRROR, download=files.__getitem__,
                                          check=check, keyring=None)  # fmt: skip
    assert found.version == "25.0.7" and "Mesa 25.0.7" in description
    assert checked and checked[0] != folder and not checked[0].exists()
    # every package's soname, in PACKAGES' order: the loader's libraries after what they need
    expected = [f"lib{n}.so.1" for n in mesa_fetch.PACKAGES]
    expected[mesa_fetch.PACKAGES.index("mesa-libgallium")] = "libgallium-25.0.7.so.1"
    assert list(found.libraries) == expected
    vendor = json.loads(found.vendor_file.read_text())
    assert vendor["ICD"]["library_path"] == str(folder.resolve() / "lib" / "libEGL_mesa.so.0")
    assert mesa.read_private(folder) == found

    # a package whose bytes are not the index's: an error naming it, the old folder kept
    bad = _mirror(corrupt="libgbm1")
    with pytest.raises(mesa_fetch.MesaFetchError, match=r"libgbm1\.deb: SHA-256 .* expected"):
        mesa_fetch.fetch(folder, MIRROR, download=bad.__getitem__, check=check, keyring=None)
    assert mesa.read_private(folder) == found
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mesa"]  # no staging folder left

    # the new folder failing to move into place after the old one was moved aside: the old back
    rename = Path.rename

    def failing_rename(self: Path, target: Path) -> Path:
        if Path(target) == folder and not self.name.startswith(".mesa.old"):
            raise OSError("no room")
        return rename(self, target)

    monkeypatch.setattr(Path, "rename", failing_rename)
    with pytest.raises(OSError, match="no room"):
        mesa_fetch.fetch(folder, MIRROR, download=files.__getitem__, check=check, keyring=None)
    monkeypatch.undo()
    assert mesa.read_private(folder) == found
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mesa"]

    # a Mesa that draws as another version: refused, the folder kept
    with pytest.raises(mesa_fetch.MesaFetchError, match=r"expected Mesa 25\.0\.7"):
        mesa_fetch.fetch(folder, MIRROR, download=files.__getitem__,
                         check=lambda staging: "llvmpipe | Mesa 22.3.6", keyring=None)  # fmt: skip
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mesa"]


def test_manifest_errors_name_the_file_and_key(tmp_path: Path) -> None:
    assert mesa.read_private(tmp_path) is None  # nothing fetched: the system's Mesa
    (tmp_path / mesa.MANIFEST).write_text('{"version": "25.0.7"}')
    with pytest.raises(ValueError, match=r"mesa\.json: expected JSON with 'version' and 'libr"):
        mesa.read_private(tmp_path)
    (tmp_path / mesa.MANIFEST).write_text('{"version": "25.0.7", "libraries": ["libdrm.so.2"]}')
    with pytest.raises(ValueError, match=r"'libraries' names libdrm\.so\.2, not in"):
        mesa.read_private(tmp_path)


def test_guards_keep_the_fetched_mesa_off_a_gpu(tmp_path: Path, monkeypatch) -> None:
    vendors = tmp_path / "egl_vendor.d"
    vendors.mkdir()
    (vendors / "50_mesa.json").write_text("{}")
    monkeypatch.setattr(mesa, "VENDOR_DIRS", (vendors,))
    for name in mesa.VENDOR_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.delenv(mesa.MESA_VARIABLE, raising=False)
    assert mesa.chosen_folder() == mesa.default_folder()
    assert mesa.why_not(tmp_path) is None
    monkeypatch.setenv(mesa.MESA_VARIABLE, "system")
    assert mesa.chosen_folder() is None and mesa.why_not(None) == "DRIVEE2E_MESA=system"
    monkeypatch.setenv(mesa.MESA_VARIABLE, str(tmp_path))
    assert mesa.chosen_folder() == tmp_path
    (vendors / "10_nvidia.json").write_text("{}")
    assert mesa.why_not(tmp_path) == "another EGL vendor is installed (10_nvidia.json)"
    (vendors / "10_nvidia.json").unlink()
    # a parent's activation leaves the folder's own vendor file chosen: still to be loaded here
    monkeypatch.setenv("__EGL_VENDOR_LIBRARY_FILENAMES", str(tmp_path / mesa.VENDOR_FILE))
    assert mesa.why_not(tmp_path) is None
    monkeypatch.setenv("__EGL_VENDOR_LIBRARY_FILENAMES", "/somewhere/10_nvidia.json")
    assert mesa.why_not(tmp_path) == "EGL vendors chosen by __EGL_VENDOR_LIBRARY_FILENAMES"
    # asked to fetch where it would not be used: one clear error, nothing fetched
    assert cli.main(["mesa", "--fetch", "--folder", str(tmp_path / "m")]) == 2
    assert not (tmp_path / "m").exists()


def _fetched() -> Path | None:
    """The folder a Mesa was fetched into for this environment, if one was and would be used."""
    folder = mesa.chosen_folder()
    if folder is None or mesa.why_not(folder) is not None:
        return None
    try:
        return folder if mesa.read_private(folder) is not None else None
    except ValueError:
        return None


DRAW = """
import sys, tempfile, numpy as np
from pathlib import Path
from drivee2e_data.sim.gl_context import gl_version
from drivee2e_data.sim.world import World
from tests.factories import front_view, synthetic_clip
intersection_map, scenario = synthetic_clip(Path(tempfile.mkdtemp()))
with World(intersection_map, scenario, "gl") as world:
    np.save(sys.argv[1], front_view(world, 10, (480, 270)).rgb)
print(gl_version())
"""


@pytest.mark.slow
@pytest.mark.skipif(_fetched() is None, reason="no Mesa fetched here (drivee2e mesa --fetch)")
def test_fetched_mesa_draws_what_the_systems_does(tmp_path: Path) -> None:
    folder = _fetched()
    images, versions = {}, {}
    # "inherited": a process started by one that activated it (its vendor file already chosen)
    for choice in ("fetched", "system", "inherited"):
        chosen = "system" if choice == "system" else str(folder)
        environment = {**os.environ, mesa.MESA_VARIABLE: chosen}
        for name in mesa.VENDOR_VARIABLES:
            environment.pop(name, None)
        if choice == "inherited":
            environment[mesa.VENDOR_VARIABLES[0]] = str(folder / mesa.VENDOR_FILE)
        out = tmp_path / f"{choice}.npy"
        result = subprocess.run([sys.executable, "-c", DRAW, str(out)], capture_output=True,
                                text=True, env=environment, cwd=Path(__file__).parents[1])  # fmt: skip
        assert result.returncode == 0, result.stderr[-2000:]
        versions[choice] = result.stdout.strip().splitlines()[-1]
        images[choice] = np.load(out)
    version = mesa.read_private(folder).version
    assert f"Mesa {version}" in versions["fetched"]
    assert versions["inherited"] == versions["fetched"]
    assert np.array_equal(images["inherited"], images["fetched"])
    assert f"Mesa {version}" not in versions["system"]
    differ = np.abs(images["fetched"].astype(int) - images["system"].astype(int)).max(axis=2) > 0
    assert images["fetched"].std() > 10  # a scene, not a blank image
    assert differ.mean() < 0.002  # a few pixels where a triangle's edge meets a pixel centre


@pytest.mark.slow
@pytest.mark.skipif(_fetched() is None, reason="no Mesa fetched here (drivee2e mesa --fetch)")
def test_bench_mesa_compares_both_through_the_command(synthetic_root: Path, tmp_path: Path):
    root = copy_clips(synthetic_root, tmp_path / "data", store.scenario_ids(synthetic_root)[:2])
    script = Path(__file__).parents[1] / "scripts" / "dev" / "bench_mesa.py"
    result = subprocess.run(
        [sys.executable, str(script), "--data", str(root), "--max-frames", "2", "--repeats", "1"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]
    lines = result.stdout.splitlines()
    assert any(line.startswith("run 1 system Mesa: 4 frames") for line in lines)
    assert any(line.startswith("run 1 fetched Mesa: 4 frames") for line in lines)
    assert any(line.startswith("logs whose bytes differ between the two:") and
               line.endswith(" of 2") for line in lines)  # fmt: skip
    assert "ratio" in result.stdout
