"""An address-space cap for filter workers (`RLIMIT_AS`), so one object cannot exhaust the machine.

The cap counts what an object's extraction adds on top of the worker after its start-up imports: the
worker measures its own address space once warmed up and sets `RLIMIT_AS` to that plus the cap. The
libraries' own reservations (thread stacks, BLAS buffers, malloc arenas) differ by machine and say
nothing about the object, so an absolute limit would fail healthy workers on some machines. Past the
cap, allocations fail: Python raises `MemoryError`, the worker exits with `MEMORY_EXIT_CODE`, and the
parent records "worker exceeded memory cap of N MB" and starts a fresh worker.

Linux only (it reads `/proc/self/statm`); elsewhere `memory_cap_supported()` is False and workers run
uncapped.
"""

import logging
import os
import sys

logger = logging.getLogger(__name__)

DEFAULT_MAX_WORKER_MEMORY_MB = 4096
"""Default cap per worker (MiB above its loaded libraries); a 2M-face GLB needs well under 2 GiB."""

MEMORY_EXIT_CODE = 86
"""Exit status of a worker that hit `MemoryError` (any value Python and signals do not use)."""


def memory_cap_supported() -> bool:
    """Whether this platform can cap a worker (Linux with the `resource` module)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        import resource
    except ImportError:
        return False
    return hasattr(resource, "RLIMIT_AS") and os.path.exists("/proc/self/statm")


def address_space_bytes() -> int:
    """This process's virtual memory size (what `RLIMIT_AS` limits), from `/proc/self/statm`."""
    with open("/proc/self/statm", encoding="ascii") as fh:
        pages = int(fh.read().split()[0])
    return pages * os.sysconf("SC_PAGE_SIZE")


def apply_memory_cap(cap_mb: int) -> bool:
    """Limit this process's further address space to `cap_mb` MiB (called inside a warmed-up worker).

    Args:
        cap_mb: MiB the process may add from now on; 0 means no cap.

    Returns:
        Whether a cap is in force (False for 0 or where unsupported; a warning is logged then).
    """
    if cap_mb <= 0:
        return False
    if not memory_cap_supported():
        logger.warning("memory caps need Linux: this filter worker runs without one")
        return False
    import resource

    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    limit = address_space_bytes() + cap_mb * 2**20
    if hard != resource.RLIM_INFINITY:
        limit = min(limit, hard)
    if soft != resource.RLIM_INFINITY and soft <= limit:
        return True  # an outer limit is already tighter: keep it
    try:
        resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
    except (ValueError, OSError) as exc:
        logger.warning("cannot cap this filter worker's memory (%s): it runs without a cap", exc)
        return False
    return True
