"""The registration node's topics: the publishers, the inputs' threads, the TF subscriptions, the services and the
diagnostics timer (:meth:`NodeTopics._create_outputs`), and the inputs' subscriptions, made once the node is warm
(:meth:`NodeTopics._subscribe`).

:class:`NodeTopics` is a part of :class:`~deepbbs_ros.node.registration_node.RegistrationNode` (a mixin).
"""

from __future__ import annotations

import time
from typing import Any

from rclpy.clock import Clock, ClockType
from std_srvs.srv import Trigger

from deepbbs_ros.errors import NodeError
from deepbbs_ros.node.inputs import CloudInput
from deepbbs_ros.node.outputs import Outputs, TfBroadcaster
from deepbbs_ros.node.qos import input_qos, qos_text
from deepbbs_ros.node.rep105 import Rep105
from deepbbs_ros.node.tf_buffer import TransformBuffer


class NodeTopics:
    """Publishers, services, timers and subscriptions."""

    def _create_outputs(self, tf_broadcaster: TfBroadcaster | None) -> None:
        """Publishers, the inputs' threads (their subscriptions are made by :meth:`_subscribe`), the ``/tf_static``
        subscription, the services and the diagnostics timer."""
        ncfg = self.cfg.node
        # topics: a bad (remapped) name becomes NodeError, after stopping the threads started so far
        self.inputs: list[CloudInput] = []
        self._drivers: dict[str, str] = {}  # topic -> its driver and the preprocessing defaults (node.drivers)
        self.static_tf = TransformBuffer()  # /tf_static, and /tf in localization mode (node/tf_buffer.py)
        self._extrinsics: dict[str, Any] = {}  # cloud frame -> T_base_sensor, once known (or given up on)
        self._t_ready = self._t_tf = time.monotonic()  # the static transform's wait counts from here
        try:
            self.outputs = Outputs(self, ncfg, input_qos(ncfg), self._errors.log, tf_broadcaster,
                                   extrinsic=self._base_from_sensor)
            #: localization mode: REP-105 outputs (map -> odom, the base's pose, /initialpose; node/rep105.py)
            self.rep105 = None if self.localization is None else Rep105(
                self, ncfg, self.outputs, self.static_tf, self._base_from_sensor, self._warnings.log,
                self.localization.hint)
            if self.localization is not None:
                self.localization.extrinsic = self._base_from_sensor  # /initialpose: the base's pose -> the sensor's
            self._sub_tf_static = self._subscribe_tf_static()
            self._sub_tf = self._subscribe_tf() if self.rep105 is not None and self.rep105.mode == "tf" else None
            # one QoS object per subscription: rclpy applies qos_overrides.<topic>.* to it in place
            self._subscribe_inputs = [self._make_input(i, name, input_qos(ncfg))
                                      for i, name in enumerate(self.input_names)]
        except NodeError:
            self._stop_threads()
            raise
        except Exception as err:  # rclpy raises several types for bad (remapped) names
            self._stop_threads()
            raise NodeError(f"cannot create topics: {err}".replace("\n", " ")) from err
        self.srv_reset = self.create_service(Trigger, "~/reset", self._on_reset)
        if self.localization is not None:
            self.srv_relocalize = self.create_service(Trigger, "~/relocalize", self._on_relocalize)
        # diagnostics on the steady (wall) clock: with use_sim_time a ROS-time timer stops with /clock (a bag
        # that ended would leave the counters frozen); the messages still carry the node's time
        self._diag_timer = self.create_timer(ncfg.diagnostics_period, self._publish_diagnostics,
                                             clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _subscribe(self) -> None:
        """Subscribe the inputs (after the warm-up: a publisher such as deepbbs-play sees the node once it is ready)
        and log them. Subscriptions the node answers go here, publishers in :meth:`_create_outputs`."""
        ncfg = self.cfg.node
        map_file = self._map_file
        try:
            self._subs = [make() for make in self._subscribe_inputs]
        except Exception as err:  # rclpy raises several types for bad (remapped) names
            self._stop_threads()
            raise NodeError(f"cannot create topics: {err}".replace("\n", " ")) from err
        self._t_ready = time.monotonic()
        self._last_pair_t = self._t_ready
        #: the QoS each input really got, after ``qos_overrides.<topic>.subscription.*``: topic -> "reliable/5"
        self.input_qos = {inp.topic: qos_text(sub.qos_profile) for inp, sub in zip(self.inputs, self._subs)}
        qos_line = ", ".join(f"{t}: {q}" for t, q in self.input_qos.items())
        self.get_logger().info(
            f"mode={ncfg.mode} inputs=[{', '.join(i.topic for i in self.inputs)}] device={self._device} "
            f"weights={self._weights} qos=[{qos_line}] slop={ncfg.slop}s "
            f"queue={ncfg.queue_size}" + (f" odometry={self.odometry_method}" if self.odometry else "")
            + (f" target=latched ({self.inputs[1].topic})" if self._map_target is not None else "")
            + (f" target=localization (map {map_file.source if map_file else self.inputs[1].topic})"
               if self.localization is not None else "")
        )
