"""The live registration node ``deepbbs_registration`` (console script ``deepbbs-node``).

Inputs (relative names: remap them the ROS way, ``-r source_cloud:=/lidar/points``; a remap whose name is
none of the node's topics is logged as a warning naming the inputs, since ROS ignores it):

* ``node.mode: pair`` (default): ``source_cloud`` and ``target_cloud`` (sensor_msgs/PointCloud2),
  paired by approximate time (``node.queue_size`` per input, ``node.slop`` seconds).
* ``node.mode: odometry``: one input ``cloud`` (or ``pointcloud_topic``, KISS-ICP's name, when that one is
  remapped and ``cloud`` is not: ``-r pointcloud_topic:=/points`` works as with KISS-ICP); the scans run
  through the odometry of ``deepbbs-replay --mode odometry --method deepbbs++``
  (:class:`deepbbs_ros.core.odometry.DeepBBSOdometry`, the
  ``odometry`` config section): deskewing with the per-point times (Velodyne ``time``, Ouster ``t``),
  GICP against a local voxel map, and DeepBBS++ (the node's network) consulted on long stamp gaps, fit drops
  and the first motion (:class:`deepbbs_ros.node.pipeline.LocalMapOdometry`). The chained scan-to-scan
  odometry (scan k registered against scan k-1) stays available as ``odometry_method="scan_to_scan"``
  of :class:`RegistrationNode` (the GICP anchor uses it).

Outputs (docs/CONVENTIONS.md, :mod:`deepbbs_ros.node.outputs`):

* ``~/pose`` (geometry_msgs/PoseStamped). Pair mode: ``T_target_source``, ``frame_id`` = target cloud
  frame, stamp = source stamp. Odometry mode: the base's pose ``T_odom_base = T_base_sensor @ T_odom_sensor @
  inv(T_base_sensor)`` (REP-105; the odom frame is the base at the first scan; ``T_base_sensor`` looked up on
  ``/tf_static`` for ``node.base_frame``, :mod:`deepbbs_ros.node.tf_static`; identity with one warning when
  none arrives within ``node.tf_timeout``, or with ``node.base_frame: ''``), ``frame_id`` = ``node.odom_frame``.
  Latched target (``node.target_mode: latched``): the scan's pose in the map frame.
* ``~/transform`` (geometry_msgs/TransformStamped): the same transform, ``child_frame_id`` = the source
  frame (pair mode) or ``node.base_frame`` / the cloud frame (odometry mode).
* ``~/odometry`` (nav_msgs/Odometry, ``node.publish_odometry``, on by default: twist from the motion since the
  previous scan over the stamp gap, covariances from the registration residuals of that motion,
  :mod:`deepbbs_ros.node.covariance`, accumulated along the trajectory in odometry mode), ``/tf``
  (``node.publish_tf``, on by default in odometry mode: ``odom_frame -> base_frame``, or the inverse with
  ``node.invert_tf``; pair mode only with ``node.pair_tf``; needs tf2_msgs: ``deepbbs-ros build-interfaces``),
  opt-in ``~/aligned_cloud`` (pair mode: the source cloud moved into the target frame; odometry mode: the scan
  moved into ``node.odom_frame``).
* ``/diagnostics``: latency per stage, clouds / pairs received, processed, dropped, errors per kind (an input
  that never pairs: ``unpaired_input``), odometry restarts on time jumps, model, device. ``~/reset``
  (std_srvs/Trigger): restart odometry at identity (a latched target: at ``node.initial_pose``) and clear the
  synchroniser.

Start-up: the model is loaded and every stage run once on a synthetic drive (``node.warmup``) before the node
logs ``ready in X s``. A scan more than 1 s before the previous one in odometry mode (a bag played again)
restarts the odometry with one log line. With ``--ros-args --log-level deepbbs_registration:=debug`` every
odometry step is logged (the path it took: GICP from the prediction, or DeepBBS++ and why; the fit; where
its time went) and every scan dropped for a newer one; the node logs its counts when it stops.

Threads: the executor's callbacks only hand messages on. Each input has its own thread that decodes and
checks every cloud on arrival and preprocesses it for DeepBBS++ (pair mode, scan-to-scan odometry; the
local-map odometry works on the raw points and preprocesses only the scans it consults DeepBBS++ on)
(:mod:`deepbbs_ros.node.inputs`; at most one message waits per input, older ones are dropped and
counted), so a pair's latency is mostly its registration. Registration / odometry runs on one worker
thread behind a "latest" slot (:mod:`deepbbs_ros.node.worker`, :mod:`deepbbs_ros.node.pipeline`): the
newest pair or scan wins, stale ones are dropped and counted. In pair mode on a CPU
(``node.registration_process: auto``) these threads hand the preprocessing and the registration to the
registration process (:mod:`deepbbs_ros.node.registration_process`), so that this process keeps only rclpy,
decoding and the hand-off; if that process dies, one line is logged and the node registers itself. Bad input
(malformed PointCloud2, empty, too few points, NaN-only, missing or changed frames) is logged once per
kind and period (``node.error_log_period``), nothing is published for it, and the node goes on. No callback ends the
executor (:mod:`deepbbs_ros.node.callbacks`): one that raises (a bug, or input nothing else checks) is one error line
naming it, counted on /diagnostics as ``errors.callback <name>``; a failed service answers ``success: false``.
"""

from __future__ import annotations

import sys
import time
from typing import Any

from rclpy.node import Node

from deepbbs_ros.config import Config
from deepbbs_ros.entry import cli_entry
from deepbbs_ros.node.callbacks import GuardedCallbacks
from deepbbs_ros.node.node_diagnostics import NodeDiagnostics, stop_line
from deepbbs_ros.node.node_inputs import InputHandlers
from deepbbs_ros.node.node_jobs import JUMP_BACK_S, RegistrationJobs, _result_summary, _step_line  # noqa: F401
from deepbbs_ros.node.node_parameters import NodeParameters
from deepbbs_ros.node.node_services import NodeServices
from deepbbs_ros.node.node_setup import ODOMETRY_METHODS, NodeSetup  # noqa: F401
from deepbbs_ros.node.node_tf import NodeTf
from deepbbs_ros.node.node_topics import NodeTopics
from deepbbs_ros.node.outputs import TfBroadcaster
from deepbbs_ros.node.run import run_node
from deepbbs_ros.node.warmup import warm_up

NODE_NAME = "deepbbs_registration"


class RegistrationNode(NodeSetup, NodeTopics, NodeParameters, InputHandlers, RegistrationJobs, NodeDiagnostics, NodeTf,
                       NodeServices, GuardedCallbacks, Node):
    """See the module docstring. The node composes its parts: the parameters
    (:mod:`~deepbbs_ros.node.node_parameters`), the model and the pipeline (:mod:`~deepbbs_ros.node.node_setup`),
    the topics (:mod:`~deepbbs_ros.node.node_topics`), the inputs (:mod:`~deepbbs_ros.node.node_inputs`), the
    worker's jobs (:mod:`~deepbbs_ros.node.node_jobs`), the counters and /diagnostics
    (:mod:`~deepbbs_ros.node.node_diagnostics`), TF (:mod:`~deepbbs_ros.node.node_tf`), the services
    (:mod:`~deepbbs_ros.node.node_services`), every callback guarded (:mod:`~deepbbs_ros.node.callbacks`); here: its
    construction (one phase per lifecycle step: :meth:`_configure_parts`, :meth:`_create_outputs`, :meth:`_warm`,
    :meth:`_subscribe`), and its end.

    Args:
        config: defaults of every parameter (ROS parameters override them); None = ``Config()``.
        registration: a ready registration object (``preprocess(xyz)``, ``register(src_pp, tgt_pp)``),
            e.g. a small test model or the GICP anchor; default: DeepBBS++ with ``registration.weights``.
        tf_broadcaster: used instead of a ``/tf`` publisher when ``node.publish_tf`` is set.
        odometry_method: odometry mode's pipeline: ``"local_map"`` (default; DeepBBSOdometry, as
            ``deepbbs-replay --mode odometry --method deepbbs++``) or ``"scan_to_scan"`` (scan k registered
            against scan k-1 with ``registration``, chained; each scan preprocessed on arrival).
        remaps: the command line's remap rules (:func:`~deepbbs_ros.node.remaps.remap_rules`, given by
            ``run_node``): those that match none of the node's topics are logged as warnings
            (:attr:`remap_warnings`) before the model loads.
        node_name, node_kwargs: passed to ``rclpy.node.Node``.

    Raises:
        NodeError: a bad parameter, frame id, topic name or weights path.
    """

    def __init__(
        self,
        config: Config | None = None,
        *,
        registration: Any = None,
        tf_broadcaster: TfBroadcaster | None = None,
        odometry_method: str = "local_map",
        node_name: str = NODE_NAME,
        remaps: Any = (),
        **node_kwargs: Any,
    ) -> None:
        t_start = time.perf_counter()
        super().__init__(node_name, **node_kwargs)
        t_model = self._configure_parts(config or Config(), registration, odometry_method, remaps, t_start)
        self._create_outputs(tf_broadcaster)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        t_warm = time.perf_counter()
        self._warm()
        self._subscribe()
        t_end = time.perf_counter()
        self.startup_s = t_end - t_start
        self.get_logger().info(
            f"ready in {self.startup_s:.1f} s (model {t_model:.1f} s, warm-up {t_end - t_warm:.1f} s)"
        )

    # -- phases: the plain node runs them in __init__, the managed node (node/managed.py) one per transition;
    # _configure_parts in node_setup.py, _create_outputs and _subscribe in node_topics.py, the warm-up here -----
    def _warm(self) -> None:
        """The warm-up (:func:`~deepbbs_ros.node.warmup.warm_up`) where ``node.warmup`` asks for it and the model is the
        node's own."""
        self.warmed_up = False
        if self.cfg.node.warmup and self._owns_reg:  # an injected registration (tests, the GICP anchor) is the caller's
            try:
                warm_up(self.cfg.preprocess.max_range, self.reg, self.odometry, self._odom_lock,
                        self._preprocess_on_arrival)
                self.warmed_up = True
            except Exception as err:  # noqa: BLE001 - a failed warm-up costs the first scans' latency, nothing else
                self.get_logger().warning(f"warm-up failed ({type(err).__name__}: {err}); the first scans run cold")

    # -- the end: threads stopped, counts logged, the node's own model closed ------------------------------------
    def _stop_threads(self) -> None:
        for inp in self.inputs:
            inp.stop()
        self.worker.stop()
        if getattr(self, "localization", None) is not None:
            self.localization.stop()

    def destroy_node(self):
        self._release()
        return super().destroy_node()

    def _release(self) -> None:
        """Stop the threads, log the counts, close the node's own registration (its processes)."""
        self._stop_threads()
        self.get_logger().info(stop_line(self.stats(), self.localization))
        if self._owns_reg and hasattr(self.reg, "close"):
            self.reg.close()


@cli_entry("deepbbs-node")
def main(argv: list[str] | None = None) -> int:
    """``deepbbs-node [--config YAML] [--ros-args ...]``: run until Ctrl-C."""
    return run_node(argv, "deepbbs-node", "Live DeepBBS++ registration node.", RegistrationNode)


if __name__ == "__main__":
    sys.exit(main())
