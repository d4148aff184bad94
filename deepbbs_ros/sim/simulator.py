"""Drive simulation: a spinning LiDAR on an ego vehicle driving through a procedural world (no ROS).

Frames and timing
-----------------
Frame ``k`` is the sweep that starts at ``t_k = k / rate_hz`` seconds after the start of the drive;
its stamp is ``STAMP0_NS + round(t_k * 1e9)``. ``Scan.T_world_lidar`` is the ground-truth pose of
the LiDAR at the stamp, i.e. at the **start** of the sweep. Column ``c`` of the sweep fires at
``t_k + c / (columns * rate_hz)``; that offset is the per-point ``time`` field, in [0, 1 / rate_hz).

Motion distortion: with ``motion_distortion=True`` every column is cast from the pose the sensor
has at its firing time and the point is reported in that (moving) sensor frame, exactly what an
uncompensated spinning LiDAR delivers (a *raw sweep*, with its per-point ``time``). With
``compensate=True`` the same sweep is then expressed in the sensor frame at the stamp using the true
pose of every column, as Apollo's compensator does (the ``time`` field is dropped: the scan is
already de-skewed). With ``motion_distortion=False`` the whole sweep is cast from the pose at the
stamp (an ideal, instantaneous or perfectly de-skewed scan): then ``T_world_lidar @ p`` lies on the
scene surface for every noiseless point ``p``.

Intensity: ``255 * albedo * (0.25 + 0.75 |cos(incidence)|)`` times a per-ring gain and a little
noise, clipped to [0, 255] (Velodyne-like calibrated reflectivity).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Iterator

import numpy as np

from deepbbs_ros.datasets.base import Scan
from deepbbs_ros.errors import SimulationError
from deepbbs_ros.sim.drive_sweeps import ANCHOR_STEP, DriveSweeps
from deepbbs_ros.sim.frames import STAMP0_NS, Frames  # noqa: F401  (STAMP0_NS re-exported)
from deepbbs_ros.sim.lidar import LidarConfig, RayCaster
from deepbbs_ros.sim.scene import SCENES, World
from deepbbs_ros.sim.trajectory import Trajectory, euler_to_matrix

S_START = 80.0  # m of road behind the start position


class DriveSimulator(DriveSweeps, Frames):
    """A reproducible simulated drive with random access to its frames.

    scene: one of :data:`SCENES`; seed: any int (same seed -> bit-identical frames);
    lidar: sensor model (default :meth:`LidarConfig.hdl64`); frames: number of frames the world is
    built for; motion_distortion, compensate: see the module docstring; rate_hz: spin rate = frame rate.

    A second drive through the same world (e.g. to localize in a map built from a first one): the world
    depends on ``(scene, seed)`` and its length, so give ``world_frames`` = the first drive's ``frames``.
    Then ``lane_offset`` (metres left of the route's centreline; None = the scene's ego lane),
    ``reverse`` (drive back the other way, by default in the mirrored lane, from ``s_start``, which then
    defaults to where the first drive ended), ``s_start`` (arc length of the start, m) and ``day`` (other
    parked cars and traffic: :class:`~deepbbs_ros.sim.scene.World`). With all of them left at their
    defaults the drive is exactly the one it always was.

    Building is cheap (a fraction of a second per km of road); ``scan_at(k)`` (sim/drive_sweeps.py) costs one
    sweep of ray casting. ``pose_at(k)`` gives the ground truth without casting (e.g. to pick training pairs).
    """

    def __init__(
        self,
        scene: str,
        seed: int,
        lidar: LidarConfig | None = None,
        *,
        frames: int = 100,
        motion_distortion: bool = True,
        rate_hz: float = 10.0,
        compensate: bool = False,
        world_frames: int | None = None,
        lane_offset: float | None = None,
        reverse: bool = False,
        s_start: float | None = None,
        day: int | None = None,
    ) -> None:
        if scene not in SCENES:
            raise SimulationError(f"unknown scene {scene!r}; choose one of {', '.join(SCENES)}")
        if int(frames) < 1:
            raise SimulationError(f"frames must be >= 1, got {frames}")
        if not 0.5 <= float(rate_hz) <= 50.0:
            raise SimulationError(f"rate_hz must be in [0.5, 50], got {rate_hz}")
        self.lidar = lidar if lidar is not None else LidarConfig.hdl64()
        self.lidar.validate()
        self.scene, self.seed, self.frames = scene, int(seed), int(frames)
        self.motion_distortion = bool(motion_distortion)
        self.compensate = bool(compensate)
        self.rate_hz = float(rate_hz)
        self._variant = {"world_frames": world_frames, "lane_offset": lane_offset, "reverse": reverse,
                         "s_start": s_start, "day": day}  # for iter_frames' worker processes
        self.period = 1.0 / self.rate_hz
        if world_frames is not None and int(world_frames) < 1:
            raise SimulationError(f"world_frames must be >= 1, got {world_frames}")
        duration = self.frames * self.period
        world_duration = (self.frames if world_frames is None else int(world_frames)) * self.period
        length = S_START + 20.0 * (world_duration + 2.0) + self.lidar.max_range + ANCHOR_STEP + 150.0
        self.world = World(scene, self.seed, length, day=day)
        if reverse and s_start is None:  # where the forward drive of the same world is at its last frame
            fwd = Trajectory(self.world, self.seed, world_duration + self.period, S_START)
            s_start = float(np.interp(world_duration - self.period, fwd.t_grid, fwd.s_grid))
        self.trajectory = Trajectory(self.world, self.seed, duration + self.period,
                                     s_start=S_START if s_start is None else float(s_start),
                                     lane_offset=lane_offset, reverse=reverse)
        self.T_base_lidar = np.eye(4)
        self.T_base_lidar[:3, :3] = euler_to_matrix(0.0, np.deg2rad(self.lidar.mount_pitch_deg), 0.0)
        self.T_base_lidar[2, 3] = self.lidar.mount_height
        self._dirs = self.lidar.directions()  # (C, B, 3) sensor frame
        self._col_time = np.arange(self.lidar.columns) * (self.period / self.lidar.columns)
        ring_rng = np.random.default_rng([self.seed, 707])
        self._ring_gain = ring_rng.uniform(0.85, 1.15, self.lidar.beams)  # per-laser calibration spread
        self._casters: OrderedDict[int, tuple[RayCaster, np.ndarray]] = OrderedDict()
        self.timings_s = {"build": 0.0, "cast": 0.0, "post": 0.0}

    # ---- poses ----------------------------------------------------------------------------------
    def T_world_lidar(self, t: np.ndarray | float) -> np.ndarray:
        """(..., 4, 4) float64 pose of the LiDAR at drive time ``t`` (s)."""
        return self.trajectory.poses(t) @ self.T_base_lidar


def simulate_drive(
    scene: str,
    seed: int,
    frames: int,
    *,
    lidar: LidarConfig | None = None,
    motion_distortion: bool = True,
    rate_hz: float = 10.0,
    compensate: bool = False,
) -> Iterator[Scan]:
    """Yield ``frames`` simulated :class:`Scan` s of one drive (see :class:`DriveSimulator`).

    Scan.points: (N, 3) float32 in the LiDAR frame; fields ``intensity`` float32 [0, 255],
    ``time`` float32 (s since the stamp, in [0, 1/rate_hz)), ``ring`` uint16 (0 = lowest beam),
    plus ``column`` uint16 for organised sensors; ``T_world_lidar`` = ground truth at the stamp.
    """
    sim = DriveSimulator(scene, seed, lidar, frames=frames, motion_distortion=motion_distortion, rate_hz=rate_hz,
                         compensate=compensate)
    return iter(sim)  # a plain function, so bad arguments raise here and not at the first next()


_WORKER_SIM: DriveSimulator | None = None


def _worker_init(kwargs: dict) -> None:
    global _WORKER_SIM
    _WORKER_SIM = DriveSimulator(**kwargs)


def _worker_scan(frame: int) -> Scan:
    assert _WORKER_SIM is not None
    return _WORKER_SIM.scan_at(frame)


def iter_frames(sim: DriveSimulator, workers: int = 1) -> Iterator[Scan]:
    """Yield all frames of ``sim`` in order, simulated in ``workers`` processes (1 = in this one).

    Every worker rebuilds the same world from the same seed, and frames do not depend on the order
    in which they are simulated, so the output is bit-identical for any number of workers.
    """
    if workers <= 1:
        yield from sim
        return
    import concurrent.futures as cf
    import multiprocessing as mp

    kwargs = {
        "scene": sim.scene, "seed": sim.seed, "lidar": sim.lidar, "frames": sim.frames,
        "motion_distortion": sim.motion_distortion, "rate_hz": sim.rate_hz, "compensate": sim.compensate,
        **sim._variant,
    }  # fmt: skip
    ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
    with cf.ProcessPoolExecutor(workers, mp_context=ctx, initializer=_worker_init, initargs=(kwargs,)) as pool:
        pending: list[cf.Future] = []
        nxt = 0
        for _ in range(sim.frames):
            while nxt < sim.frames and len(pending) < 2 * workers:  # bounded read-ahead
                pending.append(pool.submit(_worker_scan, nxt))
                nxt += 1
            yield pending.pop(0).result()
