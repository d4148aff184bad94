"""The non-repetitive (Livox) scanners (no ROS): :class:`SolidStateConfig`, its scan pattern (a Risley-prism rosette
or a spinning head whose lines sweep an elevation band), and the Livox Avia and Mid-360 presets (:func:`avia`,
:func:`mid360`; their datasheet figures in sim/patterns.py's module docstring)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from deepbbs_ros.errors import SimulationError


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
