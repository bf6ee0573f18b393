"""A closed-loop run's results: each episode's row (`result_row`, written per clip by the
runner into `RUN/episodes/`), the run's summary (SR, DS, RC, infractions per km, SR per
behaviour category, seconds per scene) and `RUN/episodes.parquet`, `summary.json` and
`table.md`."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from drivee2e_data import store
from drivee2e_data.evaluate.episode import EpisodeResult
from drivee2e_data.evaluate.options import EvaluationOptions
from drivee2e_data.metrics.closedloop import COLLISIONS, PENALTY, Infraction

EPISODES_FOLDER = "episodes"
COUNTED = tuple(i for i in Infraction if i is not Infraction.OUTSIDE_ROUTE_LANES)


def result_row(
    scenario: Any, result: EpisodeResult, options: EvaluationOptions, removed: int
) -> dict[str, Any]:
    """An episode's row: its clip, the options that score it, its score, infractions (a count
    of each counted kind, and every event as JSON) and where its wall time went."""
    score = result.score
    behavior = scenario.behavior
    row: dict[str, Any] = {
        "scenario_id": scenario.scenario_id,
        "map_id": scenario.map_id,
        "category": behavior.category.value if behavior else "",
        "sub_scenario": behavior.sub_scenario.value if behavior else "",
        "agent": options.agent if not options.agent_cmd else f"remote:{options.agent_cmd}",
        "variant": options.variant,
        "reactive": options.reactive,
        "seed": options.seed,
        "status": score.status,
        "success": score.success,
        "route_completion": score.route_completion,
        "penalty": score.penalty,
        "driving_score": score.driving_score,
        "outside_lanes_percent": score.outside_lanes_percent,
        "off_road_percent": result.off_road_percent,
        "driven_m": result.driven_m,
        "route_length_m": result.route_length_m,
        "steps": result.steps,
        "sim_seconds": result.sim_seconds,
        "episode_seconds": result.wall_seconds,
        "observe_seconds": result.observe_seconds,
        "agent_seconds": result.agent_seconds,
        "removed_agents": removed,
        "failure": result.failure,
        "events": json.dumps(
            [
                {
                    "infraction": e.infraction.value,
                    "frame": e.frame,
                    "partner_id": e.partner_id,
                    "detail": e.detail,
                }
                for e in score.events
            ]
        ),
    }
    for infraction in COUNTED:
        row[infraction.value] = score.count(infraction)
    return row


def read_rows(out: Path, scenario_ids: list[str]) -> list[dict[str, Any]]:
    rows = []
    for scenario_id in scenario_ids:
        path = out / EPISODES_FOLDER / f"{scenario_id}.json"
        if path.is_file():
            rows.append(json.loads(path.read_text()))
    return rows


def summarize(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """SR, DS, RC, infractions per km, SR per behaviour category, seconds per scene."""
    scored = [r for r in rows if r.get("status") != "error"]
    count = len(scored)
    if count == 0:
        return {"episodes": 0, "errors": len(rows)}
    km = sum(r["driven_m"] for r in scored) / 1000.0
    per_km = {
        i.value: sum(r[i.value] for r in scored) / max(km, 1e-9)
        for i in (*PENALTY, Infraction.ROUTE_DEVIATION, Infraction.AGENT_BLOCKED)
    }
    categories: dict[str, list[bool]] = {}
    for r in scored:
        categories.setdefault(r["category"] or "-", []).append(bool(r["success"]))
    return {
        "episodes": count,
        "errors": len(rows) - count,
        "success_rate": 100.0 * sum(bool(r["success"]) for r in scored) / count,
        "driving_score": float(np.mean([r["driving_score"] for r in scored])),
        "route_completion": float(np.mean([r["route_completion"] for r in scored])),
        "penalty": float(np.mean([r["penalty"] for r in scored])),
        "collisions": sum(r[i.value] for r in scored for i in COLLISIONS),
        "infractions_per_km": per_km,
        "agent_failures": sum(r[Infraction.AGENT_FAILED.value] for r in scored),
        "driven_km": km,
        "seconds_per_scene": float(np.mean([r["wall_seconds"] for r in scored])),
        "sim_seconds_per_scene": float(np.mean([r["sim_seconds"] for r in scored])),
        "success_rate_per_category": {
            name: 100.0 * sum(v) / len(v) for name, v in sorted(categories.items())
        },
        "episodes_per_category": {name: len(v) for name, v in sorted(categories.items())},
    }


def write_results(
    out: Path, rows: list[dict[str, Any]], options: EvaluationOptions
) -> dict[str, Any]:
    """episodes.parquet, summary.json and table.md of a finished run."""
    summary = {"options": options.identity(), **summarize(rows)}
    if rows:
        columns = sorted({key for row in rows for key in row})
        table = pa.Table.from_pylist([{c: row.get(c) for c in columns} for row in rows])
        path = out / "episodes.parquet"
        partial = path.with_name(f".{path.name}.partial")
        pq.write_table(table, partial)
        partial.replace(path)
    store.write_bytes_atomic(out / "summary.json", json.dumps(summary, indent=1).encode())
    store.write_bytes_atomic(out / "table.md", markdown_table(summary).encode())
    return summary


def _unscored_warning(summary: dict[str, Any]) -> list[str]:
    """A line under the scores where some episodes say nothing of the driving: the agent failed
    (scored as a stop: its crash, not its driving) or the clip could not run. A run on a 4-GPU
    host once scored 30 of 40 episodes ended by a CUDA error as DS 10.58 with no sign of it in
    the table."""
    failed, errors = summary.get("agent_failures", 0), summary.get("errors", 0)
    if not failed and not errors:
        return []
    parts = []
    if failed:
        parts.append(f"{failed} of {summary['episodes']} episodes ended by the agent's failure")
    if errors:
        parts.append(f"{errors} clip{'s' if errors > 1 else ''} could not run (not scored)")
    return [f"**Warning: {'; '.join(parts)}**: see `failure` in episodes.parquet.", ""]


def markdown_table(summary: dict[str, Any]) -> str:
    options = summary["options"]
    agent = f"remote `{options['agent_cmd']}`" if options.get("agent_cmd") else options["agent"]
    traffic = "reactive (IDM)" if options["reactive"] else "log replay"
    lines = [f"# {agent}, {options['variant']}, {traffic}", ""]
    if not summary.get("episodes"):
        return "\n".join([*lines, "no episode scored", ""])
    per_km = summary["infractions_per_km"]
    lines += [
        "| episodes | SR % | DS | RC % | collisions/km | red lights/km | s/scene |",
        "|---|---|---|---|---|---|---|",
        f"| {summary['episodes']} | {summary['success_rate']:.1f} | {summary['driving_score']:.2f} "
        f"| {summary['route_completion']:.1f} "
        f"| {sum(per_km[i.value] for i in COLLISIONS):.2f} | {per_km['red_light']:.2f} "
        f"| {summary['seconds_per_scene']:.2f} |",
        "",
        *_unscored_warning(summary),
        "| category | episodes | SR % |",
        "|---|---|---|",
    ]
    for name, rate in summary["success_rate_per_category"].items():
        lines.append(f"| {name} | {summary['episodes_per_category'][name]} | {rate:.1f} |")
    lines += ["", "| infraction | per km |", "|---|---|"]
    lines += [f"| {name} | {value:.2f} |" for name, value in per_km.items()]
    return "\n".join(lines) + "\n"
