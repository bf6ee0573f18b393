"""Process pools as the collector and the evaluator use them."""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor


def stop_pool(pool: ProcessPoolExecutor) -> None:
    """Stop the workers now (Ctrl-C or an error in the parent) rather than after every queued
    job; jobs already finished keep their outputs."""
    for process in list(getattr(pool, "_processes", {}).values()):
        process.terminate()
    pool.shutdown(wait=True, cancel_futures=True)
