"""A part of a recording: the scans from ``--start`` to ``--end`` seconds after its first scan.

The unit is seconds since the recording's first scan (its header stamp), the same in ``deepbbs-replay`` and
``deepbbs-bag map``, so that one drive splits into a mapping part and a localization part::

    deepbbs-bag map drive.mcap site.pcd --end 60
    deepbbs-replay drive.mcap --mode localization --map site.pcd --start 60

The window is half open, ``start <= t < end``: the two commands above share no scan. Scans keep their frame
numbers in the recording.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from deepbbs_ros.datasets.base import Scan, ScanSource
from deepbbs_ros.errors import ConfigError, DatasetError


class TimeWindow:
    """The scans of ``source`` (a :class:`~deepbbs_ros.datasets.base.ScanSource`) with ``start <= t < end``, t the
    seconds since its first scan's stamp (None: from the first / to the last). Reading stops at the first scan past
    ``end``. Everything else (``errors``, ``warnings``, ``has_ground_truth``, ``close``...) is the source's;
    ``len()`` is the source's (an upper bound)."""

    def __init__(self, source: ScanSource, start: float | None = None, end: float | None = None) -> None:
        check_window(start, end)
        self.source, self.start, self.end = source, start, end
        self.kept = 0
        self.span_s = 0.0  # seconds from the first scan to the last one read

    def __iter__(self) -> Iterator[Scan]:
        t0 = None
        self.kept = 0
        for scan in self.source:
            t0 = scan.stamp_ns if t0 is None else t0
            t = (scan.stamp_ns - t0) * 1e-9
            self.span_s = max(self.span_s, t)
            if self.start is not None and t < self.start:
                continue
            if self.end is not None and t >= self.end:
                break
            self.kept += 1
            yield scan

    def __len__(self) -> int:
        return len(self.source)

    def __getattr__(self, name: str) -> Any:
        if name == "source":  # not set yet (copying): no recursion
            raise AttributeError(name)
        return getattr(self.source, name)

    def check_not_empty(self) -> None:
        """DatasetError naming the window when it held no scan (after the recording was read)."""
        if self.kept == 0 and (self.start is not None or self.end is not None):
            raise DatasetError(f"{self.source.path}: no scan from --start {self.start or 0:g} s to --end "
                               f"{'the end' if self.end is None else f'{self.end:g} s'} (the scans read span "
                               f"{self.span_s:.1f} s from the first one)")


def check_window(start: float | None, end: float | None) -> None:
    """ConfigError unless ``0 <= start < end`` (either may be None)."""
    if start is not None and not start >= 0:
        raise ConfigError(f"--start must be >= 0 s (since the first scan), got {start:g}")
    if end is not None and not end > (start or 0):
        raise ConfigError(f"--end must be after --start ({start or 0:g} s), got {end:g}")


def windowed(source: ScanSource, start: float | None, end: float | None) -> Any:
    """``source`` itself when no window is asked, else a :class:`TimeWindow` over it."""
    return source if start is None and end is None else TimeWindow(source, start, end)
