"""Where a closed-loop command's start goes: runs it with the timeline probe
(`scripts/dev/timeline/sitecustomize.py`) on PYTHONPATH, then prints, in seconds from the
command's start, when its first episode began, when its first and last worker had their world
set up, when each policy server had its agent built, when the last episode ended and the command
did; with --processes, each process's own marks.

    python scripts/dev/start_timeline.py [--log F] [--processes] -- drivee2e evaluate DATA ...
"""

from __future__ import annotations

import argparse
import collections
import os
import subprocess
import sys
import tempfile
from pathlib import Path

PROBE = Path(__file__).resolve().parent / "timeline"


def read(log: Path) -> dict[int, list[tuple[float, str]]]:
    """Each process's marks (seconds from the first process's start, mark) in time order."""
    rows = []
    for line in log.read_text().splitlines():
        when, pid, tag = line.split(None, 2)
        rows.append((float(when), int(pid), tag.strip()))
    start = min(when for when, _, _ in rows)
    by_process: dict[int, list[tuple[float, str]]] = collections.defaultdict(list)
    for when, pid, tag in sorted(rows):
        by_process[pid].append((when - start, tag))
    return by_process


def summary(by_process: dict[int, list[tuple[float, str]]]) -> list[str]:
    """The start's marks, each where the command reached it."""

    def times(tag: str) -> list[float]:
        return sorted(t for marks in by_process.values() for t, m in marks if m == tag)

    # each process's first world: when that worker could take its first step
    firsts = sorted(
        min(t for t, m in marks if m == "< World")
        for marks in by_process.values()
        if any(m == "< World" for _, m in marks)
    )
    rows = [("first episode began", times("> evaluate_clip")[:1])]
    if firsts:
        rows += [("a worker's world set up", [firsts[0]])]
        rows += [(f"every worker's ({len(firsts)})", [firsts[-1]])]
    rows += [("a policy server ready", times("> SlotReader"))]
    rows += [("last episode ended", times("< evaluate_clip")[-1:])]
    rows += [("the command ended", times("< main")[-1:])]
    return [f"{label:<24} {t:7.2f} s" for label, found in rows for t in found]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--log", type=Path, default=None, help="keep the raw timeline here")
    parser.add_argument("--processes", action="store_true", help="each process's marks too")
    parser.add_argument("command", nargs=argparse.REMAINDER)
    args = parser.parse_args()
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        parser.error("give the command after --")
    log = args.log or Path(tempfile.mkdtemp()) / "timeline.log"
    log.unlink(missing_ok=True)
    env = dict(os.environ, TIMELINE_LOG=str(log))
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(PROBE), env.get("PYTHONPATH")) if p)
    done = subprocess.run(command, env=env, stdout=subprocess.DEVNULL)
    if done.returncode != 0:
        print(f"start_timeline: the command exited with {done.returncode}", file=sys.stderr)
        return done.returncode
    if not log.is_file():
        print(
            "start_timeline: no process of the command logged (not a Python command?)",
            file=sys.stderr,
        )
        return 1
    by_process = read(log)
    print("\n".join(summary(by_process)))
    if args.processes:
        for pid, marks in by_process.items():
            print(pid, " ".join(f"{tag}@{t:.2f}" for t, tag in marks if "evaluate_clip" not in tag))
    return 0


if __name__ == "__main__":
    sys.exit(main())
