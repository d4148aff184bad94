"""The registration node's worker thread: one job (a pair, a latched-map scan, a scan to localize, an odometry
scan) registered and its outputs published, its timings and the path it took counted.

:class:`RegistrationJobs` is a part of :class:`~deepbbs_ros.node.registration_node.RegistrationNode` (a mixin):
:meth:`_process` is the :class:`~deepbbs_ros.node.worker.LatestSlotWorker`'s function.
"""

from __future__ import annotations

import time
from typing import Any

from rclpy.logging import LoggingSeverity

from deepbbs_ros.node.inputs import BadInput, Cloud
from deepbbs_ros.node.pipeline import register_clouds

JUMP_BACK_S = 1.0  # s; odometry mode: a stamp this far before the last one is a time jump (reset)


class RegistrationJobs:
    """The node's registration side, on its worker thread."""

    def _process(self, job: tuple[str, Cloud, Cloud | None]) -> None:
        mode, src, tgt = job
        t_start = time.perf_counter()
        t_in = src.t_recv if tgt is None else max(src.t_recv, tgt.t_recv)
        t_ready = src.t_ready if tgt is None else max(src.t_ready, tgt.t_ready)
        timings = {"queue_wait": (t_start - t_ready) * 1e3}
        found = None  # localization: a scan a search placed (the scans that came meanwhile follow it)
        try:
            if mode == "pair":
                T_start = self._pair_start.start(src, tgt)  # the last valid answer (None: the full pipeline)
                reg = register_clouds(self.reg, src, tgt, T_init=T_start, good_start=T_start is not None)
                self._pair_start.update(src, tgt, reg)
                t0 = time.perf_counter()
                if getattr(reg.result, "valid", True):
                    self.outputs.pair(src, tgt, reg)
                else:  # the verdict: a pose that cannot be trusted is not published (counted, logged rate-limited)
                    self._untrusted(reg.result)
            elif mode == "localize":
                if self.loc_odometry is not None:  # odom -> base of the node's own odometry first, then map -> odom
                    self.rep105.odometry_step(src, self.loc_odometry.step(src))
                loc = self.localization.step(src)
                if loc is None:  # answered already, while following a search's pose to the newest scan
                    return
                reg = loc.registered
                t0 = time.perf_counter()
                self._localized(src, loc)
                found = loc if loc.result.event in ("found", "relocalized") else None
            elif mode == "map":
                reg, tgt_points = self._map_target.register(self.reg, src)
                t0 = time.perf_counter()
                if getattr(reg.result, "valid", True):
                    self.outputs.localized(src, tgt.frame_id, reg, tgt_points)
                else:
                    self._untrusted(reg.result)
            else:
                with self._odom_lock:  # ~/reset runs on the executor thread
                    self._check_time_jump(src)
                    step = self.odometry.step(src)
                    self._last_odom_stamp = src.stamp_ns
                reg = step.registered
                t0 = time.perf_counter()
                self.outputs.odometry_step(src, step)
        except BadInput as bad:
            self._on_bad(bad.kind, str(bad))
            return
        t_end = time.perf_counter()
        with self._lock:
            self._counts["processed"] += 1
            if reg is not None:
                self._last_result = _result_summary(reg.result)
                path = getattr(reg.result, "path", "") if mode != "odometry" else ""
                if path in self._paths:
                    self._paths[path] += 1
        if reg is None:  # the odometry origin: nothing was registered
            if mode == "odometry" and self.get_logger().is_enabled_for(LoggingSeverity.DEBUG):
                self.get_logger().debug(f"odometry step {src.stamp_ns} ns: origin; ms: queue_wait "
                                        f"{timings['queue_wait']:.0f} total {(t_end - t_in) * 1e3:.0f}")
            return
        timings.update(reg.timings_ms)
        timings["publish"] = (t_end - t0) * 1e3
        timings["total"] = (t_end - t_in) * 1e3
        self._stages.add(timings)
        if mode == "localize" and found is not None:
            self._follow(src, found)
        if mode == "odometry" and self.get_logger().is_enabled_for(LoggingSeverity.DEBUG):
            self.get_logger().debug(_step_line(src, reg, timings))

    def _follow(self, src: Cloud, found: Any) -> None:
        """A search placed ``src``: the scans that arrived meanwhile are tracked and published (node/bridge.py), the
        node's own odometry stepped through them first; their time is the ``bridge`` stage."""
        t0 = time.perf_counter()
        for cloud, later in self.localization.bridge(found, src.stamp_ns):
            if self.loc_odometry is not None:
                self.rep105.odometry_step(cloud, self.loc_odometry.step(cloud))
            self._localized(cloud, later)
        if self.localization.last_bridge:
            self._stages.add({"bridge": (time.perf_counter() - t0) * 1e3})
            self.get_logger().info(self.localization.last_bridge)

    def _localized(self, src: Cloud, loc: Any) -> None:
        """Publish one localized scan (REP-105 outputs); a rejected one is counted (there and as not trusted), never
        published."""
        if loc.line:
            self.get_logger().info(loc.line)
        if loc.result.valid:
            self.rep105.localized(src, loc.frame_id, loc.registered, loc.result, loc.crop)
        else:
            with self._lock:
                self._counts["untrusted"] += 1

    def _check_time_jump(self, cloud: Cloud) -> None:
        """Odometry mode: a scan more than ``JUMP_BACK_S`` before the last one (a bag played again, ``deepbbs-play
        --loop``, simulated time rewound) restarts the odometry at identity, with one log line."""
        last = self._last_odom_stamp
        if last is not None and cloud.stamp_ns < last - int(JUMP_BACK_S * 1e9):
            self.odometry.reset()
            with self._lock:
                self._counts["time_jumps"] += 1
            self.get_logger().info(
                f"{self.inputs[0].topic}: time jumped back {(last - cloud.stamp_ns) * 1e-9:.2f} s "
                f"(stamp {cloud.stamp_ns} ns after {last} ns): odometry restarted at identity"
            )

    def _untrusted(self, result: Any) -> None:
        with self._lock:
            self._counts["untrusted"] += 1
        self._errors.log("untrusted_pose", f"pose not published: the verdict's probability {result.probability:.2f} is "
                         f"below registration.verdict_probability {self.cfg.registration.verdict_probability} (the "
                         "scans do not overlap, or no start yaw registered them)")


def _step_line(cloud: Cloud, reg: Any, timings: dict[str, float]) -> str:
    """One odometry step for the debug log: the stamp, the path it took (GICP from the prediction, or DeepBBS++
    consulted and why), the fit and where its time went."""
    step = reg.result
    path = "gicp"
    if getattr(step, "deepbbs", False):
        path = f"deepbbs++ ({step.reason}; {'won' if step.won else 'not used'})"
    times = {**cloud.timings_ms, **timings}
    stages = " ".join(f"{k.removeprefix('register.')} {v:.0f}" for k, v in times.items())
    return f"odometry step {cloud.stamp_ns} ns: {path}, fit {getattr(step, 'fit', float('nan')):.2f}; ms: {stages}"


def _result_summary(result: Any) -> dict[str, float]:
    """The last result's figures for /diagnostics: the odometry's fit (an ``OdometryStep``), else the
    registration's inlier ratio and convergence."""
    if hasattr(result, "fit") and hasattr(result, "T_first_k"):
        return {"odometry_fit": float(result.fit), "odometry_deepbbs": float(bool(result.deepbbs))}
    return {
        "inlier_ratio": float(getattr(result, "inlier_ratio", float("nan"))),
        "converged": float(bool(getattr(result, "converged", False))),
        "verdict_score": float(getattr(result, "score", float("nan"))),
        "verdict_probability": float(getattr(result, "probability", float("nan"))),
    }
