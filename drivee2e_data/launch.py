"""The `drivee2e` command's entry point: a collection or an evaluation on a pool of workers starts
the server its workers fork from first, so that its imports (a second or more) run beside the
command's own rather than after them; then the command runs (`cli.main`)."""

from __future__ import annotations

import sys


def main() -> int:
    argv = sys.argv[1:]
    from drivee2e_data.collect import preload as collection
    from drivee2e_data.evaluate import preload as evaluation

    if collection.pools_workers(argv):
        collection.start_worker_server()
    elif evaluation.pools_workers(argv):
        evaluation.start_worker_server(_agent_modules(argv))
    from drivee2e_data.cli import main as cli_main

    return cli_main(argv)


def _agent_modules(argv: list[str]) -> tuple[str, ...]:
    """The module of the built-in agent an `evaluate` command runs (none for another agent, or
    one of its own process, `--agent-cmd`): its pool's workers import it."""
    from drivee2e_data.agents.registry import AGENTS
    from drivee2e_data.processes import argument_value

    if argument_value(argv, "--agent-cmd") is not None:
        return ()
    target = AGENTS.get(argument_value(argv, "--agent") or "expert")
    return (target.partition(":")[0],) if target else ()
