"""A pose finished on the scans' scene-sized grids, judged on both grids (no ROS).

GICP's 0.5 m grid blends a narrow place's walls, floor and ceiling: in a 2-3 m corridor a roll about its axis moves
the wall points by 2-3 cm per degree, under the residual tolerance the verdict reads the fit's hold with (a fifth of
``registration.verdict_dist``, 0.1 m), so ``pinned`` (core/visibility.py) reads a right pose there as free by 12-16
tolerances along that roll and the verdict rejects it, however well everything else fits. The pose finished on the
scene-sized grids (core/polish.py ``finish``) is pinned there: the finer grid's tolerance scales with it.

Such a pose is taken when both grids take it:

* GICP's grid, on which the verdict's coefficients were fitted, reads every feature but the hold of the weakest
  direction, and that only where its probability is under the bar and GICP's grid does not hold the pose itself
  (``pinned`` under the bound from which the verdict file judges a pose as held where it is, core/calibrated.py
  ``anchored_below``): there ``pinned`` is read on the scene's grids. A pose GICP's grid holds and still rejects (a
  slide along a corridor that its door frames pin elsewhere) stays rejected;
* the scene's grids judge it as ``registration.good_start_finish_grid`` "scene" does: their voxels, the verdict's
  distance scaled with the finer grid (core/verdict.py ``on_scene_grid``), then the second-minimum check there
  (core/second_minimum.py).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from deepbbs_ros.core import anchoring, calibrated, plane_matches, second_minimum, verdict, visibility

__all__ = ["degenerate", "judge"]

_PINNED = visibility.FEATURES.index("pinned")
#: the twist's components (core/anchoring.py: translation, rotation about the target sensor's origin), by name
_AXES = ("x", "y", "z", "a roll about x", "a pitch about y", "a yaw about z")


def _probability(pts: np.ndarray, T: np.ndarray, target: Any, dist: float,
                 pinned: float | None = None) -> tuple[float, float]:
    """(the good-start verdict's probability of ``T`` (4, 4) from ``pts`` against ``target`` at ``dist`` m, with
    ``pinned`` in place of the measured one when given; the measured ``pinned``): the features it reads
    (core/verdict.py ``features``: kept on the target, the good start's own verdict of the same pose)."""
    f = verdict.features(pts, T, target, dist, "good_start")
    own = float(f[_PINNED])
    if pinned is not None:
        f[_PINNED] = pinned
    return float(calibrated.probability(f, "good_start")), own


def _unheld(pts: np.ndarray, T: np.ndarray, tpc: Any, rc: Any, bar: float) -> tuple[float, str]:
    """(GICP's grid's probability of ``T``; why the scene's grids are not read: "" where GICP's grid neither takes the
    pose nor holds it, ``pinned`` under the verdict file's held bound). Arguments as :func:`judge`."""
    held = calibrated.anchored_below()
    p_gicp, pin = _probability(pts, T, tpc, rc.verdict_dist)
    if verdict.is_valid(p_gicp, bar):  # not taken for GICP's grid's own checks (a second minimum): they stand
        return p_gicp, f"taken by GICP's grid's probability {p_gicp:.2f}, not by its checks"
    if held <= 0 or pin >= held:
        return p_gicp, f"GICP's grid holds it (pinned {pin:.3f}) and gives {p_gicp:.2f}"
    return p_gicp, ""


def judge(pts: np.ndarray, T: np.ndarray, spc: Any, tpc: Any, rc: Any, bar: float) -> tuple[float, str]:
    """The pose ``T`` (4, 4), finished on the scene-sized grids of the precision-stage clouds ``spc`` / ``tpc``
    (``core.polish.PolishCloud``), judged on both grids (see the module); ``pts``: the verdict's points on GICP's
    grid (source frame), ``bar``: the probability to reach -> (its probability: the lower of the two grids', "" when
    taken, else why not)."""
    p_gicp, why = _unheld(pts, T, tpc, rc, bar)
    if why:
        return p_gicp, why
    scene = verdict.on_scene_grid(spc, tpc, rc)
    if scene is None:
        return p_gicp, "no scene-sized grid"
    fpts, ftgt, fdist = scene
    p_scene, fine_pin = _probability(fpts, T, ftgt, fdist)
    if not verdict.is_valid(p_scene, bar):
        return p_scene, f"verdict on the scene's grids {p_scene:.2f} < {bar}"
    p_both, _ = _probability(pts, T, tpc, rc.verdict_dist, fine_pin)
    if not verdict.is_valid(p_both, bar):
        return p_both, f"verdict on GICP's grid, pinned on the scene's ({fine_pin:.3f}), {p_both:.2f} < {bar}"
    prob = min(p_scene, p_both)
    scene_rc = dataclasses.replace(rc, verdict_dist=fdist)
    if rc.second_minimum and second_minimum.check(fpts, T, spc.finer(), ftgt, scene_rc).ambiguous:
        return prob, "a second minimum as good along its weakest direction on the scene's grids"
    return prob, ""


def degenerate(pts: np.ndarray, T: np.ndarray, spc: Any, tpc: Any, rc: Any, bar: float) -> str:
    """Why no other start makes the verdict take a pose where GICP's finished pose ``T`` (4, 4) lies ("" where one
    might): GICP's grid neither holds it (``pinned`` under the held bound) nor takes it, yet takes it with ``pinned``
    read on the scene's grids: what the verdict lacks is the hold along the weakest direction, which the scene's
    geometry sets, not the start (the full pipeline's answers there are judged the same way). Arguments as
    :func:`judge`."""
    p_gicp, why = _unheld(pts, T, tpc, rc, bar)
    scene = None if why else verdict.on_scene_grid(spc, tpc, rc)
    if scene is None:
        return ""
    fine_pin = plane_matches.pose_pinned(scene[0], T, scene[1], scene[2])  # its hold alone: the rest is GICP's grid's
    p_both, _ = _probability(pts, T, tpc, rc.verdict_dist, fine_pin)
    if not verdict.is_valid(p_both, bar):
        return ""
    twist, unc = second_minimum.weakest(pts @ T[:3, :3].T + T[:3, 3], tpc, rc.verdict_dist)
    along = "its weakest direction" if twist is None else _AXES[int(np.argmax(np.abs(twist / anchoring.SCALE)))]
    return (f"not valid: degenerate along {along} (free by {unc:.0f} tolerances on GICP's grid, verdict {p_gicp:.2f}; "
            f"held as on the scene's grids, {p_both:.2f}): no other start makes the verdict take a pose here")
