"""The `drivee2e` command's entry point: a collection on a pool of workers starts the server its
workers fork from first, so that its imports (about a second) run beside the command's own
rather than after them; then the command runs (`cli.main`)."""

from __future__ import annotations

import sys


def main() -> int:
    argv = sys.argv[1:]
    from drivee2e_data.collect.preload import pools_workers, start_worker_server

    if pools_workers(argv):
        start_worker_server()
    from drivee2e_data.cli import main as cli_main

    return cli_main(argv)
