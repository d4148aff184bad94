"""The calling thread held on one CPU while a block runs (:func:`one_cpu`): KISS-ICP's and KISS-Matcher's TBB sums
grouped as on one CPU, the same on any machine (no ROS import)."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager


def _current_cpu(cpus: set[int]) -> int:
    """The CPU this thread last ran on (Linux: /proc/thread-self/stat, field 39), else the first allowed one."""
    try:
        with open("/proc/thread-self/stat", "rb") as fh:
            cpu = int(fh.read().rsplit(b")", 1)[1].split()[36])
    except (OSError, ValueError, IndexError):
        return min(cpus)
    return cpu if cpu in cpus else min(cpus)


@contextmanager
def one_cpu(on: bool = True) -> Iterator[None]:
    """The calling thread on one CPU while the block runs (Linux; elsewhere, or ``on`` False: nothing).

    KISS-ICP and KISS-Matcher compute with TBB, whose parallel sums group their terms by the number of CPUs the
    calling thread may use, even on one thread (KISS-ICP's ``max_num_threads``: 1); KISS-Matcher has no thread
    setting at all (its answer varied from run to run on 2 cores). In this block they see one CPU: one thread and
    the same sums on any machine. With ``eval.threads`` 1 every call of either runs in this block. The CPU is the
    one the thread is running on already, so that processes side by side (a fleet's tasks) do not all queue on
    the same CPU."""
    if not on or not hasattr(os, "sched_setaffinity"):
        yield
        return
    cpus = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {_current_cpu(cpus)})
    try:
        yield
    finally:
        os.sched_setaffinity(0, cpus)
