"""The road scenes' styles: road and traffic parameters per scene type, and the road's vertical offsets (no ROS)."""

from __future__ import annotations

from dataclasses import dataclass

SCENES = ("urban", "suburban", "highway", "open_road")

ROAD_DZ = 0.03  # m, road surface above the terrain
CURB_DZ = 0.18  # m, sidewalk above the terrain

ALB_ROAD, ALB_MARK, ALB_WALK, ALB_VERGE, ALB_CURB = 0.10, 0.75, 0.35, 0.25, 0.40


@dataclass(frozen=True)
class Style:
    """Road and traffic parameters of one scene type (metres, m/s, degrees)."""

    half_width: float  # carriageway half width
    sidewalk: float  # sidewalk width behind a curb; 0 = no curb (verge)
    ego_offset: float  # ego lane centre, lateral (left positive)
    markings: tuple[tuple[float, bool], ...]  # (lateral offset, dashed)
    straight: tuple[float, float]  # straight segment length range
    turn90_prob: float  # probability that a segment end is a 90-degree turn
    turn_radius: tuple[float, float]
    curve_prob: float  # probability of a gentle curve instead
    curve_radius: tuple[float, float]
    curve_angle: tuple[float, float]
    v_cruise: tuple[float, float]
    a_lat: float  # m/s^2 allowed in curves
    stop_prob: float  # probability of a stop at an intersection / segment end
    stop_dwell: tuple[float, float]  # s
    start_stopped_prob: float
    terrain_amp: float  # m
    movers: tuple[tuple[float, int], ...]  # (lateral offset, +1 same direction / -1 oncoming)
    mover_gap: float  # mean gap between moving cars in a lane (m)
    mover_speed: tuple[float, float]
    hills: float = 0.0  # m, amplitude of the short roadside hills
    bank: float = 0.0  # slope of roadside embankments / cuttings
    ditch: float = 0.0  # m, depth of the roadside ditches
    junction_gap: tuple[float, float] = (150.0, 400.0)  # m between side roads (junctions)
    junction_angle: tuple[float, float] = (40.0, 140.0)  # degrees from the road's heading


STYLES: dict[str, Style] = {
    "urban": Style(
        7.5,
        4.0,
        -1.8,
        ((0.0, False), (3.6, True), (-3.6, True)),
        (70, 220),
        0.5,
        (14, 20),
        0.25,
        (100, 300),
        (10, 35),
        (8.0, 13.0),
        2.0,
        0.45,
        (2.0, 7.0),
        0.5,
        0.8,
        ((1.8, -1),),
        45.0,
        (6.0, 13.0),
        hills=0.3,
        bank=0.05,
        junction_gap=(120.0, 300.0),
        junction_angle=(55.0, 125.0),
    ),
    "suburban": Style(
        5.5,
        2.0,
        -1.75,
        ((0.0, False),),
        (60, 200),
        0.3,
        (12, 18),
        0.45,
        (100, 500),
        (15, 50),
        (8.0, 12.0),
        2.2,
        0.3,
        (1.0, 3.0),
        0.3,
        1.5,
        ((1.75, -1),),
        90.0,
        (7.0, 12.0),
        hills=1.0,
        bank=0.1,
        ditch=0.3,
        junction_gap=(70.0, 200.0),
    ),
    "highway": Style(
        12.5,
        0.0,
        -6.3,
        (
            (0.9, False),
            (-0.9, False),
            (4.5, True),
            (-4.5, True),
            (8.1, True),
            (-8.1, True),
            (11.7, False),
            (-11.7, False),
        ),
        (150, 500),
        0.0,
        (0, 0),
        0.85,
        (700, 2000),
        (5, 25),
        (17.0, 20.0),
        2.0,
        0.0,
        (0, 0),
        0.0,
        2.0,
        ((2.7, -1), (6.3, -1), (9.9, -1), (-2.7, 1), (-9.9, 1)),
        80.0,
        (16.0, 30.0),
        hills=2.5,
        bank=0.3,
        ditch=0.6,
        junction_gap=(400.0, 900.0),
        junction_angle=(6.0, 12.0),
    ),
    "open_road": Style(
        4.0,
        0.0,
        -1.8,
        ((0.0, True), (3.6, False), (-3.6, False)),
        (60, 250),
        0.0,
        (0, 0),
        0.85,
        (100, 1000),
        (10, 60),
        (13.0, 20.0),
        2.0,
        0.03,
        (1.0, 3.0),
        0.1,
        3.0,
        ((1.8, -1),),
        180.0,
        (12.0, 22.0),
        hills=4.0,
        bank=0.35,
        ditch=0.7,
        junction_gap=(150.0, 450.0),
        junction_angle=(30.0, 150.0),
    ),
}
