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
livox_ros_driver2 PointCloud2 layout.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from deepbbs_ros.errors import SimulationError
from deepbbs_ros.sim.lidar import LidarConfig


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


@dataclass(frozen=True)
class SolidStateConfig:
    """A non-repetitive (Livox) scanner. Angles in degrees, distances in metres.

    Each of ``lines`` lasers draws its own curve through the field of view; the sensor emits
    ``points_per_s`` points spread evenly over the lines and over time. ``kind`` ``"rosette"``: a
    forward-looking Risley-prism rosette (two counter-rotating prisms, frequencies ``f1_hz`` and
    ``f2_hz`` of irrational ratio, so no frame repeats another), the lines stacked in elevation to
    fill ``hfov_deg`` x (``vfov_max_deg`` - ``vfov_min_deg``). ``"spin"``: a 360 deg head turning at
    ``f1_hz`` whose lines sweep the elevation band at ``f2_hz`` (irrational to ``f1_hz``), so coverage
    fills in over time.
    """

    name: str
    kind: str
    hfov_deg: float
    vfov_min_deg: float
    vfov_max_deg: float
    lines: int
    points_per_s: float
    max_range: float
    min_range: float
    range_noise: float = 0.02
    dropout: float = 0.01
    f1_hz: float = 0.0
    f2_hz: float = 0.0
    mount_height: float = 1.9  # above the floor / road when carried by a car (mounts override it)
    mount_pitch_deg: float = 0.0

    def validate(self) -> None:
        if self.kind not in ("rosette", "spin"):
            raise SimulationError(f"solid-state kind must be 'rosette' or 'spin', got {self.kind!r}")
        if self.lines < 1 or self.points_per_s <= 0:
            raise SimulationError("a solid-state sensor needs lines >= 1 and points_per_s > 0")
        if not 0 <= self.min_range < self.max_range:
            raise SimulationError("a solid-state sensor needs 0 <= min_range < max_range")

    def pattern(self, t0: float, period: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rays of the frame that starts ``t0`` s after power-on and lasts ``period`` s.

        Returns directions (N, 3) float64 unit vectors in the sensor frame, times (N,) float64 s since
        the frame start (ascending, in [0, period)) and line (N,) uint8. The pattern depends on the
        absolute time ``t0``, so consecutive frames cover different directions.
        """
        n = int(round(self.points_per_s * period))
        times = np.arange(n) * (period / n)
        line = (np.arange(n) % self.lines).astype(np.uint8)
        t = t0 + times
        w1, w2 = 2 * np.pi * self.f1_hz, 2 * np.pi * self.f2_hz
        if self.kind == "rosette":
            radius = 0.5 * self.hfov_deg
            phase = 2 * np.pi * line / self.lines
            u = 0.5 * radius * (np.cos(w1 * t + phase) + np.cos(w2 * t))  # azimuth offset, deg
            v = 0.5 * radius * (np.sin(w1 * t + phase) + np.sin(w2 * t))
            span = (self.vfov_max_deg - self.vfov_min_deg) - self.hfov_deg  # line stack height
            mid = 0.5 * (self.vfov_max_deg + self.vfov_min_deg)
            offs = np.linspace(-span / 2, span / 2, self.lines) if self.lines > 1 else np.zeros(1)
            az, el = np.deg2rad(u), np.deg2rad(mid + v + offs[line])
        else:
            az = w1 * t + 2 * np.pi * line / self.lines
            # sine in sin(elevation): an even spread over the band's solid angle
            s_lo, s_hi = np.sin(np.deg2rad(self.vfov_min_deg)), np.sin(np.deg2rad(self.vfov_max_deg))
            s = 0.5 * (s_lo + s_hi) + 0.5 * (s_hi - s_lo) * np.sin(w2 * t + 1.7 * line)
            el = np.arcsin(s)
        ce = np.cos(el)
        d = np.stack([ce * np.cos(az), ce * np.sin(az), np.sin(el)], axis=1)
        return d, times, line


def avia(**kw) -> SolidStateConfig:
    """Livox Avia: 70.4 x 77.2 deg forward rosette, 6 lines, 240k points/s, 1-190 m, 2 cm."""
    return replace(SolidStateConfig("avia", "rosette", 70.4, -38.6, 38.6, 6, 240_000.0, 190.0, 1.0,
                                    f1_hz=176.3, f2_hz=-176.3 / np.sqrt(2.0)), **kw)


def mid360(**kw) -> SolidStateConfig:
    """Livox Mid-360: 360 x 59 deg (-7..+52), 4 lines, 200k points/s, 0.1-40 m, 2 cm."""
    return replace(SolidStateConfig("mid360", "spin", 360.0, -7.0, 52.0, 4, 200_000.0, 40.0, 0.1,
                                    f1_hz=10.0 * np.sqrt(3.0), f2_hz=97.0 * np.sqrt(2.0)), **kw)


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
