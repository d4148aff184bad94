"""A ROS 2 recording's LiDAR (and ground-truth) topic copied message by message into a new rosbag2 (no ROS):
``BagSource.copy_to`` (datasets/rosbag.py), what ``deepbbs-bag convert`` does from a ROS 2 bag to a bag without
``--repack``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from deepbbs_ros.datasets.bag_common import bag_typestore, detail
from deepbbs_ros.datasets.bag_mcap import McapBackend
from deepbbs_ros.datasets.bag_topics import several_clouds
from deepbbs_ros.datasets.bag_write import qos_profile, rosbag2_writer
from deepbbs_ros.errors import BagError, DeepBBSError


def copy_messages(source: Any, out: Path | str, storage: str, topic: str | None, gt_topic: str | None,
                  max_frames: int | None) -> int:
    """``source.copy_to(out, storage, topic=, gt_topic=, max_frames=)`` of a ``BagSource`` ``source`` (see there):
    -> the clouds written."""
    if source.format == "rosbag1":
        raise BagError(f"{source.path}: a ROS 1 bag cannot be copied message by message; convert it with --repack")
    if source.topic is None:
        raise several_clouds(source.path, source.cloud_topics)
    names = {source.topic: topic or source.topic}
    if source.gt_topic is not None:
        names[source.gt_topic] = gt_topic or source.gt_topic
    typestore = bag_typestore()
    qos = [qos_profile()]
    n = 0
    last_cloud_t = None
    try:
        with rosbag2_writer(out, storage) as writer:
            conns: dict[str, Any] = {}
            try:
                for src_topic, typ, t, data in source.backend.raw(list(names)):
                    if src_topic == source.topic:
                        if max_frames is not None and n >= max_frames:
                            break
                        n += 1
                        last_cloud_t = t
                    elif max_frames is not None and n >= max_frames and t > last_cloud_t:
                        continue  # ground truth after the last cloud copied
                    if isinstance(source.backend, McapBackend):
                        source.backend._register(data[0])
                        payload = data[2].data
                    else:
                        payload = data
                    if src_topic not in conns:
                        conns[src_topic] = writer.add_connection(names[src_topic], typ, typestore=typestore,
                                                                 offered_qos_profiles=qos)
                    writer.write(conns[src_topic], t, payload)
            except BagError as err:
                source.fault(err)
    except Exception as err:  # noqa: BLE001 - the writer's own errors (rosbags WriterError, disk full)
        if isinstance(err, DeepBBSError):
            raise
        raise BagError(f"{out}: cannot write bag: {detail(err)}") from None
    return n
