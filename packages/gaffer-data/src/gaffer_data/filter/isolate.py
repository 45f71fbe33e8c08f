"""Feature extraction in spawned worker processes, each object under a time limit.

Each worker serves one object at a time over a pipe. An object that outlives `timeout_s` gets its
worker killed and is recorded as rejected with "timeout after N s"; one that kills its worker (a
segfault in a native loader, the OOM killer) is recorded as crashed, and one that allocates past the
worker's memory cap (`gaffer_data.filter.memory_cap`) as "worker exceeded memory cap of N MB". Either
way a fresh worker takes the next object, so one hostile file never stalls or ends the run. The clock
starts when the worker takes the object, after its start-up imports.
"""

import logging
import math
import multiprocessing
import os
import signal
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from multiprocessing.process import BaseProcess
from pathlib import Path
from typing import Any

from gaffer_data.filter.features import ObjectFeatures, warm_up
from gaffer_data.filter.memory_cap import MEMORY_EXIT_CODE, apply_memory_cap

logger = logging.getLogger(__name__)

Extractor = Callable[..., ObjectFeatures]
"""`extract_features` or a stand-in with its signature; must be importable (spawned workers)."""


def _serve(
    conn: Connection, extract: Extractor, options: dict[str, Any], memory_cap_mb: int
) -> None:
    warm_up()
    apply_memory_cap(memory_cap_mb)  # after the imports: the cap is for the objects
    try:
        while (job := conn.recv()) is not None:
            conn.send("started")
            conn.send(extract(job[0], job[1], **options))
    except MemoryError:
        # Exit at once: reporting could itself fail for memory, and a fresh worker starts clean.
        os._exit(MEMORY_EXIT_CODE)


@dataclass
class _Worker:
    process: BaseProcess
    conn: Connection
    job: tuple[str, Path] | None = None
    started: float | None = None  # when the worker acknowledged the job


def _failed(oid: str, path: Path, error: str) -> ObjectFeatures:
    try:
        size_mb = path.stat().st_size / 2**20
    except OSError:
        size_mb = math.nan
    return ObjectFeatures(object_id=oid, path=str(path), error=error, file_size_mb=size_mb)


def extract_isolated(
    pairs: Sequence[tuple[str, Path]],
    extract: Extractor,
    *,
    workers: int,
    timeout_s: float | None,
    options: dict[str, Any],
    memory_cap_mb: int = 0,
) -> dict[str, ObjectFeatures]:
    """Features of every `(object_id, path)`; timeouts, crashes and memory overruns become `error`s.

    Args:
        pairs: the objects.
        extract: called in a worker as `extract(object_id, path, **options)`.
        workers: worker processes.
        timeout_s: seconds one object may take, or None for no limit.
        options: keyword arguments of `extract`.
        memory_cap_mb: MiB of address space one object may add to its worker (`RLIMIT_AS`, Linux;
            see `gaffer_data.filter.memory_cap`); 0 for no cap.
    """
    ctx = multiprocessing.get_context("spawn")
    pending = deque(pairs)
    results: dict[str, ObjectFeatures] = {}
    pool: list[_Worker] = []

    def spawn() -> _Worker:
        parent, child = ctx.Pipe()
        process = ctx.Process(
            target=_serve, args=(child, extract, options, memory_cap_mb), daemon=True
        )
        process.start()
        child.close()
        return _Worker(process=process, conn=parent)

    def replace(worker: _Worker, error: str) -> None:
        if worker.job is None:  # internal: only busy workers are replaced
            raise RuntimeError("internal error: replacing an idle filter worker")
        oid, path = worker.job
        logger.warning("%s: %s", oid, error)
        results[oid] = _failed(oid, path, error)
        worker.process.kill()
        worker.process.join()
        worker.conn.close()
        pool.remove(worker)

    try:
        while pending or pool:
            idle = sum(w.job is None for w in pool)
            while len(pool) < workers and idle < len(pending):
                pool.append(spawn())
                idle += 1
            for worker in pool:
                if worker.job is None and pending:
                    worker.job = pending.popleft()
                    worker.conn.send(worker.job)
            if not any(w.job for w in pool):
                break
            now = time.monotonic()
            deadlines = [
                w.started + timeout_s
                for w in pool
                if w.started is not None and timeout_s is not None
            ]
            wait_s = max(0.0, min(deadlines) - now) if deadlines else None
            wait([w.conn for w in pool] + [w.process.sentinel for w in pool], timeout=wait_s)
            for worker in list(pool):
                _step(worker, results, replace, timeout_s, memory_cap_mb)
    finally:
        for worker in pool:
            if worker.job is None and worker.process.is_alive():
                try:
                    worker.conn.send(None)  # idle: ask it to exit
                    worker.process.join(timeout=5.0)
                except OSError:
                    pass  # it died meanwhile
            worker.process.kill()
            worker.process.join()
            worker.conn.close()
    return results


def _step(
    worker: _Worker,
    results: dict[str, ObjectFeatures],
    replace: Callable[[_Worker, str], None],
    timeout_s: float | None,
    memory_cap_mb: int,
) -> None:
    """Advance one worker: take its messages, or replace it when it died or ran out of time."""
    try:
        while worker.job is not None and worker.conn.poll():
            message = worker.conn.recv()
            if message == "started":
                worker.started = time.monotonic()
            else:
                results[worker.job[0]] = message
                worker.job, worker.started = None, None
    except (EOFError, OSError):
        pass  # the worker died mid-message: handled below
    if worker.job is None:
        return
    if not worker.process.is_alive():
        replace(worker, _death_reason(worker.process.exitcode, memory_cap_mb))
    elif (
        timeout_s is not None
        and worker.started is not None
        and time.monotonic() - worker.started >= timeout_s
    ):
        replace(worker, f"timeout after {timeout_s:g} s")


def _death_reason(code: int | None, memory_cap_mb: int) -> str:
    if code == MEMORY_EXIT_CODE:
        if memory_cap_mb > 0:
            return f"worker exceeded memory cap of {memory_cap_mb} MB"
        return "worker ran out of memory (no cap set)"
    reason = f"feature extraction crashed the process (exit code {code})"
    # Native code (C++ std::bad_alloc) aborts instead of raising when an allocation fails.
    if memory_cap_mb > 0 and code == -signal.SIGABRT:
        reason += f", possibly at the memory cap of {memory_cap_mb} MB"
    return reason
