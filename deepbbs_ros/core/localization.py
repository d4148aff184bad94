"""Localization in a prior map, its public names (no ROS): :class:`MapLocalizer` (core/map_localizer.py: a scan's
pose in the map, with no guess or from one) and :class:`MapTracker` (core/tracking.py: the state machine around it,
the node's and the replay's), with the results' types and the helpers that were always importable from here.

``from deepbbs_ros.core.localization import MapLocalizer, MapTracker``. The tracker imports the localizer, and this
module both, so neither imports the other through it.
"""

from __future__ import annotations

from deepbbs_ros.core.descriptors import (  # noqa: F401  (re-exported: tests reach the descriptor's helpers here)
    GROUND_WINDOW,
    _HeightGrid,
    _match,
    _match_many,
    _match_observed,
    _normalise_columns,
    _PolarTemplate,
    _spectra,
)
from deepbbs_ros.core.drive_places import OBSTACLE_BAND, keyframe_places  # noqa: F401
from deepbbs_ros.core.localization_types import (  # noqa: F401  (re-exported)
    MIN_SCAN_POINTS,
    LocalizationResult,
    PreparedScan,
    _Answer,
    _as_cloud,
    _Crop,
    _crop_cloud,
    _heading,
    _rz,
    _yaw,
)
from deepbbs_ros.core.map_index import _CellIndex, voxel_downsample  # noqa: F401
from deepbbs_ros.core.map_localizer import CLOUD_BYTES, MIN_MAP_POINTS, MapLocalizer  # noqa: F401
from deepbbs_ros.core.place_search import MIN_PROBE_POINTS  # noqa: F401
from deepbbs_ros.core.tracking import (  # noqa: F401
    DESKEW_WINDOW,
    HINT_MIN_RADIUS,
    HINT_MIN_YAW,
    HINT_SIGMAS,
    HINT_YAW_STEP,
    MapTracker,
)

__all__ = ["LocalizationResult", "MapLocalizer", "MapTracker", "PreparedScan", "voxel_downsample"]
