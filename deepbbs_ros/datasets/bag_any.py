"""Reading ROS 1 bags and sqlite3 rosbag2 recordings through rosbags' ``AnyReader`` (no ROS install)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

from deepbbs_ros.datasets.bag_common import bag_typestore, detail
from deepbbs_ros.errors import BagError


class AnyBackend:
    """rosbags AnyReader: ROS 1 .bag, rosbag2 sqlite3 directories, bare .db3."""

    def __init__(self, path: Path) -> None:
        from rosbags.highlevel import AnyReader

        ros1 = path.suffix == ".bag"
        self.path = path
        self.reader = AnyReader([path], default_typestore=bag_typestore(ros1))
        self.reader.open()
        self.kind = "rosbag1" if ros1 else ("db3" if path.suffix == ".db3" else "rosbag2-sqlite3")
        self.warnings: list[str] = []
        self.topics: dict[str, tuple[str, int]] = {}
        for c in self.reader.connections:
            typ, cnt = self.topics.get(c.topic, (c.msgtype, 0))
            self.topics[c.topic] = (typ, cnt + int(c.msgcount))
        self.start_ns = int(self.reader.start_time) if self.reader.connections else 0
        self.end_ns = int(self.reader.end_time) - 1 if self.reader.connections else 0  # end_time is last + 1

    def raw(self, topics: list[str] | None, on_damage=None) -> Iterator[tuple[str, str, int, Any]]:
        """(topic, msgtype, log_time_ns, raw bytes) in log-time order; BagError on damage."""
        conns = [c for c in self.reader.connections if topics is None or c.topic in topics]
        it = self.reader.messages(connections=conns)
        last = None
        while True:
            try:
                item = next(it, None)
            except Exception as err:  # noqa: BLE001 - damaged bytes reach rosbags' parsers in many ways
                where = f"after log time {last * 1e-9:.6f} s" if last is not None else "before the first message"
                raise BagError(f"{self.path}: bag is truncated or corrupt {where} ({detail(err)})") from None
            if item is None:
                return
            conn, t, data = item
            last = t
            yield conn.topic, conn.msgtype, int(t), data

    def decode(self, msgtype: str, data: Any) -> Any:
        return self.reader.deserialize(data, msgtype)

    def close(self) -> None:
        self.reader.close()
