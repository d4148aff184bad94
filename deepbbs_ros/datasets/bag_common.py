"""What the bag readers and writers share: message type names, the typestores, which paths are bags, a one-line
error detail and message counting (no ROS install)."""

from __future__ import annotations

from pathlib import Path

from deepbbs_ros.errors import BagError

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "nav_msgs/msg/Odometry", "geometry_msgs/msg/TransformStamped")


def is_bag(path: Path) -> bool:
    """True for a ROS 1 ``.bag``, a bare ``.mcap``/``.db3`` or a rosbag2 directory."""
    if path.is_dir():
        return (path / "metadata.yaml").is_file() or any(path.glob("*.mcap")) or any(path.glob("*.db3"))
    return path.suffix in (".bag", ".mcap", ".db3")


def bag_typestore(ros1: bool = False):
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_JAZZY)


def is_mcap(path: Path) -> bool:
    return (path.is_file() and path.suffix == ".mcap") or (path.is_dir() and any(path.glob("*.mcap")))


def detail(err: BaseException) -> str:
    text = str(err).strip().splitlines()[0] if str(err).strip() else ""
    return f"{type(err).__name__}: {text}" if text else type(err).__name__


def metadata_counts(path: Path) -> dict[str, int] | None:
    """``{topic: message_count}`` as a rosbag2 directory's metadata.yaml states it, or None."""
    meta = path / "metadata.yaml"
    if not path.is_dir() or not meta.is_file():
        return None
    try:
        import yaml

        doc = yaml.safe_load(meta.read_text())
        entries = doc["rosbag2_bagfile_information"]["topics_with_message_count"] or []
        return {str(e["topic_metadata"]["name"]): int(e["message_count"]) for e in entries}
    except Exception:  # noqa: BLE001 - a damaged metadata.yaml only loses the comparison
        return None


def count_messages(backend) -> tuple[dict[str, tuple[str, int]], int, int, str | None]:
    """Read every message of a backend (nothing decoded): ({topic: (type, count)}, first, last log time, the damage
    met or None). A damaged chunk that can be stepped over is counted as damage and reading goes on after it."""
    topics: dict[str, tuple[str, int]] = {}
    lo, hi, error = None, None, None
    damage: list[str] = []
    try:
        for topic, typ, t, _data in backend.raw(None, on_damage=lambda err: damage.append(str(err))):
            _typ, cnt = topics.get(topic, (typ, 0))
            topics[topic] = (typ, cnt + 1)
            lo, hi = (t, t) if lo is None else (min(lo, t), max(hi, t))
    except BagError as err:
        damage.append(str(err))
    error = "; ".join(damage) if damage else None
    return topics, lo or 0, hi or 0, error
