"""A closed-loop run's summary and table (`evaluate.results`): the scores, and a warning where
episodes say nothing of the driving."""

from __future__ import annotations

from drivee2e_data.evaluate.options import EvaluationOptions
from drivee2e_data.evaluate.results import markdown_table, summarize
from drivee2e_data.metrics.closedloop import Infraction


def _row(scenario_id: str, score: float, failed: bool = False) -> dict:
    row = {i.value: 0 for i in Infraction}
    row.update(scenario_id=scenario_id, status="agent_failed" if failed else "completed",
               driven_m=100.0, category="STR", success=not failed, driving_score=score,
               route_completion=score, penalty=1.0, wall_seconds=2.0, sim_seconds=10.0)  # fmt: skip
    row[Infraction.AGENT_FAILED.value] = int(failed)
    return row


def _table(rows: list[dict]) -> str:
    options = EvaluationOptions(agent="tcp").identity()
    return markdown_table({"options": options, **summarize(rows)})


def test_a_clean_run_has_no_warning() -> None:
    table = _table([_row("a", 100.0), _row("b", 50.0)])
    assert "| 2 | 100.0 | 75.00 | 75.0 |" in table
    assert "Warning" not in table


def test_agent_failures_and_clips_that_could_not_run_are_named_under_the_scores() -> None:
    rows = [_row("a", 100.0), _row("b", 0.0, failed=True), _row("c", 0.0, failed=True)]
    rows.append({"scenario_id": "d", "status": "error", "failure": "no such map"})
    summary = summarize(rows)
    assert summary["agent_failures"] == 2 and summary["errors"] == 1
    table = _table(rows)
    assert (
        "**Warning: 2 of 3 episodes ended by the agent's failure; 1 clip could not run "
        "(not scored)**" in table
    )
    assert table.index("Warning") < table.index("| category |")
