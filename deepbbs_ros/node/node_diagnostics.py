"""The registration node's counters and ``/diagnostics``: :meth:`NodeDiagnostics.stats`, the diagnostics message
(on a steady timer), an input that never pairs, an unexpected error on a thread, the line said when it stops.

:class:`NodeDiagnostics` is a part of :class:`~deepbbs_ros.node.registration_node.RegistrationNode` (a mixin).
"""

from __future__ import annotations

import threading
import time
import traceback
from pathlib import Path
from typing import Any

from deepbbs_ros.node.diagnostics import RateLimitedErrors, StageTimes
from deepbbs_ros.node.drops import DropLog
from deepbbs_ros.node.pipeline import LocalMapOdometry


class NodeDiagnostics:
    """The node's counters, /diagnostics and error reports."""

    def _init_counters(self, log_period: float) -> None:
        """The counters, the latency per stage and the rate-limited logs (``log_period`` s: ``node.error_log_period``)
        of a node being configured."""
        self._errors = RateLimitedErrors(lambda text: self.get_logger().error(text), log_period)
        # conditions of the graph, not of a message: an input that never pairs, a target not there yet
        self._warnings = RateLimitedErrors(lambda text: self.get_logger().warning(text), log_period)
        # localization: a scan dropped unanswered is said once, later ones summarised (node/drops.py)
        self._drops = DropLog(lambda text: self.get_logger().info(text), log_period)
        self._stages = StageTimes()
        self._lock = threading.Lock()
        self._counts = {"received": 0, "pairs": 0, "processed": 0, "rejected": 0, "time_jumps": 0, "untrusted": 0}
        self._last_result: dict[str, float] = {}
        self._arrivals: dict[int, tuple[float, int]] = {}  # input index -> (monotonic arrival, stamp ns)
        self._gap_seen: float | None = None  # the last pair's time when a check last found the inputs' stamps apart
        self._last_pair_t = time.monotonic()
        self._paths = {"gicp": 0, "deepbbs": 0, "search": 0}  # pair mode: which registration path answered

    def stats(self) -> dict[str, Any]:
        """Counters of the node, its inputs, the synchroniser and the worker (also on /diagnostics)."""
        with self._lock:
            out: dict[str, Any] = dict(self._counts)
            out.update(self._last_result)
            out["paths"] = dict(self._paths)
        out["published"] = self.outputs.published
        out["dropped"] = self.worker.dropped
        out["input_dropped"] = [inp.dropped for inp in self.inputs]
        out["preprocess_cache"] = {"hits": self._cache.hits, "misses": self._cache.misses}
        out["sync"] = dict(self.sync.stats)
        out["sync_queue"] = list(self.sync.queue_lengths())
        out["errors"] = dict(self._errors.counts)
        out["warnings"] = dict(self._warnings.counts)
        out["latency_ms"] = self._stages.summary()
        if isinstance(self.odometry, LocalMapOdometry):
            out["deepbbs_consulted"], out["deepbbs_won"] = self.odometry.consulted, self.odometry.won
            out["degenerate"], out["degenerate_frames"] = self.odometry.degenerate, self.odometry.degenerate_frames
        return out

    def _publish_diagnostics(self) -> None:
        self._check_unpaired()
        s = self.stats()
        values = {
            "mode": self.cfg.node.mode,
            "device": self._device,
            "weights": self._weights,
            "registration process": getattr(self.reg, "state", "off") if hasattr(self.reg, "stream_deskew") else "off",
            "network process": getattr(self.reg, "network_process_state", "-"),
            "messages received": s["received"],
            "pairs synchronised": s["pairs"],
            "pairs processed": s["processed"],
            "pairs dropped (newest wins)": s["dropped"],
            "clouds dropped before preprocessing (oldest first)": ",".join(map(str, s["input_dropped"])),
            "clouds or pairs rejected (bad input)": s["rejected"],
            "poses not published (the verdict rejected them)": s["untrusted"],
            "preprocessing cache hits / misses": "{hits} / {misses}".format(**s["preprocess_cache"]),
            "sync overflow / stale / late": "{overflow} / {stale} / {late}".format(**s["sync"]),
            "sync queue lengths": ",".join(map(str, s["sync_queue"])),
            "odometry restarts on time jumps": s["time_jumps"],
        }
        with self._lock:
            values.update({f"input.{topic}.driver": v for topic, v in sorted(self._drivers.items())})
        if self.cfg.node.mode == "pair":  # which path answered: GICP from the good start, the deep passes, the search
            for path, n in s["paths"].items():
                values[f"paths.{path}"] = n
        if "deepbbs_consulted" in s:
            values["odometry: DeepBBS++ consulted / won"] = f"{s['deepbbs_consulted']} / {s['deepbbs_won']}"
            values["degenerate"] = s["degenerate"] or "no"  # e.g. "corridor-like, weak axis x (ratio 2.1e-03)"
            values["odometry: scans in degenerate places"] = s["degenerate_frames"]
        if self.localization is not None:
            values.update({f"localization.{k}": v for k, v in self.localization.diagnostics().items()})
            drops = self._drops.diagnostics()  # the bridge's drops among them (localization.drop_sink)
            values.update({f"localization.{k}": v for k, v in drops.items()})
            values.update({f"localization.{k}": v for k, v in self.rep105.diagnostics().items()})
        for kind, n in sorted(s["errors"].items()):
            values[f"errors.{kind}"] = n
        for kind, n in sorted(s["warnings"].items()):
            values[f"warnings.{kind}"] = n
        for stage, st in sorted(s["latency_ms"].items()):
            values[f"latency_ms.{stage}"] = f"median {st['median']:.1f} p99 {st['p99']:.1f} max {st['max']:.1f}"
        for k in self._last_result:
            if k in s:
                values[f"last.{k}"] = f"{s[k]:.3f}"
        self.outputs.publish_diagnostics(
            f"{self.get_name()}: registration", self._device, values,
            sum(s["errors"].values()) + sum(s["warnings"].values()),
            self.get_clock().now().to_msg(),
            self._localization_warning() or (f"degenerate place: {s['degenerate']}; the motion model holds the weak "
                                             "direction" if s.get("degenerate") else ""),
        )  # fmt: skip

    def _localization_warning(self) -> str:
        if self.localization is None:
            return ""
        return self.localization.warning() or (self.rep105.problem if self.rep105 is not None else "")

    def _check_unpaired(self) -> None:
        """Pair mode (stamped): an input that has received clouds without a pair for ``node.unpaired_warn_after``
        s is reported (log and /diagnostics), naming the topics and the stamp gap."""
        if self.cfg.node.mode != "pair" or self._map_target is not None or self.localization is not None:
            return
        now = time.monotonic()
        wait = self.cfg.node.unpaired_warn_after
        with self._lock:
            arrivals, last_pair = dict(self._arrivals), self._last_pair_t
        if not arrivals or now - last_pair < wait:
            return
        recent = {i: a for i, a in arrivals.items() if now - a[0] < wait}
        if not recent:
            return  # nothing arriving: not a pairing problem
        names = [inp.topic for inp in self.inputs]
        if len(arrivals) < len(self.inputs):
            missing = [names[i] for i in range(len(self.inputs)) if i not in arrivals]
            self._warnings.log("unpaired_input", f"no pair for {now - last_pair:.1f} s: {', '.join(missing)} has "
                             f"received nothing while {', '.join(names[i] for i in recent)} receives clouds")
            return
        if self._gap_seen != last_pair:
            # reported from the second check on: at the first one the partner may still be on its input's thread
            # (one input has scan k, the other still k - 1 while scan k's is decoded: a pair a moment later)
            self._gap_seen = last_pair
            return
        (_, s0), (_, s1) = arrivals[0], arrivals[1]
        gap = (s0 - s1) * 1e-9
        self._warnings.log(
            "unpaired_input",
            f"no pair for {now - last_pair:.1f} s: {names[0]} stamps are {gap:+.3f} s from {names[1]}'s "
            f"(latest), beyond node.slop={self.cfg.node.slop} s; synchronise the stamps, raise node.slop, or "
            "use node.target_mode:=latched for a static target (a map)",
        )

    def _on_thread_error(self, job, exc: BaseException) -> None:
        text = "".join(traceback.format_exception_only(type(exc), exc)).strip()
        frames = traceback.extract_tb(exc.__traceback__)
        where = f" (in {Path(frames[-1].filename).name}:{frames[-1].lineno}, {frames[-1].name})" if frames else ""
        self._errors.log("internal_error", f"unexpected {text}{where}; the node continues")
        self.get_logger().debug("".join(traceback.format_exception(exc)))


def stop_line(s: dict[str, Any], localization: Any) -> str:
    """The line the node logs when it stops: its counts (``s``: :meth:`NodeDiagnostics.stats`)."""
    line = (f"stopping: {s['received']} clouds received, {s['processed']} processed, {s['published']} poses "
            f"published; dropped before preprocessing {sum(s['input_dropped'])}, by the worker {s['dropped']}, "
            f"rejected {s['rejected']}, not trusted {s['untrusted']}")
    if "deepbbs_consulted" in s:
        line += f"; odometry: DeepBBS++ consulted {s['deepbbs_consulted']}, won {s['deepbbs_won']}"
    if localization is not None:
        d = localization.diagnostics()
        line += (f"; localization: {d['placed']} placed, {d['rejected']} rejected, {d['recoveries']} "
                 f"recoveries, state {d['state']}")
    return line
