"""No module imports a higher layer (docs/architecture.md, "Layers"): every `import` of the
package's own modules, at the top or inside a function, is checked against the layer order."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# (layer, module-name prefixes), lowest first; a module may import its own layer and those below
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("geometry", ("geometry", "arrays", "errors", "processes", "collision")),
    ("data model", ("scenario", "hdmap", "sun", "ego_limits", "binding")),
    ("storage", ("mapjson", "store")),
    ("sources, curation", ("sources", "curation")),
    ("sim", ("sim",)),
    ("sensors", ("sensors",)),
    ("logs", ("logs",)),
    ("metrics", ("metrics",)),
    ("loaders", ("loaders", "splits")),
    ("evaluate", ("evaluate",)),
    ("agents, export", ("agents", "export", "openloop")),
    ("jobs", ("pipeline", "figures", "collect")),
    ("interface", ("cli", "launch")),
)
PACKAGE_FOLDERS = {"collect": ROOT / "collect", "loaders": ROOT / "loaders"}


def _layer(module: str) -> int:
    """The layer index of `drivee2e_data.<module>`."""
    head = module.split(".")[0]
    for index, (_, prefixes) in enumerate(LAYERS):
        if head in prefixes:
            return index
    raise AssertionError(f"drivee2e_data.{module} is in no layer of LAYERS (and of the docs)")


def _modules() -> dict[str, Path]:
    """Every module of the package by its name under drivee2e_data."""
    modules = {}
    for path in (ROOT / "drivee2e_data").rglob("*.py"):
        name = ".".join(path.relative_to(ROOT / "drivee2e_data").with_suffix("").parts)
        modules[name.removesuffix(".__init__")] = path
    for package, folder in PACKAGE_FOLDERS.items():
        for path in folder.rglob("*.py"):
            name = ".".join((package, *path.relative_to(folder).with_suffix("").parts))
            modules[name.removesuffix(".__init__")] = path
    return modules


def _imports(path: Path, module: str) -> set[str]:
    """The package modules `path` imports anywhere in it (names under drivee2e_data)."""
    found = set()
    package = module.split(".")[:-1] if path.name != "__init__.py" else module.split(".")
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: from the module's package
                base = package[: len(package) - node.level + 1]
                names = [".".join(["drivee2e_data", *base, node.module or ""]).rstrip(".")]
            else:
                names = [node.module or ""]
                names += [f"{node.module}.{alias.name}" for alias in node.names]
        else:
            continue
        for name in names:
            if name.startswith("drivee2e_data.") and name != "drivee2e_data":
                found.add(name.removeprefix("drivee2e_data."))
    return found


def test_no_module_imports_a_higher_layer():
    modules = _modules()
    upward = []
    for module, path in modules.items():
        if module in ("__init__", "__main__"):
            continue
        level = _layer(module)
        for target in _imports(path, module):
            if target.split(".")[0] not in {p for _, ps in LAYERS for p in ps}:
                continue  # an attribute of the package root, not a module
            if _layer(target) > level:
                upward.append(f"{module} ({LAYERS[level][0]}) imports {target} "
                              f"({LAYERS[_layer(target)][0]})")  # fmt: skip
    assert not upward, "\n".join(sorted(upward))


def test_every_module_has_a_layer():
    for module in _modules():
        if module not in ("__init__", "__main__"):
            _layer(module)
