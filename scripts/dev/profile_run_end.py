"""Where the end of a collection goes, in the parent process: from the workers' last frame to
the command's summary, each clip's log made final from its segments, the pool's shutdown (its
workers' exits) and the index.

    python scripts/dev/profile_run_end.py DATA [more `drivee2e collect` options]

Runs `drivee2e collect DATA ...` (`--workers auto` unless given) in this process (its pool's server started
first, as the command does) with the parent's steps stamped, then prints them in seconds from
the collection's start, and the end's parts:

  - logs: the last frame to the last log made final (`_ClipTracker.write_log`: the last
    segments copied, the summary written, fsync);
  - exits: the pool told to exit to its workers gone (`ProcessPoolExecutor.shutdown`);
  - end: the last frame to `collect` returning, as `bench_collect.py`'s "end".

On an H100 host each worker's EGL context is torn down one at a time by the driver, so the
exits grow with the workers (`scripts/dev/bench_context_exit.py`).
"""

from __future__ import annotations

import sys
import threading
import time
from dataclasses import dataclass, field


@dataclass
class Stamps:
    """The parent's steps, in `time.time()` seconds."""

    started: float = 0.0  # `collect` called
    returned: float = 0.0  # `collect` returned
    last_frame: float = 0.0  # the workers' last frame ended (from the units' spans)
    logs: list[tuple[str, float, float]] = field(default_factory=list)  # clip, begun, ended
    shutdowns: list[tuple[bool, float, float]] = field(default_factory=list)  # wait, begun, ended
    lock: threading.Lock = field(default_factory=threading.Lock)

    def log(self, clip: str, begun: float, ended: float) -> None:
        with self.lock:
            self.logs.append((clip, begun, ended))


def end_parts(stamps: Stamps) -> dict[str, float]:
    """The end's parts in seconds (module docstring): `logs` (the last frame to the last log
    final, 0 if none ended after it), `exits` (the first shutdown call to the workers gone: the
    end of the last call), and `end` (the last frame to `collect` returning)."""
    last_log = max((ended for _, _, ended in stamps.logs), default=stamps.last_frame)
    exits = 0.0
    if stamps.shutdowns:
        exits = max(e for _, _, e in stamps.shutdowns) - min(b for _, b, _ in stamps.shutdowns)
    return {
        "logs": max(0.0, last_log - stamps.last_frame),
        "exits": exits,
        "end": stamps.returned - stamps.last_frame,
    }


def _stamped(stamps: Stamps) -> None:
    """Wrap the parent's steps so that each stamps `stamps` as it runs."""
    from concurrent.futures.process import ProcessPoolExecutor

    from drivee2e_data.collect import runner

    shutdown = ProcessPoolExecutor.shutdown

    def stamped_shutdown(self, wait=True, **kwargs):
        begun = time.time()
        try:
            return shutdown(self, wait=wait, **kwargs)
        finally:
            stamps.shutdowns.append((wait, begun, time.time()))

    ProcessPoolExecutor.shutdown = stamped_shutdown
    write_log = runner._ClipTracker.write_log

    def stamped_write_log(self, scenario_id):
        begun = time.time()
        try:
            return write_log(self, scenario_id)
        finally:
            stamps.log(scenario_id, begun, time.time())

    runner._ClipTracker.write_log = stamped_write_log
    collect = runner.collect

    def stamped_collect(*args, **kwargs):
        summary = collect(*args, **kwargs)
        stamps.returned = time.time()
        stamps.started = summary.started
        spans = [span for result in summary.results for span in result.spans]
        stamps.last_frame = max((span[1] for span in spans), default=stamps.returned)
        return summary

    runner.collect = stamped_collect


def main() -> int:
    if len(sys.argv) < 2 or sys.argv[1].startswith("-"):
        print(__doc__.split("\n\n")[1], file=sys.stderr)
        return 2
    argv = ["collect", sys.argv[1], *sys.argv[2:]]
    if not any(word.split("=")[0] == "--workers" for word in argv):
        argv += ["--workers", "auto"]
    from drivee2e_data.collect.preload import pools_workers, start_worker_server

    if pools_workers(argv):
        start_worker_server()
    stamps = Stamps()
    _stamped(stamps)
    from drivee2e_data.cli import main as cli_main

    code = cli_main(argv)
    if stamps.returned == 0.0:
        return code
    print(f"\nthe parent's steps, s from the collection's start ({len(stamps.logs)} logs):")
    rows = [(stamps.last_frame, "the workers' last frame ended")]
    rows += [(ended, f"log {clip} final ({ended - begun:.2f} s)") for clip, begun, ended in
             sorted(stamps.logs, key=lambda log: log[2])[-4:]]  # fmt: skip
    rows += [(begun, f"pool shutdown (wait={wait}) called, returned after {ended - begun:.2f} s")
             for wait, begun, ended in stamps.shutdowns]  # fmt: skip
    rows.append((stamps.returned, "collect returned"))
    for at, what in sorted(rows):
        print(f"  {at - stamps.started:8.2f}  {what}")
    parts = end_parts(stamps)
    print(
        f"end {parts['end']:.2f} s after the last frame: the last logs took {parts['logs']:.2f} "
        f"s of it, the workers' exits {parts['exits']:.2f} s (beside the logs where the pool is "
        "told to exit first)"
    )
    return code


if __name__ == "__main__":
    sys.exit(main())
