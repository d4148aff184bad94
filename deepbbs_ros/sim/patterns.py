"""Scan patterns of the LiDARs robots carry: Ouster, Hesai, RoboSense presets and Livox rosettes (no ROS).

Spinning sensors are :class:`~deepbbs_ros.sim.lidar.LidarConfig` presets (ray cast by
:func:`~deepbbs_ros.sim.lidar.lidar_sweep`); Livox sensors scan a non-repetitive pattern and are
:class:`SolidStateConfig` (ray cast by :func:`~deepbbs_ros.sim.solid_state.pattern_sweep`).

Figures are the vendors' published datasheet values (rounded; ranges at about 10 % reflectivity where a
datasheet gives two):

* Ouster OS0 / OS1 (Ouster OS0 / OS1 datasheets and hardware user manuals, rev7; static.ouster.dev
  sensor docs): 32, 64 or 128 beams, uniform spacing over a 90 deg (OS0, +-45) or 45 deg (OS1, +-22.5)
  vertical field of view, 1024 columns at 10 Hz, range 0.5-50 m (OS0) / 0.5-120 m (OS1) (10 % targets at
  50 % detection probability), repeatability +-1.5-5 cm (the first OS1 datasheet: +-1.5 cm at high SNR,
  +-3 cm at SNR 100); organised output, per-point ``t`` (uint32 ns since the scan's stamp), as ouster-ros
  publishes it.
* Hesai XT32 (Hesai PandarXT-32 / XT32M2X user manuals, www.hesaitech.com/downloads): 32 channels 1 deg
  apart over -16..+15 deg, 0.18 deg azimuth at 10 Hz, 0.05-120 m, precision 0.5-1 cm; per-point
  ``timestamp`` (float64, absolute seconds) as HesaiLidar_ROS_2.0 publishes it.
* RoboSense RS-Helios-32 (RS-Helios 5515 datasheet): 32 beams over -55..+15 deg, dense around the
  horizon and sparse below (the table here is Helios-like, not the vendor's calibration), 0.2 deg azimuth
  at 10 Hz, 0.2-150 m, +-2 cm; per-point ``timestamp`` (float64, absolute seconds) as rslidar_sdk does.
* Livox Avia (Livox Avia user manual v1.0, 2020.10, www.livoxtech.com/avia): 70.4 x 77.2 deg (horizontal x
  vertical) forward field of view, non-repetitive scanning, 6 laser lines, 240,000 points/s, 10 Hz frames,
  blind zone 1 m, 190 m at 10 % reflectivity, range random error 2 cm (1 sigma at 20 m).
* Livox Mid-360 (Livox Mid-360 user manual / livox wiki): 360 x 59 deg (-7..+52 deg elevation),
  non-repetitive, 4 laser lines, 200,000 points/s, blind zone 0.1 m, 40 m at 10 % reflectivity, 2 cm;
  coverage of the field of view grows with integration time.

Livox clouds carry ``line`` (uint8), ``tag`` (uint8, 0) and ``timestamp`` (float64, absolute ns), the
livox_ros_driver2 PointCloud2 layout. The Livox scanners' model and presets: sim/rosettes.py (imported from here too).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from deepbbs_ros.errors import SimulationError
from deepbbs_ros.sim.lidar import LidarConfig
from deepbbs_ros.sim.rosettes import SolidStateConfig, avia, mid360


def _ouster(name: str, beams: int, half_fov: float, max_range: float, noise: float, **kw) -> LidarConfig:
    cfg = LidarConfig(name=name, beams=beams, vfov_min_deg=-half_fov, vfov_max_deg=half_fov,
                      azimuth_step_deg=360.0 / 1024, max_range=max_range, min_range=0.5, range_noise=noise,
                      organized=True)
    return replace(cfg, **kw)


def helios32_elevations() -> tuple[float, ...]:
    """RS-Helios-32-like beam table (deg, ascending): 8 beams over +15..+5, 16 over +4..-12, 8 down to -55."""
    upper = np.linspace(15.0, 5.0, 8)
    middle = np.linspace(4.0, -12.0, 16)
    lower = np.linspace(-14.5, -55.0, 8)
    return tuple(float(e) for e in np.sort(np.concatenate([upper, middle, lower])))


def xt32(**kw) -> LidarConfig:
    """Hesai XT32: 32 beams 1 deg apart, -16..+15 deg, 0.18 deg azimuth, 0.05-120 m, 1 cm noise."""
    cfg = LidarConfig(name="xt32", beams=32, vfov_min_deg=-16.0, vfov_max_deg=15.0, azimuth_step_deg=0.18,
                      max_range=120.0, min_range=0.05, range_noise=0.01)
    return replace(cfg, **kw)


def helios32(**kw) -> LidarConfig:
    """RoboSense RS-Helios-32-like: 32 non-uniform beams over -55..+15 deg, 0.2 deg azimuth, 0.2-150 m."""
    cfg = LidarConfig(name="helios32", beams=32, elevations_deg=helios32_elevations(), azimuth_step_deg=0.2,
                      max_range=150.0, min_range=0.2, range_noise=0.02)
    return replace(cfg, **kw)


#: spinning presets beside LidarConfig's own four (hdl64, hdl32, vlp16, ouster64)
SPINNING = {
    "os0_32": lambda **kw: _ouster("os0_32", 32, 45.0, 50.0, 0.025, **kw),
    "os0_64": lambda **kw: _ouster("os0_64", 64, 45.0, 50.0, 0.025, **kw),
    "os0_128": lambda **kw: _ouster("os0_128", 128, 45.0, 50.0, 0.025, **kw),
    "os1_32": lambda **kw: _ouster("os1_32", 32, 22.5, 120.0, 0.015, **kw),
    "os1_64": lambda **kw: _ouster("os1_64", 64, 22.5, 120.0, 0.015, **kw),
    "os1_128": lambda **kw: _ouster("os1_128", 128, 22.5, 120.0, 0.015, **kw),
    "xt32": xt32,
    "helios32": helios32,
}


SOLID_STATE = {"avia": avia, "mid360": mid360}
#: every sensor name the simulator knows, in --help order
SENSORS = ("hdl64", "hdl32", "vlp16", "ouster64", *SPINNING, *SOLID_STATE)


def make_sensor(name: str, **kw) -> LidarConfig | SolidStateConfig:
    """The preset ``name`` (one of :data:`SENSORS`), with field overrides ``kw``."""
    if name in SPINNING:
        return SPINNING[name](**kw)
    if name in SOLID_STATE:
        return SOLID_STATE[name](**kw)
    if name in SENSORS:
        return LidarConfig.preset(name, **kw)
    raise SimulationError(f"unknown sensor {name!r}; choose one of {', '.join(SENSORS)}")


def driver_of(name: str) -> str:
    """The driver whose PointCloud2 fields a sensor's scans imitate: velodyne, ouster, hesai, robosense, livox."""
    if name in SOLID_STATE:
        return "livox"
    if name.startswith("os"):  # the older ouster64 preset keeps its float32 ``time``, as it always had
        return "ouster"
    return {"xt32": "hesai", "helios32": "robosense"}.get(name, "velodyne")


def driver_fields(name: str, fields: dict[str, np.ndarray], stamp_ns: int) -> dict[str, np.ndarray]:
    """Turn the simulator's ``time`` (float32 s since the stamp) into the driver's own time field.

    Ouster ``t`` uint32 ns since the stamp; Hesai / RoboSense ``timestamp`` float64 absolute s; Livox
    ``timestamp`` float64 absolute ns (and ``tag`` uint8). Velodyne keeps ``time``.
    """
    driver = driver_of(name)
    if driver == "velodyne" or "time" not in fields:
        return fields
    out = dict(fields)
    t = np.asarray(out.pop("time"), dtype=np.float64)
    if driver == "ouster":
        out["t"] = np.round(t * 1e9).astype(np.uint32)
    elif driver == "livox":
        out["tag"] = np.zeros(len(t), np.uint8)
        out["timestamp"] = float(stamp_ns) + np.round(t * 1e9)
    else:
        out["timestamp"] = stamp_ns * 1e-9 + t
    return out
