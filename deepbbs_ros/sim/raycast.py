"""Closest-hit ray casting against a triangle mesh with Embree (no ROS): what the simulated LiDARs cast their rays
with (sim/lidar.py)."""

from __future__ import annotations

import numpy as np

from deepbbs_ros.errors import SimulationError


class RayCaster:
    """Closest-hit ray casting against a static triangle mesh with Embree (via ``embreex``).

    The mesh is shifted by ``origin`` (a world point near the sensor) before it is handed to Embree,
    which works in float32; rays are shifted the same way, so world coordinates of any size keep
    millimetre precision.

    vertices: (V, 3) float64 world; faces: (F, 3) int; origin: (3,) float64 world.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, origin: np.ndarray | None = None) -> None:
        try:
            from embreex import rtcore_scene
            from embreex.mesh_construction import TriangleMesh
        except ImportError as err:  # pragma: no cover - embreex is an install requirement
            raise SimulationError("the LiDAR simulator needs the 'embreex' package (pip install embreex)") from err
        self.origin = np.zeros(3) if origin is None else np.asarray(origin, dtype=np.float64)
        self.num_faces = int(len(faces))
        self._scene = None
        if self.num_faces:
            self._scene = rtcore_scene.EmbreeScene()
            TriangleMesh(
                scene=self._scene,
                vertices=np.ascontiguousarray(vertices - self.origin, dtype=np.float32),
                indices=np.ascontiguousarray(faces, dtype=np.int32),
            )

    def cast(self, origins: np.ndarray, directions: np.ndarray, max_range: float):
        """Cast rays; returns (dist (N,) float32, face (N,) int32 (-1 = miss), normal (N, 3) float32).

        origins: (N, 3) float64 world; directions: (N, 3) unit vectors. ``dist`` is ``max_range``
        for misses; ``normal`` is the (unnormalised) geometric normal of the hit face.
        """
        n = len(origins)
        if self._scene is None or n == 0:
            return (np.full(n, max_range, np.float32), np.full(n, -1, np.int32), np.zeros((n, 3), np.float32))
        o = np.ascontiguousarray(origins - self.origin, dtype=np.float32)
        d = np.ascontiguousarray(directions, dtype=np.float32)
        out = self._scene.run(o, d, dists=np.full(n, max_range, np.float32), output=1)
        return out["tfar"], out["primID"].astype(np.int32), out["Ng"]
