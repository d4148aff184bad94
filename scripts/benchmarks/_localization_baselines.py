"""The localization benchmark's baselines (scripts/benchmarks/localization.py): KISS-Matcher and Open3D's FPFH + RANSAC
against the whole map, each finished by GICP; each runs in a child process (_localization_methods.Isolated)."""

from __future__ import annotations

import numpy as np

RANSAC_SEED = 1  # Open3D's random generator, seeded before every RANSAC


def _map_gicp(points: np.ndarray, config):
    """The whole map as small_gicp's GICP target (no range crop), the baseline's voxel and neighbours."""
    from deepbbs_ros.core.polish import prepare_polish_cloud

    ev = config.eval
    return prepare_polish_cloud(points, ev.baseline_voxel_size, ev.baseline_neighbors, registration_type="GICP")


class KissMatcherSolver:
    """KISS-Matcher registering the scan against the whole map (voxel ``voxel`` m: its outdoor default 0.3 m
    takes over 30 s per query against a 300 m map here), then GICP (the project's small_gicp baseline) against
    the whole map; accepted when KISS-Matcher calls its solution valid. KISS-Matcher computes the map's
    features inside every call (its API takes two clouds), which is part of its time."""

    def __init__(self, points: np.ndarray, config=None, voxel: float = 1.0) -> None:
        from deepbbs_ros.baselines import KissMatcherRegistration, SmallGicpRegistration
        from deepbbs_ros.config import Config

        self.config = config or Config()
        self.km = KissMatcherRegistration("kiss-matcher", self.config)
        self.voxel = float(voxel)
        self.gicp = SmallGicpRegistration("gicp", self.config)
        self.map_points = np.ascontiguousarray(points, np.float32)
        self.map_gicp = _map_gicp(points, self.config)

    def solve(self, scan, prior=None):
        import kiss_matcher

        from deepbbs_ros.baselines import PreparedCloud

        src = self.km.preprocess(scan).points  # the preprocess crop, as the scan-to-scan baseline
        matcher = kiss_matcher.KISSMatcher(kiss_matcher.KISSMatcherConfig(voxel_size=self.voxel))
        tgt = self.map_points
        if prior is not None:  # a coarse prior: the map within its radius only
            tgt = np.ascontiguousarray(tgt[np.linalg.norm(tgt[:, :2] - prior[0], axis=1) <= prior[1]])
        sol = matcher.estimate(src, tgt)
        T = np.eye(4)
        T[:3, :3] = np.asarray(sol.rotation, dtype=np.float64)
        T[:3, 3] = np.asarray(sol.translation, dtype=np.float64).reshape(3)
        g = self.gicp.align(self.gicp.preprocess(scan), PreparedCloud(self.map_gicp.cloud, self.map_gicp.tree,
                                                                      self.map_gicp.n_points, 0.0), T)
        ok = bool(sol.valid)
        return g.T_target_source, ok, "" if ok else \
            f"KISS-Matcher: solution not valid ({matcher.get_num_final_inliers()} inliers)"


class FpfhRansacSolver:
    """Open3D: FPFH features (voxel ``voxel`` m, normals within 2 voxels, features within 5) of the scan and the
    whole map (the map's once), registration_ransac_based_on_feature_matching (mutual filter off, edge-length
    and distance checkers, 1.5 voxels), then GICP against the whole map. No acceptance test of its own."""

    def __init__(self, points: np.ndarray, config=None, voxel: float = 1.0, iterations: int = 100000) -> None:
        import open3d as o3d  # noqa: F401  (ImportError / OSError: the caller skips this baseline)

        from deepbbs_ros.baselines import SmallGicpRegistration
        from deepbbs_ros.config import Config

        self.config = config or Config()
        self.voxel, self.iterations = float(voxel), int(iterations)
        self.map_down, self.map_fpfh = self._features(points)
        self.gicp = SmallGicpRegistration("gicp", self.config)
        self.map_gicp = _map_gicp(points, self.config)

    def _features(self, points: np.ndarray):
        import open3d as o3d

        reg = o3d.pipelines.registration
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
        down = pc.voxel_down_sample(self.voxel)
        down.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * self.voxel, max_nn=30))
        fpfh = reg.compute_fpfh_feature(down, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * self.voxel, max_nn=100))
        return down, fpfh

    def solve(self, scan, prior=None):
        import open3d as o3d

        from deepbbs_ros.baselines import PreparedCloud
        from deepbbs_ros.core.preprocess import crop_range

        reg = o3d.pipelines.registration
        pp = self.config.preprocess
        pts = scan[crop_range(scan, pp.min_range, pp.max_range)]
        down, fpfh = self._features(pts)
        d = 1.5 * self.voxel
        tgt, tgt_fpfh = self.map_down, self.map_fpfh
        if prior is not None:  # a coarse prior: the map within its radius only
            xy = np.asarray(self.map_down.points)[:, :2]
            idx = np.flatnonzero(np.linalg.norm(xy - prior[0], axis=1) <= prior[1])
            tgt = self.map_down.select_by_index(idx.tolist())
            tgt_fpfh = reg.Feature()
            tgt_fpfh.data = np.ascontiguousarray(self.map_fpfh.data[:, idx])
        o3d.utility.random.seed(RANSAC_SEED)  # each query's draws the same on every run
        res = reg.registration_ransac_based_on_feature_matching(
            down, tgt, fpfh, tgt_fpfh, False, d,
            reg.TransformationEstimationPointToPoint(False), 3,
            [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(d)],
            reg.RANSACConvergenceCriteria(self.iterations, 0.999))
        T = np.asarray(res.transformation, np.float64)
        g = self.gicp.align(self.gicp.preprocess(scan), PreparedCloud(self.map_gicp.cloud, self.map_gicp.tree,
                                                                      self.map_gicp.n_points, 0.0), T)
        return g.T_target_source, True, ""  # no acceptance test: every answer is published
