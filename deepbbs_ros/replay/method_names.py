"""The registration methods replay knows by name: the lists (pairwise, global, odometry-only, DeepBBS variants),
how each one's input clouds are made (:data:`INPUTS`), ``--method`` parsed (:func:`parse_methods`) and a method's
ROS-legal name (:func:`topic_name`). The methods themselves: replay/methods.py, replay/baseline_methods.py."""

from __future__ import annotations

from deepbbs_ros.errors import ConfigError

METHODS = ("deepbbs++", "deepbbs++s2s", "deepbbs++gicp", "deepbbs", "icp", "plane-icp", "gicp", "kiss-icp",
           "kiss-matcher", "kiss-matcher+gicp")
PAIRWISE = ("deepbbs++", "deepbbs++s2s", "deepbbs++gicp", "deepbbs", "icp", "plane-icp", "gicp", "kiss-matcher",
            "kiss-matcher+gicp")
GLOBAL = ("kiss-matcher", "kiss-matcher+gicp")  # global registrations: pairs mode only
ODOMETRY_ONLY = ("kiss-icp", "deepbbs++s2s")
DEEPBBS_VARIANTS = ("deepbbs++", "deepbbs++s2s", "deepbbs++gicp", "deepbbs")

#: how each method's input clouds are made (reported in metrics.json)
INPUTS = {
    "deepbbs++": "DeepBBS++ preprocessing (crop, ground removal, voxel grid, FPS to preprocess.num_points) and, "
                 "with registration.polish on (default), the GICP precision stage on the whole voxelised scan",
    "deepbbs++gicp": "DeepBBS++ with the GICP precision stage forced on (registration.polish = gicp; the default)",
    "deepbbs": "DeepBBS++ preprocessing; the network alone: deep passes from the one start (no refinement, no "
               "precision stage, no global search)",
    "deepbbs++s2s": "DeepBBS++ scan-to-scan, chained (the paper's pipeline as an odometry)",
    "deepbbs++odom": "DeepBBS++ odometry (core/odometry.py): KISS-ICP-style scan-to-local-map ICP on the raw scan "
                     "(crop, voxel map, deskew from per-point times), DeepBBS++ where the motion prior fails",
    "kiss-matcher": "KISS-Matcher (global, no initial guess) on the raw scan cropped to the preprocess ranges, "
                    "its own voxel grid (eval.kiss_matcher_voxel)",
    "kiss-matcher+gicp": "KISS-Matcher, then small_gicp GICP from its answer on the GICP baseline's clouds",
    "kiss-icp": "KISS-ICP's own pipeline on the raw scan (crop to preprocess ranges, voxel map, deskew)",
}


def parse_methods(text: str, mode: str) -> list[str]:
    """``"deepbbs++,gicp"`` -> ``["deepbbs++", "gicp"]``; ConfigError on unknown / mode-incompatible names."""
    names = [m.strip().lower() for m in text.split(",") if m.strip()]
    if not names:
        raise ConfigError("--method: give at least one method")
    for m in names:
        if m not in METHODS:
            raise ConfigError(f"--method: unknown method {m!r} (known: {', '.join(METHODS)})")
        if m in ODOMETRY_ONLY and mode != "odometry":
            raise ConfigError(f"--method: {m} is an odometry and runs only with --mode odometry")
        if m in GLOBAL and mode == "odometry":
            raise ConfigError(f"--method: {m} is a global pair registration and runs only with --mode pairs")
    return list(dict.fromkeys(names))


def topic_name(method: str) -> str:
    """A ROS-legal name for a method: ``deepbbs++`` -> ``deepbbs_pp``, ``deepbbs++gicp`` -> ``deepbbs_pp_gicp``,
    ``plane-icp`` -> ``plane_icp``."""
    return method.replace("++gicp", "_pp_gicp").replace("++", "_pp").replace("+", "_").replace("-", "_")
