"""The distribution lists every subpackage: a non-editable install (`pip install .`) ships
exactly the packages named in pyproject.toml, so one left out is missing only there."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_every_subpackage_is_in_pyproject() -> None:
    # read without tomllib (Python 3.11+) so the test runs on 3.10 too
    text = (ROOT / "pyproject.toml").read_text()
    packages = re.search(r"^packages = \[(.*?)\]", text, re.S | re.M).group(1)
    listed = set(re.findall(r'"([\w.]+)"', packages))
    directories = re.search(
        r"^\[tool\.setuptools\.package-dir\]\n(.*?)(?:\n\n|\Z)", text, re.S | re.M
    )
    mapped = {
        name: ROOT / folder
        for name, folder in re.findall(r'^"([\w.]+)" = "([\w/]+)"$', directories.group(1), re.M)
    }
    on_disk = {
        ".".join(init.parent.relative_to(ROOT).parts)
        for init in (ROOT / "drivee2e_data").rglob("__init__.py")
    }
    for name, folder in mapped.items():
        on_disk |= {
            ".".join((name, *init.parent.relative_to(folder).parts))
            for init in folder.rglob("__init__.py")
        }
    assert listed == on_disk
