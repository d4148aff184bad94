"""Preprocessing defaults per LiDAR, and which LiDAR a scan comes from (no ROS import).

``preprocess.sensor`` names a row of :data:`~deepbbs_ros.config.preprocess.SENSORS` (the section's defaults per
LiDAR, beside the section); ``"auto"`` picks one from the driver that published the
scan (``driver``: ``msg_adapters.layouts.recognise_driver`` reads it from the PointCloud2 fields, and the caller
passes it in) or, without one, from the cloud's shape (:func:`guess_sensor`). :func:`resolve` applies the row to a
:class:`PreprocessConfig`: a setting the user changed from its default always wins over the sensor's.

Only what genuinely differs between sensors is in the table. The spinning sensors keep the defaults the model was
trained and measured with (car-roof HDL-64E and the simulated spinning drives): their rows are empty on purpose, so
that a recognised Velodyne, Ouster or Hesai cloud is preprocessed exactly as before. Per-point times need no row:
a cloud's times are used when the driver writes them, and a sweep model is fitted only when the times follow the
azimuth (``core.preprocess.SweepTimes``: spinning sensors, not Livox rosettes).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from deepbbs_ros.config import PreprocessConfig
from deepbbs_ros.config.preprocess import SENSORS

#: ``msg_adapters.layouts.recognise_driver`` names -> the sensor whose defaults apply (a Velodyne's model is unknown
#: from its fields, and every spinning row is the defaults: None; a Livox is told by its shape)
DRIVER_SENSORS: dict[str, str | None] = {"velodyne": None, "ouster": "ouster", "hesai": "hesai",
                                         "robosense": "robosense", "livox": None}

_NARROW = 0.5  # a cloud filling less than this fraction of the azimuth circle is a narrow solid-state sensor
_AZ_BINS = 36  # 10-degree azimuth bins
#: the shape guess reads an even subsample of about this many points (1,024 gave the same guess on every real set and
#: simulated sensor, but not on a simulated Mid-360 corridor scan moved 2 m off its sensor: 0.50 against 0.47)
_MAX_SHAPE_POINTS = 4096


def azimuth_coverage(points: np.ndarray, max_points: int = _MAX_SHAPE_POINTS) -> float:
    """Fraction of the 36 ten-degree azimuth bins (sensor frame, around +z) holding at least 0.2 % of the
    finite points of ``points`` (N, 3) (an even subsample of about ``max_points``): about 1 for a spinning sensor,
    about 0.2 for a Livox Avia."""
    pts = np.asarray(points)[:: max(1, len(points) // max_points)]
    if pts.ndim == 2 and pts.shape[1] == 3:  # column by column: a quarter of the time of a row-wise all()
        finite = np.isfinite(pts[:, 0]) & np.isfinite(pts[:, 1]) & np.isfinite(pts[:, 2])
    else:
        finite = np.isfinite(pts).all(axis=1)
    if not finite.all():  # a copy only when some rows are missing returns
        pts = pts[finite]
    if len(pts) == 0:
        return 0.0
    az = np.arctan2(pts[:, 1], pts[:, 0])
    hist = np.bincount(((az + np.pi) / (2 * np.pi) * _AZ_BINS).astype(np.int64), minlength=_AZ_BINS + 1)
    hist[0] += hist[_AZ_BINS:].sum()  # +pi is -pi's bin (a modulo costs more than the rest)
    hist = hist[:_AZ_BINS]
    return float(np.count_nonzero(hist >= 0.002 * len(pts))) / _AZ_BINS


def guess_sensor(points: np.ndarray, driver: str | None = None) -> str | None:
    """The sensor of a scan (N, 3) from its ``driver`` (a :data:`DRIVER_SENSORS` name) or its shape; None when
    nothing says it is anything but a spinning sensor (the defaults apply). A Livox cloud, or any cloud that fills
    less than half the azimuth circle, is a ``"livox_avia"`` (narrow field of view) or, filling more, a
    ``"livox_mid360"``."""
    if driver == "livox":
        return "livox_avia" if azimuth_coverage(points) < _NARROW else "livox_mid360"
    if driver in DRIVER_SENSORS:  # a spinning sensor's driver: its row, whatever the cloud's shape (a crop)
        return DRIVER_SENSORS[driver]
    return "livox_avia" if azimuth_coverage(points) < _NARROW else None


def resolve(cfg: PreprocessConfig, sensor: str | None = None) -> PreprocessConfig:
    """``cfg`` with the defaults of ``sensor`` (default ``cfg.sensor``; ``"auto"`` or None: ``cfg`` as is) in every
    field that still holds its generic default; the fields the user changed keep their values. The result's
    ``sensor`` names the sensor applied."""
    name = cfg.sensor if sensor is None else sensor
    if name in (None, "auto") or name not in SENSORS:
        return cfg
    generic = PreprocessConfig()
    changes = {k: v for k, (v, _) in SENSORS[name].items() if getattr(cfg, k) == getattr(generic, k)}
    if not changes and cfg.sensor == name:
        return cfg
    return replace(cfg, sensor=name, **changes)

