"""What every replay loop shares (no ROS import): the recording read once, each scan counted as it is read
(``results.frames_read`` and the ``progress`` callback), every ``stride``-th scan kept, and Ctrl-C ending the loop
with the results so far, marked incomplete (:func:`keep_on_interrupt`)."""

from __future__ import annotations

from collections.abc import Callable, Collection, Iterable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from deepbbs_ros.datasets.base import Scan

#: the error line of a run that Ctrl-C ended (its results so far are kept, marked incomplete)
INTERRUPTED = "interrupted by the user (Ctrl-C)"


def counted(scans: Iterable[Scan], results: Any, progress: Callable[[int], None] | None = None,
            ) -> Iterator[tuple[int, Scan]]:
    """(position in the stream, scan) of every scan read, each counted in ``results.frames_read`` and passed to
    ``progress(1)`` as it is read."""
    for pos, scan in enumerate(scans):
        results.frames_read += 1
        if progress:
            progress(1)
        yield pos, scan


def strided(scans: Iterable[Scan], results: Any, stride: int, progress: Callable[[int], None] | None = None,
            skip: Collection[int] = ()) -> Iterator[tuple[int, Scan]]:
    """:func:`counted`, keeping every ``stride``-th position not in ``skip`` (every scan read is counted)."""
    for pos, scan in counted(scans, results, progress):
        if pos % stride or pos in skip:
            continue
        yield pos, scan


def mark_interrupted(results: Any) -> None:
    """``results`` (``complete``, ``errors``) marked as ended by Ctrl-C."""
    results.complete = False
    results.errors.append(INTERRUPTED)


@contextmanager
def keep_on_interrupt(results: Any) -> Iterator[Any]:
    """Ctrl-C inside the block ends it: the results so far kept, marked incomplete (:func:`mark_interrupted`); other
    errors propagate."""
    try:
        yield results
    except KeyboardInterrupt:
        mark_interrupted(results)
