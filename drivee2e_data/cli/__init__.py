"""The `drivee2e` command: parses arguments, calls the library, prints. No logic of its own.

One module per group of commands: `data` (synth, import, curate, scenarios, split),
`collection` (view, collect, logs, mesa), `learning` (cache, train, predict, openloop, export) and
`closedloop` (evaluate); `arguments` holds the argument types they share.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from drivee2e_data import __version__
from drivee2e_data.cli import closedloop, collection, data, learning
from drivee2e_data.errors import DriveE2EError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="drivee2e",
        description="Real intersection traffic to simulated expert data and a closed-loop benchmark.",
    )
    parser.add_argument("--version", action="version", version=f"drivee2e-data {__version__}")
    commands = parser.add_subparsers(dest="command", required=True)

    data.add_synth(commands)
    data.add_import(commands)
    collection.add_view(commands)
    data.add_curate(commands)
    data.add_scenarios(commands)
    collection.add_collect(commands)
    data.add_split(commands)
    learning.add_cache(commands)
    learning.add_train(commands)
    learning.add_predict(commands)
    learning.add_openloop(commands)
    learning.add_export(commands)
    closedloop.add_evaluate(commands)
    collection.add_logs(commands)
    collection.add_mesa(commands)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    handlers = {
        "synth": data.run_synth,
        "import": data.run_import,
        "curate": data.run_curate,
        "view": collection.run_view,
        "scenarios": data.run_scenarios,
        "collect": collection.run_collect,
        "logs": collection.run_logs,
        "split": data.run_split,
        "cache": learning.run_cache,
        "train": learning.run_train,
        "predict": learning.run_predict,
        "openloop": learning.run_openloop,
        "export": learning.run_export,
        "evaluate": closedloop.run_evaluate,
        "mesa": collection.run_mesa,
    }
    try:
        return handlers[args.command](args)
    except DriveE2EError as error:
        print(f"drivee2e: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("drivee2e: interrupted; finished outputs are kept, rerun to resume", file=sys.stderr)
        return 130
