"""CPU threads: how many this process may use (its affinity), and ``0`` read as all of them.

Every small_gicp call and every library thread count (``eval.threads``, ``registration.polish_threads``,
``registration.gicp_threads``) goes through :func:`threads_or_all`. No ROS import.
"""

from __future__ import annotations

import os

__all__ = ["cpu_cores", "threads_or_all"]


def cpu_cores() -> int:
    """The CPU cores this process may run on (its affinity: ``taskset``, a container's cpuset), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # no affinity on this platform
        return max(1, os.cpu_count() or 1)


def threads_or_all(n: int) -> int:
    """``n`` threads, or every CPU core this process may use for ``n <= 0``."""
    return n if n > 0 else cpu_cores()
