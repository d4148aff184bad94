"""What a recording holds, counted by reading it, and its copy (no ROS install): :class:`BagInfo`, a mixin of
datasets/rosbag.py's ``BagSource`` (which fills ``backend``, ``topic`` and ``cloud_topics``)."""

from __future__ import annotations

from pathlib import Path

from deepbbs_ros.datasets.bag_common import count_messages, metadata_counts
from deepbbs_ros.datasets.bag_copy import copy_messages
from deepbbs_ros.datasets.bag_mcap import McapBackend


class BagInfo:
    """``read_counts``, ``copy_to`` and ``info`` of a :class:`~deepbbs_ros.datasets.rosbag.BagSource`."""

    def read_counts(self) -> tuple[dict[str, tuple[str, int]], str | None]:
        """Read the whole recording (every chunk CRC-checked, nothing decoded): ({topic: (type, count)},
        the damage met or None)."""
        topics, _lo, _hi, error = count_messages(self.backend)
        if isinstance(self.backend, McapBackend):
            crc = self.backend.data_crc_errors()
            if crc and not error:  # damage outside the chunks (their own CRCs passed)
                error = "; ".join(crc)
        return topics, error

    def copy_to(self, out: Path | str, storage: str = "mcap", *, topic: str | None = None,
                gt_topic: str | None = None, max_frames: int | None = None) -> int:
        """Copy the LiDAR topic (and the ground-truth topic) message by message into a new rosbag2:
        the clouds keep their bytes (layout, fields, organisation, frame), each topic its type; ``topic``
        / ``gt_topic`` rename them in the copy. ROS 2 recordings only (a ROS 1 cloud has another
        serialisation: see :func:`write_rosbag`). Damage stops the copy as reading does (strict: BagError;
        lenient: recorded in ``errors``, the copy holds everything before it). Returns the clouds written.
        """
        return copy_messages(self, out, storage, topic, gt_topic, max_frames)

    def info(self) -> dict:
        """What the recording holds, counted by reading it (``frames`` = scans on the LiDAR topic);
        ``metadata_counts`` where metadata.yaml states other counts, ``damage`` where reading stopped."""
        counts, damage = self.read_counts()
        types = {t: typ for t, (typ, _) in self.backend.topics.items()}
        d = super().info()  # path, format, topics, frames (here: as counted), ground truth
        d["frames"] = counts.get(self.topic, ("", 0))[1] if self.topic else None
        d.update({
            "cloud_topics": self.cloud_topics,
            "duration_s": (self.backend.end_ns - self.backend.start_ns) * 1e-9,
            "start_ns": self.backend.start_ns,
            "topics": [{"topic": t, "type": types.get(t, counts.get(t, ("?",))[0]), "count": counts.get(t, ("", 0))[1]}
                       for t in sorted(set(types) | set(counts))],
        })
        meta = metadata_counts(self.path)
        if meta is not None:
            differ = {t: n for t, n in meta.items() if n != counts.get(t, ("", 0))[1]}
            if differ:
                d["metadata_counts"] = differ
        if damage:
            d["damage"] = damage
        return d
