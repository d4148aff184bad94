"""A recording read as scans (:class:`ScanSource`, every reader's base) and a sized iterable of scans for writers;
the scan record (datasets/scan.py) and the helpers the file readers and writers share (datasets/scan_files.py)
are imported from here too."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from deepbbs_ros.datasets.poses import (  # noqa: F401  (re-exported)
    PoseTrack,
    T_to_xyzquat,
    parse_stamp,
    stamp_to_str,
    xyzquat_to_T,
)
from deepbbs_ros.datasets.scan import (  # noqa: F401  (re-exported)
    ABSOLUTE_TIME_FIELD,
    APOLLO_LIDAR_FRAME,
    APOLLO_LIDAR_TOPIC,
    APOLLO_RAW_LIDAR_TOPIC,
    GT_POSE_TOPIC,
    TIME_FIELDS,
    WORLD_FRAME,
    Scan,
    time_field,
    time_offsets,
)
from deepbbs_ros.datasets.scan_files import (  # noqa: F401  (re-exported)
    check_ground_truth,
    check_scan_file,
    missing_pose_error,
    numbered_files,
    prepare_output,
    scan_intensity,
    valid_mask,
)
from deepbbs_ros.errors import DatasetError


class ScanSource:
    """A recording read as a sequence of :class:`Scan` in stamp order.

    Subclasses fill ``path``, ``topic``, ``has_ground_truth`` and implement :meth:`_scans` and
    :meth:`__len__`. With ``lenient=True`` iteration stops quietly at the first fault, after yielding
    every valid scan before it, and appends the fault's message to :attr:`errors`; damage that costs
    only itself (a damaged scan file, a damaged bag chunk: :meth:`skip`) is recorded the same way and
    reading goes on after it. Otherwise every fault raises :class:`~deepbbs_ros.errors.DatasetError`
    (or its subclass ``BagError``).
    """

    format: str = "?"

    def __init__(self, path: Path | str, *, lenient: bool = False) -> None:
        self.path = Path(path)
        self.lenient = lenient
        self.topic: str | None = None
        self.gt_topic: str | None = None
        self.has_ground_truth = False
        self.errors: list[str] = []
        self.fault_at: list[int] = []
        self._deferred: list[DatasetError] = []
        self.warnings: list[str] = []  # damage that cost nothing (e.g. a summary rebuilt by reading)

    def _scans(self) -> Iterator[Scan]:  # pragma: no cover - abstract
        raise NotImplementedError

    def __len__(self) -> int:  # pragma: no cover - abstract
        raise NotImplementedError

    def __iter__(self) -> Iterator[Scan]:
        self.yielded = 0
        try:
            for scan in self._scans():
                self.yielded += 1
                yield scan
        except DatasetError as err:
            if not self.lenient:
                raise
            self.fault(err)
        else:  # damage found on opening that no scan ran into (e.g. a bad line after the last frame's pose)
            self.warnings.extend(str(e) for e in self._deferred if str(e) not in self.warnings)

    def defer(self, err: DatasetError) -> None:
        """Damage found on opening (a pose file's bad line): raise when strict; when lenient, the scans
        before it are read and the scan that needs what it lost raises it (then recorded by
        :meth:`fault`, with its position)."""
        if not self.lenient:
            raise err
        self._deferred.append(err)

    def fault(self, err: DatasetError) -> None:
        """Raise ``err``, or record it (once) when lenient; the caller then stops as it documents.
        ``fault_at`` keeps, for each recorded fault, how many scans had been yielded before it."""
        if not self.lenient:
            raise err
        if str(err) not in self.errors:
            self.errors.append(str(err))
            self.fault_at.append(getattr(self, "yielded", 0))

    def skip(self, err: DatasetError) -> None:
        """Damage that costs only itself (one scan file, one bag chunk): raise ``err`` when strict;
        when lenient record it and let reading go on after it."""
        if not self.lenient:
            raise err
        self.fault(type(err)(f"{err}; skipped, reading went on"))

    def close(self) -> None:
        """Release open files (bags); iterating afterwards is not supported."""

    def __enter__(self) -> ScanSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def info(self) -> dict[str, Any]:
        """Summary for ``deepbbs-bag info``: format, path, topic, frames, ground truth."""
        return {
            "path": str(self.path),
            "format": self.format,
            "topic": self.topic,
            "gt_topic": self.gt_topic,
            "frames": len(self),
            "ground_truth": self.has_ground_truth,
        }

    def __repr__(self) -> str:
        return f"{type(self).__name__}({str(self.path)!r}, frames={len(self)}, ground_truth={self.has_ground_truth})"


class SizedIterable:
    """Wrap an iterator with a known length, so progress bars show a total (``write_scans(SizedIterable(it, n))``)."""

    def __init__(self, iterable: Iterable[Scan], length: int) -> None:
        self._iterable = iterable
        self._length = int(length)

    def __iter__(self) -> Iterator[Scan]:
        return iter(self._iterable)

    def __len__(self) -> int:
        return self._length
