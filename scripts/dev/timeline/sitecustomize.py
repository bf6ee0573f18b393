"""The timeline probe of `scripts/dev/start_timeline.py`: on PYTHONPATH with TIMELINE_LOG set,
every Python process of a command (its pools' workers and servers too) appends to that file its
start, the first import of a few heavy modules, and the entries and exits of the functions in
`WRAP`, each with its wall time and process id; with TIMELINE_STEPS set, of each closed-loop
step's observing and acting too (`STEP_WRAP`: "Class.method" names)."""

import functools
import importlib.abc
import os
import sys
import time

LOG = os.environ.get("TIMELINE_LOG")
WRAP = {
    "drivee2e_data.evaluate.runner": [
        "_init_worker",
        "evaluate_clip",
        "_run_pool",
        "prepare_run",
        "_pool_episodes",
    ],
    "drivee2e_data.evaluate.results": ["write_results"],
    "drivee2e_data.evaluate.policy_server": ["serve", "SlotReader", "start_servers"],
    "drivee2e_data.processes": ["_start_worker"],
    "drivee2e_data.sim.world": ["World", "connect", "build_twin", "World.replay"],
    "drivee2e_data.sim.gl_context": ["context"],
    "drivee2e_data.sim.gl_renderer": ["GLRenderer"],
    "drivee2e_data.evaluate.observation": ["SensorObserver"],
    "drivee2e_data.cli": ["main"],
}
STEP_WRAP = {
    "drivee2e_data.evaluate.episode": ["Episode._observe"],
    "drivee2e_data.evaluate.policy_server": ["ServedAgent.act"],
}
if os.environ.get("TIMELINE_STEPS"):
    for _module, _names in STEP_WRAP.items():
        WRAP[_module] = WRAP.get(_module, []) + _names


def note(tag):
    with open(LOG, "a") as f:
        f.write(f"{time.time():.3f} {os.getpid()} {tag}\n")


def marked(target, tag):
    """`target` called between the marks "> tag" and "< tag"."""

    @functools.wraps(target)
    def wrapper(*a, **k):
        note(f"> {tag}")
        try:
            return target(*a, **k)
        finally:
            note(f"< {tag}")

    for cached in ("cache_info", "cache_clear"):  # a functools.cache'd function's own calls
        if hasattr(target, cached):
            setattr(wrapper, cached, getattr(target, cached))
    return wrapper


def wrap(module, name):
    if "." in name:  # a method: wrapped on its class
        owner_name, method = name.split(".")
        owner = getattr(module, owner_name, None)
        if owner is not None and hasattr(owner, method):
            setattr(owner, method, marked(getattr(owner, method), name))
        return
    target = getattr(module, name, None)
    if target is None:
        return
    if isinstance(target, type):  # a class: its construction
        target.__init__ = marked(target.__init__, name)
        return
    setattr(module, name, marked(target, name))


class Finder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path, target=None):
        if fullname not in WRAP:
            return None
        for finder in sys.meta_path:
            if finder is self:
                continue
            spec = (
                finder.find_spec(fullname, path, target) if hasattr(finder, "find_spec") else None
            )
            if spec is not None:
                break
        else:
            return None
        loader = spec.loader
        original = loader.exec_module

        def exec_module(module):
            original(module)
            for name in WRAP[fullname]:
                wrap(module, name)

        loader.exec_module = exec_module
        return spec


if LOG:
    note("interpreter " + " ".join(sys.argv)[:60])
    sys.meta_path.insert(0, Finder())
    _seen: set[str] = set()

    def audit(event, args):
        if event == "import" and args[0] in ("torch", "pybullet", "moderngl", "cv2"):
            if args[0] not in _seen:
                _seen.add(args[0])
                note(f"import {args[0]}")

    sys.addaudithook(audit)
