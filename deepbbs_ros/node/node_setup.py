"""The registration node's configure phase: the parameters read, the map file and the model loaded, the pipeline's
parts made (the synchroniser, the odometry, the localization, the worker and its preprocessing cache).

:class:`NodeSetup` is a part of :class:`~deepbbs_ros.node.registration_node.RegistrationNode` (a mixin); the plain
node runs it in ``__init__``, the managed node (:mod:`deepbbs_ros.node.managed`) at configure.
"""

from __future__ import annotations

import threading
import time
from typing import Any

from deepbbs_ros.config import Config
from deepbbs_ros.errors import NodeError
from deepbbs_ros.node.localization import NodeLocalization
from deepbbs_ros.node.map_data import load_map_file
from deepbbs_ros.node.node_parameters import check_frames
from deepbbs_ros.node.parameters import load_registration
from deepbbs_ros.node.pipeline import LocalMapOdometry, MapTarget, PairStart, ScanToScanOdometry, takes_good_start
from deepbbs_ros.node.preprocess_cache import PreprocessCache, arrival_preprocess
from deepbbs_ros.node.sync import ApproximateTimeSync
from deepbbs_ros.node.worker import LatestSlotWorker

ODOMETRY_METHODS = ("local_map", "scan_to_scan")


class NodeSetup:
    """The parameters, the model and the pipeline's parts."""

    def _configure_parts(self, config: Config, registration: Any, odometry_method: str, remaps: Any,
                         t_start: float) -> float:
        """Read the parameters; load the map file, the model (unless ``registration`` is given) and the pipeline's
        parts (the worker's thread). Returns the model's load time (s)."""
        self.cfg = self._declare_config(config)
        ncfg = self.cfg.node
        check_frames(ncfg)
        if odometry_method not in ODOMETRY_METHODS:
            raise NodeError(f"odometry_method must be one of {', '.join(ODOMETRY_METHODS)}, got {odometry_method!r}")
        self.odometry_method = odometry_method
        localization = ncfg.mode == "pair" and ncfg.target_mode == "localization"
        map_file = None
        if localization and self.cfg.localization.map_path:  # read (and refused) before the model loads
            map_file = load_map_file(self.cfg.localization.map_path, ncfg.map_frame)
        self._choose_inputs(remaps, map_file is not None)
        self._init_counters(ncfg.error_log_period)
        self._odom_lock = threading.Lock()  # the odometry state: worker thread vs ~/reset
        self._last_odom_stamp: int | None = None  # odometry mode: a stamp far before it is a time jump (reset)
        self._map_target = MapTarget(self.cfg) if ncfg.mode == "pair" and ncfg.target_mode == "latched" else None
        self._pair_start = PairStart(ncfg.good_start_max_gap, False)  # stamped pairs: the last valid answer (below)

        # the model: device and weights checked first, with errors naming the parameter
        self._owns_reg = registration is None  # closed with the node (its network process)
        if registration is None:
            registration, self._weights = load_registration(self.cfg, lambda text: self.get_logger().error(text))
            t_model = time.perf_counter() - t_start
        else:
            t_model = 0.0
            self._weights = str(getattr(registration, "weights", "") or "<injected model>")
        self.reg = registration
        self._device = str(getattr(registration, "device", "cpu"))
        # a registration that takes a good start (DeepBBS++; not the GICP anchor, which always starts from identity)
        self._pair_start.enabled = ncfg.good_start and ncfg.mode == "pair" and takes_good_start(registration)
        #: node.target_mode localization: the tracker in the prior map (node/localization.py), else None
        self.localization = NodeLocalization(self.cfg, registration) if localization else None
        if localization:  # the scans its bridge passes over: counted and said with the others
            self.localization.drop_sink = lambda why, stamp, n: self._drops.dropped(why, stamp, self.inputs[0].topic, n)
        if map_file is not None:
            self.get_logger().info(self.localization.build(map_file))
            if self.localization.map_warning:
                self.get_logger().warning(self.localization.map_warning)
        if ncfg.publish_odometry:  # warm the imports the first odometry message needs
            import scipy.spatial  # noqa: F401
            import scipy.spatial.transform  # noqa: F401

        # pipeline: synchroniser (pair mode), odometry (odometry mode), the registration worker
        self.sync = ApproximateTimeSync(2, ncfg.queue_size, ncfg.slop, self._on_pair)
        self.odometry = self._make_odometry()
        #: localization with node.localization_odom lidar: the node's own odometry of odom -> base
        self.loc_odometry = None
        if localization and ncfg.localization_odom == "lidar":
            try:
                self.loc_odometry = LocalMapOdometry(self.cfg, self.reg, covariance=False)
            except ImportError as err:
                raise NodeError(f"node.localization_odom lidar needs kiss-icp and small_gicp ({err}); install them, "
                                "or use 'tf' (an odometry source) or 'none'") from err
        self.worker = LatestSlotWorker(self._process, self._on_thread_error, name="deepbbs-registration")
        self._cache = PreprocessCache(arrival_preprocess(self.reg, self._pair_start.enabled or (
            self._map_target is not None and ncfg.good_start)))
        # preprocessing on arrival only where every scan is registered by the network (the localizer preprocesses
        # the raw scan itself, with its per-point times)
        self._preprocess_on_arrival = not isinstance(self.odometry, LocalMapOdometry) and self.localization is None
        self._map_file = map_file
        return t_model

    def _make_odometry(self) -> LocalMapOdometry | ScanToScanOdometry | None:
        """The odometry of odometry mode (None in pair mode): ``reset()`` and ``step(cloud) ->
        OdometryEstimate`` (:mod:`deepbbs_ros.node.pipeline`), sharing the node's registration."""
        if self.cfg.node.mode != "odometry":
            return None
        cov = self.cfg.node.publish_odometry
        if self.odometry_method == "scan_to_scan":
            return ScanToScanOdometry(self.reg, covariance=cov)
        try:
            return LocalMapOdometry(self.cfg, self.reg, covariance=cov)
        except ImportError as err:
            raise NodeError(f"odometry mode needs kiss-icp and small_gicp ({err}); "
                            "install them or use the scan-to-scan odometry") from err
