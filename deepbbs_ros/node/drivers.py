"""Which LiDAR driver publishes an input topic, and the preprocessing defaults that follow from it (no ROS import).

Each input recognises its driver once, from the first good message's PointCloud2 field names
(``msg_adapters.layouts.recognise_driver``: Livox, Ouster, Velodyne, Hesai / RoboSense, or none), and passes it to
every preprocessing of that topic's scans, which settles ``preprocess.sensor: auto`` with it
(``core.sensors.guess_sensor``). :func:`describe` says what was chosen: one log line and the ``input.<topic>.driver``
value of /diagnostics.
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any

import numpy as np

from deepbbs_ros.config import PreprocessConfig


def recognise(msg: Any) -> str | None:
    """The driver family that wrote the PointCloud2 ``msg`` (rclpy or rosbags), from its fields, or None."""
    from msg_adapters.layouts import recognise_driver

    return recognise_driver(msg.fields)


def sensor_defaults(cfg: PreprocessConfig, driver: str | None, xyz: np.ndarray) -> tuple[str | None, dict[str, Any]]:
    """(the sensor whose defaults apply to the scan ``xyz`` (N, 3) of ``driver``, None for the generic defaults;
    {setting: value} it changes in ``cfg``). A ``preprocess.sensor`` other than "auto" is used as it is."""
    from deepbbs_ros.core.sensors import guess_sensor, resolve

    sensor = guess_sensor(xyz, driver) if cfg.sensor == "auto" else cfg.sensor
    if sensor is None:
        return None, {}
    out = resolve(cfg, sensor)
    return sensor, {f.name: getattr(out, f.name) for f in fields(cfg)
                    if f.name != "sensor" and getattr(out, f.name) != getattr(cfg, f.name)}


def describe(topic: str, cfg: PreprocessConfig, driver: str | None, xyz: np.ndarray,
             used: bool = True) -> tuple[str, str]:
    """(the ``input.<topic>.driver`` diagnostics value, the log line) for ``topic``'s first scan ``xyz``; ``used``:
    the preprocessing takes the driver (else it settles the sensor from the cloud's shape alone: localization)."""
    sensor, changes = sensor_defaults(cfg, driver if used else None, xyz)
    if sensor is None:
        defaults = "the generic defaults"
    else:
        settings = ", ".join(f"preprocess.{k} {v}" for k, v in changes.items()) or "the generic ones"
        defaults = f"the {sensor} defaults ({settings})"
    if cfg.sensor != "auto":
        defaults += f" (preprocess.sensor is {cfg.sensor!r})"
    elif not used or driver is None:
        defaults += " (from the cloud's shape)"
    found = f"{driver} driver recognised from the fields" if driver else "no known LiDAR driver in the fields"
    return f"{driver or 'none'}: {defaults}", f"{topic}: {found}; preprocessing with {defaults}"
