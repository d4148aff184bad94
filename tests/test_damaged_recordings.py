"""Damaged recordings end in a clear answer: one error line and exit code 1, or the results of every
frame the damage did not touch with ``"complete": false`` and the reason; never a traceback, never
``"complete": true`` for an unfinished run. Every mcap written carries chunk, data and summary CRCs.

Each damaged kind is built from a tiny recording written into tmp_path by the package's own writers
(rosbags + the mcap package for bags, the PCD/KITTI writers for folders), then damaged byte-wise.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from deepbbs_ros.cli.bag import main as bag_main
from deepbbs_ros.cli.replay import main as replay_main
from deepbbs_ros.datasets import open_source, write_pcd, write_scans
from deepbbs_ros.datasets.rosbag import write_rosbag
from deepbbs_ros.errors import DatasetError
from deepbbs_ros.replay.synthetic import synthetic_drive

N = 8
CHUNK = 64 * 1024  # small chunks: one scan (~150 kB) closes a chunk, so the bag has several


@pytest.fixture(scope="module")
def scans():
    return synthetic_drive(N, seed=3, keep=0.25)


@pytest.fixture(scope="module")
def fast_config(tmp_path_factory):
    path = tmp_path_factory.mktemp("cfg") / "fast.yaml"
    path.write_text("eval:\n  threads: 1\n  baseline_max_iters: 20\n")
    return path


def make_bag(scans, path: Path) -> Path:
    write_rosbag(scans, path, chunk_size=CHUNK)
    return path / f"{path.name}.mcap"


def chunk_layout(mcap: Path) -> list[tuple[int, int, list[tuple[str, int]]]]:
    """[(start, length, [(topic, log_time), ...]), ...] of every chunk, read through the intact index."""
    from mcap.reader import SeekingReader
    from mcap.records import Chunk, Message
    from mcap.stream_reader import breakup_chunk

    with open(mcap, "rb") as f:
        summary = SeekingReader(f).get_summary()
        out = []
        for ci in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
            from mcap.data_stream import ReadDataStream

            f.seek(ci.chunk_start_offset + 9)
            chunk = Chunk.read(ReadDataStream(f))
            msgs = [(summary.channels[r.channel_id].topic, r.log_time) for r in breakup_chunk(chunk)
                    if isinstance(r, Message)]
            out.append((ci.chunk_start_offset, ci.chunk_length, msgs))
    return out


def footer(mcap: Path) -> tuple[int, int, int]:
    """(summary_start, summary_offset_start, summary_crc) of the footer."""
    data = mcap.read_bytes()
    return struct.unpack("<QQI", data[-8 - 20 : -8])


def zero(path: Path, offset: int, n: int) -> None:
    data = bytearray(path.read_bytes())
    data[offset : offset + n] = bytes(len(data[offset : offset + n]))
    path.write_bytes(bytes(data))


def run_replay(src: Path, out: Path, capsys, *extra: str) -> tuple[int, list[str], dict | None]:
    rc = replay_main([str(src), "--mode", "odometry", "--method", "gicp", "--out", str(out), "--quiet",
                      "--no-bag", *extra])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    metrics = out / "latest" / "metrics.json"
    return rc, err, (json.loads(metrics.read_text()) if metrics.exists() else None)


def frame_stamps(out: Path) -> list[int]:
    lines = (out / "latest" / "frames.csv").read_text().splitlines()[1:]
    return [int(line.split(",")[2]) for line in lines]


# ------------------------------------------------------------------------------------------- CRCs
def _crcs(mcap: Path) -> tuple[list[int], int, int]:
    from mcap.records import Chunk, DataEnd, Footer
    from mcap.stream_reader import StreamReader

    chunks, data_crc, summary_crc = [], None, None
    with open(mcap, "rb") as f:
        for r in StreamReader(f, emit_chunks=True, validate_crcs=True).records:
            if isinstance(r, Chunk):
                chunks.append(r.uncompressed_crc)
            elif isinstance(r, DataEnd):
                data_crc = r.data_section_crc
            elif isinstance(r, Footer):
                summary_crc = r.summary_crc
    return chunks, data_crc, summary_crc


def test_every_written_mcap_carries_crcs(scans, tmp_path, fast_config, capsys):
    """write_scans, deepbbs-bag convert (copy and --repack) and the results bag: every chunk CRC, the
    data-section CRC and the summary CRC are set (and valid: StreamReader validates them)."""
    written = [make_bag(scans, tmp_path / "a")]
    assert bag_main(["convert", str(tmp_path / "a"), str(tmp_path / "b")]) == 0
    assert bag_main(["convert", str(tmp_path / "a"), str(tmp_path / "c"), "--repack"]) == 0
    written += [tmp_path / "b" / "b.mcap", tmp_path / "c" / "c.mcap"]
    rc = replay_main([str(tmp_path / "a"), "--method", "gicp", "--stride", "2", "--config", str(fast_config),
                      "--out", str(tmp_path / "out"), "--quiet", "--no-plots"])
    assert rc == 0
    written += list((tmp_path / "out" / "latest" / "results_bag").glob("*.mcap"))
    assert len(written) == 4
    for mcap in written:
        chunks, data_crc, summary_crc = _crcs(mcap)
        assert chunks and all(chunks) and data_crc and summary_crc, mcap


def test_committed_sample_bags_carry_crcs():
    bags = sorted((Path(__file__).resolve().parents[1] / "bags").glob("*/*.mcap"))
    assert len(bags) == 2
    for mcap in bags:
        chunks, data_crc, summary_crc = _crcs(mcap)
        assert chunks and all(chunks) and data_crc and summary_crc, mcap
        source = open_source(mcap.parent)  # read through the summary's index: nothing to warn about
        assert source.warnings == [] and len(source) == 15


# ----------------------------------------------------------------------------- damaged bags (reader)
def _damage(kind: str, mcap: Path) -> None:
    layout = chunk_layout(mcap)
    start, length, _ = layout[len(layout) // 2]
    size = mcap.stat().st_size
    if kind == "cut_mid":
        mcap.write_bytes(mcap.read_bytes()[: start + length // 2])
    elif kind == "cut_before_summary":
        mcap.write_bytes(mcap.read_bytes()[: footer(mcap)[0]])
    elif kind == "cut_in_header":
        mcap.write_bytes(mcap.read_bytes()[:30])
    elif kind == "zeroed_mid_chunk":
        zero(mcap, start + length // 2, 4096)
    elif kind == "chunk_crc_mismatch":  # the chunk decompresses fine, its data does not match its CRC
        data = bytearray(mcap.read_bytes())
        data[start + 9 + 24] ^= 0x01  # uncompressed_crc field of the chunk record
        mcap.write_bytes(bytes(data))
    elif kind == "zeroed_summary":
        zero(mcap, footer(mcap)[0], 4096)
    elif kind == "zeroed_footer":
        zero(mcap, size - 28, 20)
    else:  # pragma: no cover
        raise AssertionError(kind)


def _lost_in_middle_chunk(mcap: Path, scans) -> set[int]:
    """Stamps of the scans a damaged middle chunk costs: its clouds and the scans whose pose it holds."""
    layout = chunk_layout(mcap)
    return {t for _topic, t in layout[len(layout) // 2][2]}


@pytest.mark.parametrize(
    "kind, outcome",
    [
        ("cut_mid", "prefix"),  # truncation: every scan before the cut, then the fault
        ("cut_before_summary", "all_warned"),  # the data section is whole: every scan, a warning
        ("cut_in_header", "error"),  # nothing readable: one error
        ("zeroed_mid_chunk", "skip_chunk"),  # a bad chunk costs its own frames, not those around it
        ("chunk_crc_mismatch", "skip_chunk"),
        ("zeroed_summary", "all_warned"),  # rosbags' read_index raised MemoryError here
        ("zeroed_footer", "all_warned"),
    ],
)
def test_damaged_bag_reader(kind, outcome, scans, tmp_path):
    mcap = make_bag(scans, tmp_path / "bag")
    lost = _lost_in_middle_chunk(mcap, scans)
    _damage(kind, mcap)
    stamps = [s.stamp_ns for s in scans]
    if outcome == "error":
        with pytest.raises(DatasetError, match=r"bag\.mcap"):
            list(open_source(tmp_path / "bag"))
        return
    if outcome == "skip_chunk":  # the index is intact: read through it, nothing to warn about
        assert open_source(tmp_path / "bag").warnings == []
    source = open_source(tmp_path / "bag", lenient=True)
    back = list(source)
    got = [s.stamp_ns for s in back]
    for s in back:  # whatever comes back is exactly what was written
        i = stamps.index(s.stamp_ns)
        np.testing.assert_array_equal(s.points, scans[i].points)
        np.testing.assert_allclose(s.T_world_lidar, scans[i].T_world_lidar, atol=1e-12)
    if outcome == "all_warned":
        assert got == stamps and source.errors == []
        assert len(source.warnings) == 1 and "read from the start" in source.warnings[0]
    elif outcome == "prefix":
        assert 1 <= len(got) < N and got == stamps[: len(got)]
        assert len(source.errors) == 1 and "truncated or corrupt at byte" in source.errors[0]
    else:
        assert lost and got == [t for t in stamps if t not in lost], (got, lost)
        assert len(source.errors) == 1
        assert "damaged chunk at bytes" in source.errors[0] and "skipped, reading went on" in source.errors[0]
        if kind == "chunk_crc_mismatch":
            assert "crc" in source.errors[0].lower()
        with pytest.raises(DatasetError, match="damaged chunk at bytes"):  # strict: the same damage raises
            list(open_source(tmp_path / "bag"))


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.floats(0.0, 1.0), zero_at=st.floats(0.0, 1.0), zero_len=st.integers(1, 20_000),
       mode=st.sampled_from(["cut", "zero"]), storage=st.sampled_from(["mcap", "sqlite3"]))
def test_any_damage_gives_original_scans_or_a_clear_error(tmp_path_factory, scans, cut, zero_at, zero_len, mode,
                                                          storage):
    """Truncation anywhere or zeroed bytes anywhere (mcap and sqlite3 rosbag2): opening and reading
    (lenient) raise nothing but a DatasetError; with mcap every scan that comes back is one that was
    written (the CRCs catch the rest; sqlite3 has no checksum of its payloads)."""
    path = tmp_path_factory.mktemp("h") / "bag"
    write_rosbag(scans[:4], path, storage=storage, chunk_size=CHUNK)
    mcap = next(path.glob("*.mcap" if storage == "mcap" else "*.db3"))
    data = mcap.read_bytes()
    if mode == "cut":
        mcap.write_bytes(data[: int(cut * len(data))])
    else:
        zero(mcap, int(zero_at * len(data)), zero_len)
    stamps = [s.stamp_ns for s in scans[:4]]
    try:
        source = open_source(path, lenient=True)
        back = list(source)
    except DatasetError as err:
        assert "bag" in str(err)
        return
    for s in back if storage == "mcap" else []:
        i = stamps.index(s.stamp_ns)
        np.testing.assert_array_equal(s.points, scans[i].points)
    if len(back) < 4 and (storage == "mcap" or mode == "cut"):
        assert source.errors, "scans went missing without a word"


def test_zero_quaternion_ground_truth_in_a_bag(scans, tmp_path):
    """A ground-truth PoseStamped with a zero quaternion ends the readable part with a clear error."""
    from rosbags.typesys import Stores, get_typestore

    from deepbbs_ros.datasets.rosbag import rosbag2_writer
    from msg_adapters.pointcloud2 import arrays_to_pointcloud2
    from msg_adapters.transforms import matrix_to_pose_stamped

    ts = get_typestore(Stores.ROS2_JAZZY)
    with rosbag2_writer(tmp_path / "bag") as w:
        cc = w.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=ts)
        gc = w.add_connection("/ground_truth/pose", "geometry_msgs/msg/PoseStamped", typestore=ts)
        for k, s in enumerate(scans[:5]):
            w.write(cc, s.stamp_ns, ts.serialize_cdr(arrays_to_pointcloud2(
                s.points, stamp_ns=s.stamp_ns, frame_id="lidar", flavor="rosbags"), "sensor_msgs/msg/PointCloud2"))
            pose = matrix_to_pose_stamped(s.T_world_lidar, s.stamp_ns, "world", flavor="rosbags")
            if k == 3:
                pose.pose.orientation.x = pose.pose.orientation.y = pose.pose.orientation.z = 0.0
                pose.pose.orientation.w = 0.0
            w.write(gc, s.stamp_ns, ts.serialize_cdr(pose, "geometry_msgs/msg/PoseStamped"))
    source = open_source(tmp_path / "bag", lenient=True)
    assert [s.stamp_ns for s in source] == [s.stamp_ns for s in scans[:3]]
    assert len(source.errors) == 1 and "ground-truth message 3" in source.errors[0]


# ------------------------------------------------------------------------------------ end to end (CLI)
def test_replay_bad_chunk_in_the_middle_keeps_the_frames_around_it(scans, tmp_path, fast_config, capsys):
    mcap = make_bag(scans, tmp_path / "bag")
    lost = _lost_in_middle_chunk(mcap, scans)
    _damage("zeroed_mid_chunk", mcap)
    rc, err, doc = run_replay(tmp_path / "bag", tmp_path / "out", capsys, "--config", str(fast_config))
    assert rc == 1 and len(err) == 1 and err[0].startswith("deepbbs-replay: error: recording fault after")
    assert "damaged chunk at bytes" in err[0] and "Traceback" not in err[0]
    assert doc["complete"] is False and len(doc["errors"]) == 1
    assert frame_stamps(tmp_path / "out") == [s.stamp_ns for s in scans if s.stamp_ns not in lost]


@pytest.mark.parametrize("cut", [0.05, 0.4])
def test_replay_truncated_bag_with_plots(scans, tmp_path, fast_config, capsys, cut):
    """Cut before the first pair completes (the plots used to die on an empty log axis) or mid-way:
    one error line, exit 1, complete false, and the plots and metrics are written."""
    mcap = make_bag(scans, tmp_path / "bag")
    mcap.write_bytes(mcap.read_bytes()[: int(cut * mcap.stat().st_size)])
    rc = replay_main([str(tmp_path / "bag"), "--method", "gicp", "--stride", "1", "--max-dist", "3",
                      "--config", str(fast_config), "--out", str(tmp_path / "out"), "--quiet"])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    if cut < 0.1:  # not one scan could be read
        assert rc == 1 and len(err) == 1 and "deepbbs-replay: error:" in err[0]
        return
    assert rc == 1 and len(err) == 1 and "truncated or corrupt" in err[0]
    run = (tmp_path / "out" / "latest").resolve()
    doc = json.loads((run / "metrics.json").read_text())
    assert doc["complete"] is False and len(doc["warnings"]) == 1 and "no footer" in doc["warnings"][0]
    assert {p.name for p in run.glob("*.png")} == {"errors_cdf.png", "errors_hist.png", "errors_over_pairs.png"}
    assert (run / "results_bag").is_dir()


def _apollo(scans, path: Path) -> Path:
    write_scans(scans, path, "apollo")
    return path


def _pcd_damage(kind: str, folder: Path) -> None:
    f = folder / "pcds" / "4.pcd"
    raw = f.read_bytes()
    if kind == "all_nan":
        i = raw.index(b"DATA binary\n") + len(b"DATA binary\n")
        f.write_bytes(raw[:i] + np.full((len(raw) - i) // 4, np.nan, "<f4").tobytes())
    elif kind == "says_binary_compressed":
        f.write_bytes(raw.replace(b"DATA binary\n", b"DATA binary_compressed\n"))
    elif kind == "body_cut_short":
        f.write_bytes(raw[: len(raw) // 2])
    elif kind == "empty_file":
        f.write_bytes(b"")
    elif kind == "no_points":
        write_pcd(f, {"points": np.zeros((0, 3), np.float32)})


@pytest.mark.parametrize("kind", ["all_nan", "says_binary_compressed", "body_cut_short", "empty_file", "no_points"])
def test_damaged_pcd_costs_its_own_frame(kind, scans, tmp_path, fast_config, capsys):
    folder = _apollo(scans, tmp_path / "apollo")
    _pcd_damage(kind, folder)
    rc, err, doc = run_replay(folder, tmp_path / "out", capsys, "--config", str(fast_config))
    assert rc == 1 and len(err) == 1
    assert err[0].startswith("deepbbs-replay: error: recording fault after 3 frames:") and "4.pcd" in err[0]
    assert doc["complete"] is False and doc["methods"]["gicp"]["frames"] == N - 1
    assert frame_stamps(tmp_path / "out") == [s.stamp_ns for k, s in enumerate(scans) if k != 3]


@pytest.mark.parametrize("kind, frames", [("zero_quaternion", 2), ("cut_mid_line", 2), ("nan_value", 2)])
def test_damaged_pose_file_keeps_the_frames_before(kind, frames, scans, tmp_path, fast_config, capsys):
    folder = _apollo(scans, tmp_path / "apollo")
    f = folder / "poses" / "gt_poses.txt"
    lines = f.read_text().splitlines()
    parts = lines[2].split()
    if kind == "zero_quaternion":
        parts[5:9] = ["0", "0", "0", "0"]
        lines[2] = " ".join(parts)
    elif kind == "nan_value":
        parts[3] = "nan"
        lines[2] = " ".join(parts)
    else:
        lines = [*lines[:2], lines[2][: len(lines[2]) // 2]]
    f.write_text("\n".join(lines) + "\n")
    rc, err, doc = run_replay(folder, tmp_path / "out", capsys, "--config", str(fast_config))
    assert rc == 1 and len(err) == 1 and "gt_poses.txt: line 3: malformed pose line" in err[0]
    assert err[0].startswith(f"deepbbs-replay: error: recording fault after {frames} frames")
    assert doc["complete"] is False and doc["methods"]["gicp"]["frames"] == frames


def test_kitti_bin_cut_short_costs_its_own_frame(scans, tmp_path, fast_config, capsys):
    write_scans(scans, tmp_path / "kitti", "kitti")
    f = tmp_path / "kitti" / "velodyne" / "000002.bin"
    f.write_bytes(f.read_bytes()[:1001])
    rc, err, doc = run_replay(tmp_path / "kitti", tmp_path / "out", capsys, "--config", str(fast_config))
    assert rc == 1 and len(err) == 1 and "000002.bin: size 1001 bytes is not a multiple of 16" in err[0]
    assert doc["complete"] is False and doc["methods"]["gicp"]["frames"] == N - 1


# ------------------------------------------------------------------------------------- deepbbs-bag
def test_info_reports_what_it_read_and_where_metadata_disagrees(scans, tmp_path, capsys):
    make_bag(scans, tmp_path / "bag")
    meta = tmp_path / "bag" / "metadata.yaml"
    meta.write_text(meta.read_text().replace(f"message_count: {N}\n", f"message_count: {2 * N}\n"))
    assert bag_main(["info", str(tmp_path / "bag"), "--json"]) == 0
    out, err = capsys.readouterr()
    info = json.loads(out)
    assert info["frames"] == N and {t["count"] for t in info["topics"]} == {N}
    assert info["metadata_counts"] == {"/apollo/sensor/velodyne64/compensator/PointCloud2": 2 * N,
                                       "/ground_truth/pose": 2 * N}
    assert err.count("\n") == 1 and "metadata.yaml disagrees with what was read" in err


def test_info_on_a_damaged_bag_counts_around_the_damage(scans, tmp_path, capsys):
    mcap = make_bag(scans, tmp_path / "bag")
    layout = chunk_layout(mcap)
    in_chunk = [topic for topic, _t in layout[len(layout) // 2][2]]
    _damage("zeroed_mid_chunk", mcap)
    assert bag_main(["info", str(tmp_path / "bag"), "--json"]) == 0
    out, err = capsys.readouterr()
    info = json.loads(out)
    assert "damaged chunk at bytes" in info["damage"] and "damaged recording" in err
    counts = {t["topic"]: t["count"] for t in info["topics"]}  # what was read: all but the chunk's messages
    assert counts == {topic: N - in_chunk.count(topic) for topic in counts} and info["frames"] < N


def test_convert_a_damaged_bag(scans, tmp_path, capsys):
    mcap = make_bag(scans, tmp_path / "bag")
    _damage("zeroed_mid_chunk", mcap)
    assert bag_main(["convert", str(tmp_path / "bag"), str(tmp_path / "strict")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "damaged chunk at bytes" in err[0]
    assert bag_main(["convert", str(tmp_path / "bag"), str(tmp_path / "lenient"), "--lenient"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "frames before it written" in err[0]
    copy = open_source(tmp_path / "lenient", lenient=True)  # the copy holds what was readable, as recorded
    back = list(copy)
    assert 1 <= len(back) < N


def test_info_checks_the_data_section_crc(scans, tmp_path, capsys):
    """Damage outside the chunks (a message index record) passes every chunk CRC: info still finds it
    through the data-section CRC; the scans themselves read fine."""
    mcap = make_bag(scans, tmp_path / "bag")
    start, length, _ = chunk_layout(mcap)[1]
    data = bytearray(mcap.read_bytes())
    data[start + length + 9 + 2 + 4 + 3] ^= 0xFF  # inside the message index after chunk 1
    mcap.write_bytes(bytes(data))
    assert len(list(open_source(tmp_path / "bag"))) == N
    assert bag_main(["info", str(tmp_path / "bag"), "--json"]) == 0
    out, err = capsys.readouterr()
    assert "data section CRC mismatch" in json.loads(out)["damage"] and "damaged recording" in err
