"""Process pools as the collector and the evaluator use them."""

from __future__ import annotations

import os
import signal
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor


def stop_pool(pool: ProcessPoolExecutor) -> None:
    """Stop the workers now (Ctrl-C or an error in the parent) rather than after every queued
    job; jobs already finished keep their outputs."""
    for process in list(getattr(pool, "_processes", {}).values()):
        process.terminate()
    pool.shutdown(wait=True, cancel_futures=True)


def clean_up_when_stopped(clean_up: Callable[[], None]) -> None:
    """In a pool worker: on SIGTERM (the parent's `stop_pool`) run `clean_up` (delete the
    worker's temporary files) and exit at once; the signal's default action ends the process
    without `atexit`, and left them in the temp folder."""

    def stop(signum: int, _frame: object) -> None:
        clean_up()
        os._exit(128 + signum)

    signal.signal(signal.SIGTERM, stop)
