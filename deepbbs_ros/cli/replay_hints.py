"""deepbbs-replay's hints: where a recording keeps its ground truth, and which --stride / --max-dist give more
pairs when a recording gave few."""

from __future__ import annotations

from pathlib import Path


def ground_truth_hint(source) -> str:
    """Where a recording of ``source``'s format keeps its ground truth, for a source without it: the pose
    file of a folder (where and in which format), the topics a bag could take with --gt-topic."""
    path = Path(source.path)
    fmt = getattr(source, "format", "")
    if fmt == "kitti" and getattr(source, "truth_note", ""):
        return source.truth_note
    if fmt == "kitti":
        return (f"add poses.txt to the folder (or ../../poses/{path.name}.txt, KITTI's dataset/poses/): KITTI "
                "odometry format, one line of 12 numbers per scan (the 3x4 row-major pose of camera 0), with "
                "calib.txt holding its 'Tr:' line (LiDAR to camera 0)")
    if fmt == "apollo":
        return ("add poses/gt_poses.txt to the folder: one line per scan, 'index timestamp x y z qx qy qz qw' "
                "(the LiDAR's pose in the world)")
    if fmt == "folder":
        return ("a folder of scans has none: put the scans in a KITTI folder (velodyne/NNNNNN.bin + poses.txt + "
                "calib.txt) or an Apollo folder (pcds/N.pcd + poses/gt_poses.txt)")
    from deepbbs_ros.datasets.rosbag import POSE_TYPES

    topics = getattr(getattr(source, "backend", None), "topics", {}) or {}
    poses = sorted(t for t, (typ, _n) in topics.items() if typ in POSE_TYPES)
    if poses:
        return f"give --gt-topic, one of {', '.join(poses)}"
    kinds = ", ".join(t.rsplit("/", 1)[-1] for t in POSE_TYPES)
    return f"the recording has no pose topic ({kinds}) to give with --gt-topic"


class PositionLog:
    """Iterates a scan source and keeps each scan's ground-truth position ((3,) float64, or None) in stream
    order, for :func:`pair_count_hint`."""

    def __init__(self, source) -> None:
        self.source = source
        self.positions: list = []

    def __iter__(self):
        for scan in self.source:
            T = scan.T_world_lidar
            self.positions.append(None if T is None else [float(v) for v in T[:3, 3]])
            yield scan

    def __len__(self) -> int:
        return len(self.source)


#: fewer pairs than this from a whole recording get a hint (a smaller stride or a larger max distance)
FEW_PAIRS = 10


def count_pairs(positions: list, stride: int, max_dist: float, max_gap: int) -> int:
    """How many pairs :func:`deepbbs_ros.replay.runner.iter_pairs` makes from scans at ``positions`` (stream
    order; None: no ground truth): the protocol itself, run on poses that hold only those positions."""
    from types import SimpleNamespace

    import numpy as np

    from deepbbs_ros.replay.runner import iter_pairs

    def pose(p):
        if p is None:
            return None
        T = np.eye(4)
        T[:3, 3] = p
        return T

    scans = [SimpleNamespace(T_world_lidar=pose(p)) for p in positions]
    return sum(1 for _ in iter_pairs(scans, stride, max_dist, max_gap))


def pair_count_hint(positions: list, ev, pairs: int) -> str | None:
    """A line saying why a recording gave only ``pairs`` pairs and which --stride / --max-dist give more
    (counted on the recording's own ground truth), or None when the count is not small or nothing gives more."""
    import math

    import numpy as np

    n = len(positions)
    if pairs >= FEW_PAIRS or n < 2:
        return None
    why = (f"{pairs} pair{'s' if pairs != 1 else ''} from {n} frames: pairs mode takes a source every "
           f"eval.stride = {ev.stride} frames and as its target the last frame within eval.max_dist = "
           f"{ev.max_dist:g} m")
    candidates = sorted({max(1, n // k) for k in range(1, FEW_PAIRS + 1)} | {1}, reverse=True)

    def best_stride(dist: float) -> tuple[int, int] | None:
        """The largest stride (up to eval.stride) giving FEW_PAIRS pairs, or as many as stride 1 gives."""
        most = count_pairs(positions, 1, dist, ev.max_pair_frames)
        if most <= pairs:
            return None
        for stride in candidates:
            got = count_pairs(positions, stride, dist, ev.max_pair_frames) if stride <= ev.stride else -1
            if got >= min(FEW_PAIRS, most):
                return stride, got
        return None  # pragma: no cover - stride 1 is a candidate

    flags, count = "", pairs
    found = best_stride(ev.max_dist)
    if found:
        flags, count = f"--stride {found[0]}", found[1]
    if count < FEW_PAIRS:  # scans farther apart than max_dist: sources without a target
        P = [np.asarray(p) for p in positions if p is not None]
        steps = [float(np.linalg.norm(b - a)) for a, b in zip(P, P[1:])]
        step = float(np.median(steps)) if steps else 0.0
        if step > ev.max_dist:
            dist = float(math.ceil(1.5 * step))
            found = best_stride(dist)
            if found and found[1] > count:
                stride_flag = f"--stride {found[0]} " if found[0] != ev.stride else ""
                flags, count = f"{stride_flag}--max-dist {dist:g} (the scans are {step:.1f} m apart)", found[1]
    if not flags:
        return None
    return f"{why}; {flags} gives {count} pairs"
