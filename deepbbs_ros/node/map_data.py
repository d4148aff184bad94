"""The prior map of ``node.target_mode: localization`` (no ROS import): :class:`MapData`, from the map topic or from
``localization.map_path`` (:func:`load_map_file`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from deepbbs_ros.errors import DeepBBSError, NodeError

__all__ = ["MapData", "load_map_file"]


@dataclass
class MapData:
    """A prior map for the node.

    Attributes:
        points: (N, 3) float32 metres, map frame.
        frame_id: the map frame (``node.map_frame`` for a file, the message's frame for the topic).
        source: where it came from (a path or a topic), for log lines.
        trajectory: (K, 4, 4) float64 ``T_map_sensor`` of the drive the map was built from, or None.
    """

    points: np.ndarray
    frame_id: str
    source: str
    trajectory: np.ndarray | None = None


def load_map_file(path: str | Path, frame_id: str) -> MapData:
    """Read the map file ``path`` (``.pcd`` / ``.ply``, map frame; the trajectory beside it, ``.tum``, when present).

    Raises:
        NodeError: one line naming ``localization.map_path`` and what is wrong (missing, another format,
            unreadable or damaged, no finite point).
    """
    from deepbbs_ros.datasets.maps import read_map

    try:
        prior = read_map(Path(path).expanduser())
    except DeepBBSError as err:
        raise NodeError(f"localization.map_path: {err}") from err
    except OSError as err:  # a directory, no permission: the system's reason
        raise NodeError(f"localization.map_path: cannot read {path}: {err.strerror or err}") from err
    return MapData(np.ascontiguousarray(prior.points, dtype=np.float32), frame_id, str(path), prior.trajectory)
