"""Where a closed-loop command's start goes: runs it with the timeline probe
(`scripts/dev/timeline/sitecustomize.py`) on PYTHONPATH, then prints, in seconds from the
command's start, when its first episode began, when its first and last worker had their world
set up, when each policy server had its agent built, when the last episode ended and the command
did; with --durations, each wrapped function's calls (count, mean, slowest: a world's set-up by
its parts); with --processes, each process's own marks; with --steps, every closed-loop step's too
(its observing and its agent's act, TIMELINE_STEPS), tabulated over the run's wall time: the
episodes stepping in each window and their steps' mean time, observing and acting.

    python scripts/dev/start_timeline.py [--log F] [--durations] [--processes] [--steps [--window S]]
        -- drivee2e evaluate DATA ...
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


def durations(by_process: dict[int, list[tuple[float, str]]]) -> list[str]:
    """Each wrapped function's calls over every process: how many, their mean and slowest
    seconds (a world's set-up by its parts: the GL context, the twin, the actors, the
    renderer)."""
    spans: dict[str, list[float]] = collections.defaultdict(list)
    for marks in by_process.values():
        open_at: dict[str, list[float]] = collections.defaultdict(list)
        for t, tag in marks:
            if tag.startswith("> "):
                open_at[tag[2:]].append(t)
            elif tag.startswith("< ") and open_at[tag[2:]]:
                spans[tag[2:]].append(t - open_at[tag[2:]].pop())
    lines = ["| function | calls | mean s | slowest s |", "|---|---|---|---|"]
    for name, seconds in sorted(spans.items(), key=lambda item: -sum(item[1])):
        lines.append(f"| {name} | {len(seconds)} | {sum(seconds) / len(seconds):.3f} "
                     f"| {max(seconds):.3f} |")  # fmt: skip
    return lines


def steps(by_process: dict[int, list[tuple[float, str]]], window_s: float) -> list[str]:
    """Each closed-loop step (from one observing's start to the next in the same episode) in
    windows of `window_s` of the run by its start: the episodes stepping, the steps' mean ms,
    and of it observing and acting (the agent's act on its policy server)."""
    rows = []  # (start, step s, observe s, act s)
    for marks in by_process.values():
        begun = observing = acting = None
        acted = 0.0
        for t, tag in marks:
            if tag in ("> evaluate_clip", "< evaluate_clip"):
                begun = None  # an episode's last step has no end marked: left out
            elif tag == "> Episode._observe":
                if begun is not None and observing is not None:
                    rows.append((begun, t - begun, observing, acted))
                begun, observing, acted = t, None, 0.0
            elif tag == "< Episode._observe" and begun is not None:
                observing = t - begun
            elif tag == "> ServedAgent.act":
                acting = t
            elif tag == "< ServedAgent.act" and acting is not None:
                acted = t - acting
    if not rows:
        return ["no steps logged (run with --steps, and an agent served by a policy server)"]
    lines = ["| window (s) | episodes stepping | steps | ms a step | observing | acting |",
             "|---|---|---|---|---|---|"]  # fmt: skip
    last = max(start for start, *_ in rows)
    edge = 0.0
    while edge <= last:
        inside = [r for r in rows if edge <= r[0] < edge + window_s]
        if inside:
            stepping = len(inside) * sum(r[1] for r in inside) / len(inside) / window_s
            lines.append(
                f"| {edge:.0f}-{edge + window_s:.0f} | {stepping:.1f} | {len(inside)} "
                f"| {1000 * sum(r[1] for r in inside) / len(inside):.1f} "
                f"| {1000 * sum(r[2] for r in inside) / len(inside):.1f} "
                f"| {1000 * sum(r[3] for r in inside) / len(inside):.1f} |"
            )
        edge += window_s
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--log", type=Path, default=None, help="keep the raw timeline here")
    parser.add_argument("--processes", action="store_true", help="each process's marks too")
    parser.add_argument("--steps", action="store_true", help="every closed-loop step's too")
    parser.add_argument(
        "--durations",
        action="store_true",
        help="each wrapped function's calls: count, mean and slowest seconds",
    )
    parser.add_argument("--window", type=float, default=2.0, help="--steps' window, seconds")
    parser.add_argument("command", nargs=argparse.REMAINDER)
    args = parser.parse_args()
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        parser.error("give the command after --")
    log = args.log or Path(tempfile.mkdtemp()) / "timeline.log"
    log.unlink(missing_ok=True)
    env = dict(os.environ, TIMELINE_LOG=str(log))
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(PROBE), env.get("PYTHONPATH")) if p)
    if args.steps:
        env["TIMELINE_STEPS"] = "1"
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
    if args.durations:
        print("\n".join(durations(by_process)))
    if args.steps:
        print("\n".join(steps(by_process, args.window)))
    if args.processes:
        for pid, marks in by_process.items():
            print(pid, " ".join(f"{tag}@{t:.2f}" for t, tag in marks if "evaluate_clip" not in tag))
    return 0


if __name__ == "__main__":
    sys.exit(main())
