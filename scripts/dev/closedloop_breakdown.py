"""Where closed-loop time goes, per run folder: a scene's wall time split into the episode's
drawing and input preparation (`observe_seconds`), the agent's act (its network, or the wait on
its policy server: `agent_seconds`), the rest of the episode (simulation, traffic, rules) and
what lies outside the episode (the set-up: reading the scene, building the agent, the world;
a worker's first scene pays for its agent and GL context), against the
simulated time (the reference: real time).

    python scripts/dev/closedloop_breakdown.py RUN [RUN ...] [--timeline PNG --data DATA]

RUN is an `evaluate` run folder (its `episodes.parquet`). Runs written before the episodes
recorded their observe and agent seconds show those as n/a. Where the episodes have their
`started_at`/`ended_at` and the run folder files `command_started` and `command_ended` (Unix
seconds, written around the command by scripts/dev/device_fourgpu.sh), a second table says
how the command's time divides: before the first episode started (the process, its workers,
the policy servers), the episodes' span, and after the last one ended. Where the run's policy
servers wrote what their batches cost (`policy_server_*.json`), a third table shows it.
`--timeline PNG` draws each run's episodes over its time, a row a worker (an episode goes to
the first row free when it starts: the rows are the workers' if no worker waited), coloured by
the clip's light (night, rain, else day; DATA holds the clips' bundles), its set-up hatched.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pyarrow.parquet as pq


def breakdown(run: Path) -> dict[str, float]:
    """Means over a run's scored episodes, seconds a scene; 'steps' a scene too."""
    table = pq.read_table(run / "episodes.parquet").to_pylist()
    rows = [row for row in table if row.get("status") != "error"]
    if not rows:
        raise SystemExit(f"{run}/episodes.parquet: no scored episode")

    def mean(key: str) -> float:
        values = [row.get(key) for row in rows]
        if any(value is None for value in values):
            return float("nan")
        return sum(values) / len(values)

    keys = ("wall_seconds", "episode_seconds", "observe_seconds", "agent_seconds", "sim_seconds",
            "steps", "read_seconds", "agent_build_seconds", "world_seconds")  # fmt: skip
    result = {key: mean(key) for key in keys}
    result["rest_seconds"] = (
        result["episode_seconds"] - result["observe_seconds"] - result["agent_seconds"]
    )
    result["setup_seconds"] = result["wall_seconds"] - result["episode_seconds"]
    result["episodes"] = len(rows)
    slowest = max(rows, key=lambda row: row["wall_seconds"] - row["episode_seconds"])
    result["slowest"] = tuple(
        slowest.get(key, float("nan")) or 0.0
        for key in ("read_seconds", "agent_build_seconds", "world_seconds")
    )
    return result


def phases(run: Path) -> tuple[float, float, float] | None:
    """(start-up, the episodes' span, wind-down) seconds of a run whose command's times were
    written beside it; None without them."""
    times = [run / "command_started", run / "command_ended"]
    if not all(path.is_file() for path in times):
        return None
    started, ended = (float(path.read_text()) for path in times)
    rows = pq.read_table(run / "episodes.parquet", columns=None).to_pylist()
    first = [row.get("started_at") for row in rows]
    last = [row.get("ended_at") for row in rows]
    if not rows or None in first or None in last:
        return None
    return min(first) - started, max(last) - min(first), ended - max(last)


def lanes(rows: list[dict]) -> list[int]:
    """A row of the drawing for each episode (in `rows`' order): the first whose last episode
    ended by this one's start, in order of starts."""
    ends: list[float] = []
    lane_of = {}
    for index in sorted(range(len(rows)), key=lambda k: rows[k]["started_at"]):
        row = rows[index]
        free = [k for k, end in enumerate(ends) if end <= row["started_at"] + 1e-3]
        lane = free[0] if free else len(ends)
        if lane == len(ends):
            ends.append(0.0)
        ends[lane] = row["ended_at"]
        lane_of[index] = lane
    return [lane_of[k] for k in range(len(rows))]


def draw_timeline(runs: list[Path], data: Path, path: Path) -> None:
    """Each run a panel on one time axis: its episodes on rows (`lanes`), coloured by the clip's
    light, the set-up (read, agent, world) hatched."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from drivee2e_data import store

    colours = {"night": "#26335c", "rain": "#4f86c6", "day": "#f2c14e"}
    tables = [pq.read_table(run / "episodes.parquet").to_pylist() for run in runs]
    longest = max(max(r["ended_at"] for r in t) - min(r["started_at"] for r in t) for t in tables)
    heights = [max(lanes(t)) + 1 for t in tables]
    figure, panels = plt.subplots(len(runs), 1, figsize=(11, sum(0.25 * h + 0.9 for h in heights)),
                                  sharex=True, squeeze=False)  # fmt: skip
    for run, table, axes in zip(runs, tables, panels[:, 0], strict=True):
        start = min(r["started_at"] for r in table)
        for row, lane in zip(table, lanes(table), strict=True):
            conditions = store.read_scenario(data, row["scenario_id"]).conditions
            light = ("night" if conditions.time_of_day.value == "night"
                     else "rain" if conditions.weather.value == "rain" else "day")  # fmt: skip
            left = row["started_at"] - start
            axes.barh(lane, row["ended_at"] - row["started_at"], left=left, height=0.8,
                      color=colours[light], edgecolor="black", linewidth=0.3)  # fmt: skip
            setup = sum(row.get(k) or 0.0 for k in ("read_seconds", "agent_build_seconds",
                                                      "world_seconds"))  # fmt: skip
            axes.barh(lane, setup, left=left, height=0.8, color="none", hatch="////",
                      edgecolor="black", linewidth=0)  # fmt: skip
        span = max(r["ended_at"] for r in table) - start
        axes.set_title(f"{run.name}: the episodes {span:.1f} s", fontsize=10, loc="left")
        axes.set_ylabel("worker")
        axes.set_yticks([])
    panels[-1, 0].set_xlim(0, 1.02 * longest)
    panels[-1, 0].set_xlabel("seconds since the run's first episode began (hatched: set-up)")
    handles = [plt.Rectangle((0, 0), 1, 1, color=c) for c in colours.values()]
    panels[0, 0].legend(handles, list(colours), ncol=3, loc="upper right", fontsize=9)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--timeline", type=Path, default=None, help="draw the episodes here")
    parser.add_argument("--data", type=Path, default=None, help="the clips' data root")
    args = parser.parse_args()
    if args.timeline is not None and args.data is None:
        parser.error("--timeline needs --data (the clips' conditions)")
    print("| run | scenes | steps | wall s | set-up (read, agent, world; the slowest's) "
          "| observe | agent | rest | simulated s | wall / simulated "
          "| ms a step (observe, agent, rest) |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for run in args.runs:
        b = breakdown(run)
        per_step = [1000 * b[k] / max(b["steps"], 1) for k in
                    ("observe_seconds", "agent_seconds", "rest_seconds")]  # fmt: skip
        slowest = ", ".join(f"{value:.2f}" for value in b["slowest"])
        print(f"| {run.name} | {b['episodes']} | {b['steps']:.0f} | {b['wall_seconds']:.2f} "
              f"| {b['setup_seconds']:.2f} ({b['read_seconds']:.2f}, "
              f"{b['agent_build_seconds']:.2f}, {b['world_seconds']:.2f}; {slowest}) "
              f"| {b['observe_seconds']:.2f} | {b['agent_seconds']:.2f} "
              f"| {b['rest_seconds']:.2f} | {b['sim_seconds']:.1f} "
              f"| {b['wall_seconds'] / max(b['sim_seconds'], 1e-9):.2f} "
              f"| {per_step[0]:.1f}, {per_step[1]:.1f}, {per_step[2]:.1f} |")  # fmt: skip
    timed = [(run, phases(run)) for run in args.runs]
    timed = [(run, p) for run, p in timed if p is not None]
    if timed:
        print("\n| run | command s | before the first episode | episodes' span | after the last |")
        print("|---|---|---|---|---|")
        for run, (before, span, after) in timed:
            print(
                f"| {run.name} | {before + span + after:.1f} | {before:.1f} | {span:.1f} "
                f"| {after:.1f} |"
            )
    servers = server_rows(args.runs)
    if servers:
        print("\n| run | server | requests | batches | requests a batch | gathering ms a batch "
              "| network ms a batch | answering ms a batch | warm-up s |")  # fmt: skip
        print("|---|---|---|---|---|---|---|---|---|")
        print("\n".join(servers))
    if args.timeline is not None:
        draw_timeline(args.runs, args.data, args.timeline)
        print(f"\ntimeline: {args.timeline}")


def server_rows(runs: list[Path]) -> list[str]:
    """A table row per policy server of `runs` that wrote its stats."""
    rows = []
    for run in runs:
        for path in sorted(run.glob("policy_server_*.json")):
            s = json.loads(path.read_text())
            rows.append(f"| {run.name} | {s['device']} | {s['requests']} | {s['batches']} "
                        f"| {s['requests_per_batch']:.2f} | {s['gather_ms_per_batch']:.2f} "
                        f"| {s['forward_ms_per_batch']:.2f} | {s['reply_ms_per_batch']:.2f} "
                        f"| {s.get('warm_up_s', 0.0):.2f} |")  # fmt: skip
    return rows


if __name__ == "__main__":
    main()
