"""The registration node's inputs: each input's thread and subscription, and what each arriving cloud is handed to
(the synchroniser, the latched map, the tracker, the odometry), by mode; the messages counted, bad ones logged.

:class:`InputHandlers` is a part of :class:`~deepbbs_ros.node.registration_node.RegistrationNode` (a mixin): its
methods run on the executor's thread (``_on_message``) and on the inputs' threads, over the node's counters, lock,
synchroniser, worker and localization.
"""

from __future__ import annotations

import functools
import time
from typing import Any

from rclpy.logging import LoggingSeverity
from rclpy.qos import QoSProfile
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import PointCloud2

from deepbbs_ros.errors import NodeError
from deepbbs_ros.node.drivers import describe as describe_driver
from deepbbs_ros.node.inputs import Cloud, CloudInput
from deepbbs_ros.node.pipeline import LocalMapOdometry
from deepbbs_ros.node.qos import latched_qos
from deepbbs_ros.node.remaps import KISS_ICP_INPUT, ODOM_INPUT, PAIR_INPUTS, unmatched_remaps


class InputHandlers:
    """The node's input side: :meth:`_choose_inputs`, :meth:`_make_input` per input, then the handlers of each
    cloud."""

    def _choose_inputs(self, remaps: Any, map_file: bool) -> None:
        """``input_names`` by mode (``map_file``: the map is the file's, no map topic); the remap rules that match none
        of them (and a KISS-ICP remap that ``cloud``'s overrides) logged as warnings (``remap_warnings``)."""
        ncfg = self.cfg.node
        # inputs: KISS-ICP's pointcloud_topic is the odometry input when it is remapped and cloud is not
        self.input_names = PAIR_INPUTS if ncfg.mode == "pair" else (ODOM_INPUT,)
        if map_file:
            self.input_names = PAIR_INPUTS[:1]  # the map is the file's: no map topic
        if ncfg.mode == "odometry" and self._remapped(KISS_ICP_INPUT) and not self._remapped(ODOM_INPUT):
            self.input_names = (KISS_ICP_INPUT,)
        self.remap_warnings = unmatched_remaps(remaps, ncfg.mode, self.get_name(), self.get_namespace())
        if ncfg.mode == "odometry" and self._remapped(KISS_ICP_INPUT) and self._remapped(ODOM_INPUT):
            self.remap_warnings.append(f"{KISS_ICP_INPUT} and {ODOM_INPUT} are both remapped: the input is "
                                       f"{ODOM_INPUT}'s topic, the {KISS_ICP_INPUT} remap is ignored")
        for text in self.remap_warnings:
            self.get_logger().warning(text)

    def _remapped(self, name: str) -> bool:
        """Whether a remap rule applies to the topic ``name``."""
        try:
            return self.resolve_topic_name(name) != self.resolve_topic_name(name, only_expand=True)
        except Exception:  # noqa: BLE001 - a bad remapped name is reported when the input is made
            return True

    def _make_input(self, index: int, name: str, qos: QoSProfile):
        pair = self.cfg.node.mode == "pair"
        latched = (self._map_target is not None or self.localization is not None) and name == "target_cloud"

        def on_cloud(cloud: Cloud) -> None:  # on the input's thread, once the cloud is preprocessed
            self._stages.add(cloud.timings_ms)
            with self._lock:
                self._arrivals[index] = (time.monotonic(), cloud.stamp_ns)
            if latched and self.localization is not None:
                self._on_localization_map(index, cloud)
            elif latched:
                self._map_target.set_map(cloud)
                self.get_logger().info(
                    f"target (map) from {self.inputs[index].topic}: {len(cloud.xyz)} points in {cloud.frame_id!r}"
                )
            elif self.localization is not None:
                self._on_localize_source(cloud)
            elif self._map_target is not None:
                self._on_map_source(cloud)
            elif pair:
                self.sync.add(index, cloud.stamp_ns, cloud)
            else:
                self._on_scan(cloud)

        if latched:  # a map server's QoS: reliable, transient local (the map published once reaches late joiners)
            qos = latched_qos()
        def subscribe():  # after the warm-up: a publisher (deepbbs-play) sees the node once it is ready
            return self.create_subscription(
                PointCloud2, name, lambda msg: self._on_message(index, msg), qos,
                qos_overriding_options=QoSOverridingOptions.with_default_policies(),
            )  # fmt: skip

        self.resolve_topic_name(name)  # a bad (remapped) name fails here, before the model's warm-up
        self.inputs.append(
            CloudInput(
                self.resolve_topic_name(name), self._cache if self._preprocess_on_arrival and not latched else None,
                self.cfg.node.min_points, on_cloud, self._on_bad, self._on_thread_error,
                increasing_stamps=not pair, gate=None if latched else self._input_gate(),
                deskew=None if latched else self._stream_deskew(),
                capacity=1 if pair else self.cfg.node.odometry_backlog,
                on_driver=None if latched else functools.partial(self._on_driver, index),
            )
        )  # fmt: skip
        return subscribe

    def _input_gate(self) -> Any:
        """The worker's room; in localization mode also open while a search or a bridge runs (node/bridge.py)."""
        if self.localization is None:
            return self.worker.room
        from deepbbs_ros.node.bridge import ArrivalGate

        return ArrivalGate(self.worker.room, lambda: self.localization.opens_input)

    def _on_driver(self, index: int, driver: str | None, xyz: Any) -> None:
        """An input's driver, recognised from its first message: logged, on /diagnostics, given to the odometry."""
        topic = self.inputs[index].topic
        value, line = describe_driver(topic, self.cfg.preprocess, driver, xyz, used=self.localization is None)
        with self._lock:
            self._drivers[topic] = value
        self.get_logger().info(line)
        if isinstance(self.odometry, LocalMapOdometry):  # DeepBBS++ consulted on its deskewed scans
            self.odometry.odometry.driver = driver

    def _on_message(self, index: int, msg: PointCloud2) -> None:
        t_recv = time.perf_counter()
        with self._lock:
            self._counts["received"] += 1
        inp = self.inputs[index]
        dropped = inp.dropped
        inp.submit(msg, t_recv)
        if inp.dropped > dropped and self.localization is not None:
            self._drops.dropped("before preprocessing: a newer scan arrived while the registration was busy",
                                _stamp_ns(msg), inp.topic)
        elif inp.dropped > dropped and self.get_logger().is_enabled_for(LoggingSeverity.DEBUG):
            self.get_logger().debug(f"{inp.topic}: the oldest waiting cloud dropped (scan at "
                                    f"{_stamp_ns(msg)} ns arrived, {inp.dropped} dropped so far)")

    def _on_bad(self, kind: str, message: str) -> None:
        with self._lock:
            self._counts["rejected"] += 1
        self._errors.log(kind, message)

    def _on_pair(self, items) -> None:
        (_, src), (_, tgt) = items
        self._paired()
        self.worker.submit(("pair", src, tgt))

    def _paired(self) -> None:
        """A pair (or a scan with its map) goes to the worker: counted, and the unpaired-input check's clock reset."""
        with self._lock:
            self._counts["pairs"] += 1
            self._last_pair_t = time.monotonic()

    def _on_map_source(self, cloud: Cloud) -> None:
        """Latched target: every source is paired with the latest map (no stamp matching)."""
        map_cloud = self._map_target.map
        if map_cloud is None:
            self._warnings.log("no_target", f"{self.inputs[0].topic}: scan at {cloud.stamp_ns} ns dropped: no target "
                             f"(map) on {self.inputs[1].topic} yet (latched: transient_local, reliable)")
            return
        self._paired()
        self.worker.submit(("map", cloud, map_cloud))

    def _on_localization_map(self, index: int, cloud: Cloud) -> None:
        """Localization: a map on the latched topic; its places and descriptors are built here (the map input's
        thread), the next scan searches it."""
        from deepbbs_ros.node.map_data import MapData

        try:
            line = self.localization.build(MapData(cloud.xyz, cloud.frame_id, self.inputs[index].topic))
        except NodeError as err:
            self._on_bad("bad_map", str(err))
            return
        self.get_logger().info(line)

    def _on_localize_source(self, cloud: Cloud) -> None:
        """Localization: every scan goes to the tracker (newest wins), once there is a map."""
        if not self.localization.has_map:
            topic = self.inputs[1].topic if len(self.inputs) > 1 else "the map topic"
            self._warnings.log("no_target", f"{self.inputs[0].topic}: scan at {cloud.stamp_ns} ns dropped: no map on "
                               f"{topic} yet (latched: transient_local, reliable), and localization.map_path is empty")
            return
        self._paired()
        self.localization.prepare(cloud)  # its GICP cloud on this input thread, on arrival (as the other modes)
        cloud.t_ready = time.perf_counter()
        slot = self.localization.last_arrival  # the scan a submit replaces (the worker keeps one), if it still waits
        self.localization.arrived(cloud)  # kept while a search runs: its pose is carried through them (bridge.py)
        if (self.worker.submit(("localize", cloud, None)) and not self.localization.keeps_arrivals
                and not self.localization.answered(slot)):  # one the bridge answered already is no loss
            self._drops.dropped("waiting for the registration: a newer scan replaced it (the registration of a scan "
                                "took longer than the scan period)", cloud.stamp_ns, self.inputs[0].topic)

    def _on_scan(self, cloud: Cloud) -> None:
        with self._lock:
            self._counts["pairs"] += 1
        self.worker.submit(("odometry", cloud, None))

    def _stream_deskew(self):
        """A per-topic velocity follower + deskew (``core.deskew.StreamDeskew``) where each scan is
        preprocessed on arrival by DeepBBS++ with its precision stage and ``node.pair_deskew`` is on; None
        elsewhere."""
        remote = hasattr(self.reg, "stream_deskew")  # the registration process: the topic's StreamDeskew runs there
        if not self._preprocess_on_arrival or not (remote or hasattr(self.reg, "deskew_scan")):
            return None
        if not (self.cfg.preprocess.deskew and self.cfg.node.pair_deskew) or self.cfg.registration.polish == "none":
            return None
        if remote:
            return self.reg.stream_deskew()
        from deepbbs_ros.core.deskew import StreamDeskew

        return StreamDeskew(self.reg)


def _stamp_ns(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
