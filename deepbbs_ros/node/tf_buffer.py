"""A TF buffer of the node's own: ``/tf`` (time-stamped) and ``/tf_static`` (no ROS import).

tf2_ros has no PyPI wheel, so the node keeps the tree itself. Each ``TransformStamped`` holds ``T_parent_child``
at its stamp. :class:`TransformBuffer` keeps the static edges (as :class:`~deepbbs_ros.node.tf_static.StaticTransforms`)
and, per dynamic parent -> child edge, the last ``history_s`` seconds of stamped transforms. :meth:`lookup` answers
``T_target_source`` at a stamp through any chain of edges: each dynamic edge interpolated between the two stamps
around it (translation linear, rotation slerp), as tf2 does; a stamp outside an edge's history (beyond
``extrapolation_s``) or frames that are not connected give None. ``stamp_ns=None`` (tf2's time 0): the latest of
each edge.
"""

from __future__ import annotations

import bisect
from typing import Any

import numpy as np

from deepbbs_ros.node.tf_static import StaticTransforms, valid_transforms
from msg_adapters.transforms import matrix_to_quaternion, quaternion_to_matrix


def slerp(q0: np.ndarray, q1: np.ndarray, s: float) -> np.ndarray:
    """Spherical interpolation of unit quaternions (x, y, z, w) at ``s`` in [0, 1] (the shorter way round)."""
    dot = float(np.dot(q0, q1))
    if dot < 0.0:
        q1, dot = -q1, -dot
    if dot > 0.9995:  # nearly equal: linear, renormalised
        q = q0 + s * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = np.arccos(dot)
    return (np.sin((1 - s) * theta) * q0 + np.sin(s * theta) * q1) / np.sin(theta)


def interpolate(T0: np.ndarray, T1: np.ndarray, s: float) -> np.ndarray:
    """The transform a share ``s`` of the way from ``T0`` to ``T1`` (4, 4): translation linear, rotation slerp."""
    out = np.eye(4)
    out[:3, :3] = quaternion_to_matrix(slerp(matrix_to_quaternion(T0[:3, :3]), matrix_to_quaternion(T1[:3, :3]), s))
    out[:3, 3] = (1 - s) * T0[:3, 3] + s * T1[:3, 3]
    return out


class _Edge:
    """One dynamic parent -> child edge: stamps (ns, sorted) and ``T_parent_child`` at each."""

    def __init__(self, parent: str) -> None:
        self.parent = parent
        self.stamps: list[int] = []  # sorted
        self.T: list[np.ndarray] = []

    def add(self, stamp_ns: int, T: np.ndarray, history_ns: int) -> None:
        if self.stamps and stamp_ns <= self.stamps[-1]:
            if stamp_ns == self.stamps[-1]:
                self.T[-1] = T  # the same stamp again (a re-broadcast): the newer value
                return
            i = bisect.bisect_left(self.stamps, stamp_ns)  # out of order: kept in order
            if i < len(self.stamps) and self.stamps[i] == stamp_ns:
                self.T[i] = T
                return
            self.stamps.insert(i, stamp_ns)
            self.T.insert(i, T)
        else:
            self.stamps.append(stamp_ns)
            self.T.append(T)
        old = bisect.bisect_left(self.stamps, self.stamps[-1] - history_ns)
        if old:
            del self.stamps[:old], self.T[:old]

    def at(self, stamp_ns: int | None, extrapolation_ns: int) -> np.ndarray | None:
        if not self.stamps:
            return None
        if stamp_ns is None:
            return self.T[-1]
        first, last = self.stamps[0], self.stamps[-1]
        if stamp_ns >= last:
            return self.T[-1] if stamp_ns - last <= extrapolation_ns else None
        if stamp_ns <= first:
            return self.T[0] if first - stamp_ns <= extrapolation_ns else None
        i = bisect.bisect_right(self.stamps, stamp_ns)  # stamps[i-1] <= stamp < stamps[i]
        s0, s1 = self.stamps[i - 1], self.stamps[i]
        return interpolate(self.T[i - 1], self.T[i], (stamp_ns - s0) / (s1 - s0))


class TransformBuffer(StaticTransforms):
    """Static and time-stamped transforms (module docstring); thread-safe.

    Args:
        history_s: seconds of each dynamic edge kept (behind its newest stamp).
        extrapolation_s: how far before the first / after the last stamp of an edge a lookup still answers
            (with that end's transform); 0: only between stamps (and at them).
    """

    def __init__(self, history_s: float = 10.0, extrapolation_s: float = 0.0) -> None:
        super().__init__()
        self.history_ns = int(history_s * 1e9)
        self.extrapolation_ns = int(extrapolation_s * 1e9)
        self._edges: dict[str, _Edge] = {}  # child -> its dynamic edge

    def add_stamped(self, parent: str, child: str, stamp_ns: int, T_parent_child: np.ndarray) -> None:
        """One dynamic transform ``T_parent_child`` (4, 4) at ``stamp_ns``. A child re-parented drops its history."""
        with self._cond:
            edge = self._edges.get(child)
            if edge is None or edge.parent != parent:
                edge = self._edges[child] = _Edge(parent)
            edge.add(int(stamp_ns), np.asarray(T_parent_child, dtype=np.float64), self.history_ns)
            self._cond.notify_all()

    def add_dynamic_message(self, msg: Any, rejected: list[str] | None = None) -> int:
        """Add every transform of a ``/tf`` TFMessage; returns how many (invalid ones are skipped, and said in
        ``rejected``: :func:`~deepbbs_ros.node.tf_static.valid_transforms`)."""
        n = 0
        for T, stamp_ns, parent, child in valid_transforms(msg, rejected):
            self.add_stamped(parent, child, stamp_ns, T)
            n += 1
        return n

    def has_edge(self, parent: str, child: str) -> bool:
        """Whether a dynamic ``parent -> child`` transform was received (and is still in the history)."""
        return self.newest(parent, child) is not None

    def newest(self, parent: str, child: str) -> int | None:
        """The newest stamp (ns) of the dynamic ``parent -> child`` transform, None when there is none."""
        with self._cond:
            edge = self._edges.get(child)
            return edge.stamps[-1] if edge is not None and edge.parent == parent and edge.stamps else None

    def _up(self, frame: str, stamp_ns: int | None) -> list[tuple[str, np.ndarray | None]]:
        """[(ancestor, T_ancestor_frame)] from ``frame`` itself up to its root; None from an edge without data at
        the stamp on."""
        out: list[tuple[str, np.ndarray | None]] = [(frame, np.eye(4))]
        T: np.ndarray | None = np.eye(4)
        cur, seen = frame, {frame}
        while True:
            edge = self._edges.get(cur)
            if edge is not None:
                parent, T_pc = edge.parent, edge.at(stamp_ns, self.extrapolation_ns)
            elif cur in self._parent:
                parent, T_pc = self._parent[cur]
            else:
                return out
            if parent in seen:
                return out
            seen.add(parent)
            T = None if T is None or T_pc is None else T_pc @ T
            out.append((parent, T))
            cur = parent

    def lookup(self, target: str, source: str, stamp_ns: int | None = None) -> np.ndarray | None:
        """``T_target_source`` (4, 4) at ``stamp_ns`` (None: the latest of each edge), or None when the frames are not
        connected or an edge on the way has no transform at that stamp."""
        if target == source:
            return np.eye(4)
        with self._cond:
            up_t = dict(self._up(target, stamp_ns))
            for anc, T_anc_source in self._up(source, stamp_ns):
                if anc in up_t:
                    T_anc_target = up_t[anc]
                    if T_anc_source is None or T_anc_target is None:
                        return None
                    return np.linalg.inv(T_anc_target) @ T_anc_source
        return None

