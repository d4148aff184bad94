"""PointCloud2 <-> numpy: real driver layouts, malformed messages, encoder, property round trips.

Messages in driver layouts come from msg_adapters.layouts.build_cloud, which writes the bytes with its
own structured dtype (padding filled with 0xAB), or from struct.pack; never from the encoder under test.
"""

from __future__ import annotations

import array
import struct

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from deepbbs_ros.errors import PointCloudFormatError
from msg_adapters.layouts import FLOAT64_XYZ, HESAI, LIVOX, OUSTER, VELODYNE, build_cloud
from msg_adapters.pointcloud2 import (
    CloudArrays,
    arrays_to_pointcloud2,
    field_names,
    pointcloud2_to_arrays,
    pointcloud2_to_xyz,
)

FLAVORS = ("rclpy", "rosbags")
STAMP_NS = 1_700_000_000_123_456_789


def _typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def _points(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3) float64 points 1-80 m from the origin."""
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(1.0, 80.0, (n, 1))


def _cdr_roundtrip(msg):
    """Serialize a rosbags message to CDR and back, as a bag reader would hand it over."""
    ts = _typestore()
    return ts.deserialize_cdr(ts.serialize_cdr(msg, msg.__msgtype__), msg.__msgtype__)


# --------------------------------------------------------------------------------------------------
# module hygiene
# --------------------------------------------------------------------------------------------------


def test_package_imports_no_ros_at_module_level():
    import subprocess
    import sys

    code = (
        "import sys, msg_adapters, msg_adapters.pointcloud2, msg_adapters.transforms, msg_adapters.layouts;"
        "bad = [m for m in ('rclpy', 'rosbags', 'sensor_msgs', 'geometry_msgs') if m in sys.modules];"
        "print(bad); sys.exit(1 if bad else 0)"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr


# --------------------------------------------------------------------------------------------------
# real driver layouts
# --------------------------------------------------------------------------------------------------


def test_velodyne_bytes_written_by_struct_pack():
    """Velodyne PointXYZIRT, packed point_step 22, built byte by byte (independent of numpy layouts)."""
    from builtin_interfaces.msg import Time
    from sensor_msgs.msg import PointCloud2, PointField
    from std_msgs.msg import Header

    pts = [
        (1.5, -2.25, 0.5, 17.0, 3, 0.001),
        (float("nan"), 0.0, 0.0, 1.0, 4, 0.002),
        (10.0, 20.0, -1.0, 99.5, 63, 0.099),
    ]
    data = b"".join(struct.pack("<ffffHf", *p) for p in pts)
    assert len(data) == 22 * 3
    fields = [PointField(name=n, offset=o, datatype=d, count=c) for n, o, d, c in VELODYNE[0]]
    msg = PointCloud2(
        header=Header(stamp=Time(sec=12, nanosec=5), frame_id="velodyne"),
        height=1,
        width=3,
        fields=fields,
        is_bigendian=False,
        point_step=22,
        row_step=66,
        data=data,
        is_dense=False,
    )
    cloud = pointcloud2_to_arrays(msg, ("intensity", "ring", "time"))
    np.testing.assert_array_equal(cloud.xyz, np.float32([[1.5, -2.25, 0.5], [10.0, 20.0, -1.0]]))
    np.testing.assert_array_equal(cloud.fields["intensity"], np.float32([17.0, 99.5]))
    np.testing.assert_array_equal(cloud.fields["ring"], np.uint16([3, 63]))
    np.testing.assert_array_equal(cloud.fields["time"], np.float32([0.001, 0.099]))
    assert cloud.fields["ring"].dtype == np.uint16 and cloud.xyz.dtype == np.float32
    assert (cloud.stamp_ns, cloud.frame_id, len(cloud)) == (12_000_000_005, "velodyne", 2)
    np.testing.assert_array_equal(cloud.mask, [True, False, True])


@pytest.mark.parametrize("flavor", FLAVORS)
@pytest.mark.parametrize("bigendian", [False, True])
def test_velodyne_layout(rng, flavor, bigendian):
    n = 300
    xyz = _points(rng, n)
    xyz[[5, 6]] = np.nan
    xyz[7] = np.inf
    xyz[8] = 0.0
    xyz[9] = [0.0, 0.0, 5e-4]  # closer than min_range 1e-3
    values = {
        "x": xyz[:, 0],
        "y": xyz[:, 1],
        "z": xyz[:, 2],
        "intensity": rng.uniform(0, 255, n),
        "ring": rng.integers(0, 64, n),
        "time": rng.uniform(0, 0.1, n),
    }
    msg = build_cloud(VELODYNE, values, is_bigendian=bigendian, flavor=flavor, stamp_ns=STAMP_NS, frame_id="velodyne")
    assert msg.point_step == 22
    cloud = pointcloud2_to_arrays(msg, ["intensity", "ring", "time"])
    keep = np.ones(n, bool)
    keep[[5, 6, 7, 8, 9]] = False
    np.testing.assert_array_equal(cloud.mask, keep)
    np.testing.assert_array_equal(cloud.xyz, xyz[keep].astype(np.float32))
    np.testing.assert_array_equal(cloud.fields["intensity"], values["intensity"][keep].astype(np.float32))
    np.testing.assert_array_equal(cloud.fields["ring"], values["ring"][keep].astype(np.uint16))
    np.testing.assert_array_equal(cloud.fields["time"], values["time"][keep].astype(np.float32))
    buffer = np.frombuffer(msg.data, np.uint8)
    for arr in (cloud.xyz, *cloud.fields.values()):
        assert arr.dtype.isnative and arr.flags.c_contiguous and not np.shares_memory(arr, buffer)
    assert cloud.stamp_ns == STAMP_NS and cloud.frame_id == "velodyne"
    np.testing.assert_array_equal(pointcloud2_to_xyz(msg), cloud.xyz)
    # min_range <= 0 keeps the near-origin points but still drops NaN/Inf
    assert len(pointcloud2_to_arrays(msg, min_range=0.0)) == n - 3


@pytest.mark.parametrize("flavor", FLAVORS)
def test_ouster_organised_with_nan_and_zero_rows(rng, flavor):
    height, width = 16, 64
    n = height * width
    xyz = _points(rng, n)
    xyz[3 * width : 4 * width] = np.nan  # a NaN row
    xyz[9 * width : 10 * width] = 0.0  # a no-return row (ouster-ros writes zeros)
    values = {
        "x": xyz[:, 0],
        "y": xyz[:, 1],
        "z": xyz[:, 2],
        "intensity": rng.uniform(0, 3000, n),
        "t": np.tile(np.arange(width, dtype=np.uint32) * 781250, height),
        "reflectivity": rng.integers(0, 65535, n),
        "ring": np.repeat(np.arange(height), width),
        "ambient": rng.integers(0, 65535, n),
        "range": rng.integers(0, 2**32 - 1, n, dtype=np.uint32),
    }
    msg = build_cloud(OUSTER, values, height=height, width=width, flavor=flavor)
    assert (msg.point_step, msg.height, msg.width) == (48, height, width)
    names = ("intensity", "t", "reflectivity", "ring", "ambient", "range")

    # every raw pixel, row-major (height, width)
    full = pointcloud2_to_arrays(msg, names, remove_invalid=False)
    assert (full.height, full.width) == (height, width)
    grid = full.xyz.reshape(height, width, 3)
    np.testing.assert_array_equal(grid, xyz.astype(np.float32).reshape(height, width, 3))
    np.testing.assert_array_equal(full.fields["ring"].reshape(height, width)[:, 0], np.arange(height))
    assert full.mask.all()

    # valid pixels only: one mask for every array
    cloud = pointcloud2_to_arrays(msg, names)
    keep = np.ones(n, bool)
    keep[3 * width : 4 * width] = False
    keep[9 * width : 10 * width] = False
    assert len(cloud) == n - 2 * width
    np.testing.assert_array_equal(cloud.mask, keep)
    np.testing.assert_array_equal(cloud.xyz, xyz[keep].astype(np.float32))
    expected_dtypes = {
        "intensity": np.float32,
        "t": np.uint32,
        "reflectivity": np.uint16,
        "ring": np.uint16,
        "ambient": np.uint16,
        "range": np.uint32,
    }
    for name in names:
        assert cloud.fields[name].dtype == expected_dtypes[name], name
        np.testing.assert_array_equal(cloud.fields[name], values[name][keep].astype(expected_dtypes[name]))


@pytest.mark.parametrize("flavor", FLAVORS)
@pytest.mark.parametrize("layout", [LIVOX, HESAI], ids=["livox", "hesai"])
def test_float64_timestamp_at_unaligned_offset_18(rng, flavor, layout):
    n = 257
    xyz = _points(rng, n)
    stamps = 1_700_000_000.0 + np.arange(n) * 1e-6 + rng.uniform(0, 1e-7, n)  # needs float64
    values = {
        "x": xyz[:, 0],
        "y": xyz[:, 1],
        "z": xyz[:, 2],
        "intensity": rng.uniform(0, 255, n),
        "timestamp": stamps,
        "tag": rng.integers(0, 255, n),
        "line": rng.integers(0, 6, n),
        "ring": rng.integers(0, 128, n),
    }
    msg = build_cloud(layout, values, flavor=flavor)
    assert msg.point_step == 26 and dict((f.name, f.offset) for f in msg.fields)["timestamp"] == 18
    extra = ("tag", "line") if layout is LIVOX else ("ring",)
    cloud = pointcloud2_to_arrays(msg, ("timestamp", "intensity", *extra))
    assert cloud.fields["timestamp"].dtype == np.float64
    np.testing.assert_array_equal(cloud.fields["timestamp"], stamps)
    np.testing.assert_array_equal(cloud.xyz, xyz.astype(np.float32))
    for name in extra:
        np.testing.assert_array_equal(cloud.fields[name], values[name].astype(cloud.fields[name].dtype))


@pytest.mark.parametrize("flavor", FLAVORS)
@pytest.mark.parametrize("bigendian", [False, True])
def test_float64_xyz(rng, flavor, bigendian):
    n = 100
    xyz = _points(rng, n) + 1e-9  # digits float32 cannot hold
    xyz[4] = np.nan
    msg = build_cloud(
        FLOAT64_XYZ,
        {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "intensity": np.arange(n)},
        is_bigendian=bigendian,
        flavor=flavor,
    )
    cloud = pointcloud2_to_arrays(msg, ["intensity"])
    keep = np.arange(n) != 4
    assert cloud.xyz.dtype == np.float32
    np.testing.assert_array_equal(cloud.xyz, xyz[keep].astype(np.float32))
    np.testing.assert_array_equal(cloud.fields["intensity"], np.arange(n)[keep].astype(np.float32))


@pytest.mark.parametrize("flavor", FLAVORS)
def test_row_step_padding_and_count_greater_than_one(rng, flavor):
    layout = (
        (("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("normal", 12, 7, 3), ("rgba", 24, 2, 4), ("label", 28, 5, 1)),
        36,
    )
    height, width = 4, 10
    n = height * width
    xyz = _points(rng, n)
    normal = rng.normal(size=(n, 3))
    rgba = rng.integers(0, 255, (n, 4))
    label = rng.integers(-1000, 1000, n)
    values = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "normal": normal, "rgba": rgba, "label": label}
    msg = build_cloud(layout, values, height=height, width=width, row_padding=13, flavor=flavor)
    assert msg.row_step == width * 36 + 13
    cloud = pointcloud2_to_arrays(msg, ["normal", "rgba", "label"])
    np.testing.assert_array_equal(cloud.xyz, xyz.astype(np.float32))
    assert cloud.fields["normal"].shape == (n, 3) and cloud.fields["rgba"].shape == (n, 4)
    np.testing.assert_array_equal(cloud.fields["normal"], normal.astype(np.float32))
    np.testing.assert_array_equal(cloud.fields["rgba"], rgba.astype(np.uint8))
    np.testing.assert_array_equal(cloud.fields["label"], label.astype(np.int32))


def test_unaligned_rosbags_buffer(rng):
    """A deserialized rosbags message's data can start at any address; the decoder must not care."""
    n = 50
    xyz = _points(rng, n)
    msg = build_cloud(OUSTER, {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]}, flavor="rosbags")
    shifted = np.empty(msg.data.size + 1, np.uint8)[1:]
    shifted[:] = msg.data
    assert shifted.ctypes.data % 4 != 0
    msg.data = shifted
    np.testing.assert_array_equal(pointcloud2_to_xyz(msg), xyz.astype(np.float32))
    np.testing.assert_array_equal(pointcloud2_to_xyz(_cdr_roundtrip(msg)), xyz.astype(np.float32))


@pytest.mark.parametrize("flavor", FLAVORS)
@pytest.mark.parametrize("height,width", [(1, 0), (0, 0), (0, 5)])
def test_empty_cloud(flavor, height, width):
    msg = build_cloud(VELODYNE, {}, height=height, width=width, flavor=flavor)
    cloud = pointcloud2_to_arrays(msg, ["intensity", "ring"])
    assert isinstance(cloud, CloudArrays)
    assert cloud.xyz.shape == (0, 3) and cloud.xyz.dtype == np.float32
    assert cloud.fields["ring"].shape == (0,) and cloud.fields["ring"].dtype == np.uint16
    assert pointcloud2_to_xyz(msg).shape == (0, 3)


def test_all_invalid_cloud():
    xyz = np.full((10, 3), np.nan)
    msg = build_cloud(VELODYNE, {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]})
    cloud = pointcloud2_to_arrays(msg, ["ring"])
    assert cloud.xyz.shape == (0, 3) and cloud.fields["ring"].shape == (0,)


def test_outputs_do_not_alias_the_message(rng):
    xyz = _points(rng, 20)
    msg = build_cloud(OUSTER, {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]})
    before = bytes(msg.data)
    cloud = pointcloud2_to_arrays(msg, ["intensity"], remove_invalid=False)
    cloud.xyz[:] = 0
    cloud.fields["intensity"][:] = 1
    assert bytes(msg.data) == before


def test_data_as_bytes_and_list():
    """Hand-built messages sometimes hold bytes or a list of ints in data."""
    xyz = np.float32([[1, 2, 3], [4, 5, 6]])
    msg = arrays_to_pointcloud2(xyz, flavor="rosbags")
    raw = bytes(msg.data)
    msg.data = raw
    np.testing.assert_array_equal(pointcloud2_to_xyz(msg), xyz)
    msg.data = list(raw)
    np.testing.assert_array_equal(pointcloud2_to_xyz(msg), xyz)


# --------------------------------------------------------------------------------------------------
# malformed input
# --------------------------------------------------------------------------------------------------


def _good(flavor="rclpy"):
    xyz = np.arange(12, dtype=np.float64).reshape(4, 3) + 1
    return build_cloud(VELODYNE, {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]}, height=2, width=2, flavor=flavor)


def _fields(msg, flavor, spec):
    if flavor == "rclpy":
        from sensor_msgs.msg import PointField
    else:
        PointField = _typestore().types["sensor_msgs/msg/PointField"]
    return [PointField(name=n, offset=o, datatype=d, count=c) for n, o, d, c in spec]


@pytest.mark.parametrize("flavor", FLAVORS)
@pytest.mark.parametrize(
    "mutate,match",
    [
        (lambda m, f: setattr(m, "fields", _fields(m, f, [("x", 0, 7, 1), ("y", 4, 7, 1)])), r"no z field"),
        (lambda m, f: setattr(m, "fields", _fields(m, f, [("a", 0, 7, 1)])), r"no x/y/z field"),
        (lambda m, f: setattr(m, "fields", []), r"no x/y/z field \(fields: none\)"),
        (lambda m, f: setattr(m, "row_step", m.row_step + 2), r"data length 88 != row_step\*height"),
        (lambda m, f: setattr(m, "data", m.data[:-1]), r"data length 87 != row_step\*height = 44\*2 = 88"),
        (lambda m, f: setattr(m, "height", 3), r"data holds 2 rows, so width\*height does not match"),
        (lambda m, f: setattr(m, "width", 0), r"width\*height mismatch: width 0 x height 2 = 0 points"),
        (lambda m, f: setattr(m, "height", 0), r"width\*height mismatch"),
        (lambda m, f: setattr(m, "row_step", 40), r"row_step 40 < width\*point_step = 2\*22 = 44"),
        (lambda m, f: setattr(m, "point_step", 20), r"field 'time' \(offset 18, 1 x 4 bytes\) runs past point_step 20"),
        (
            lambda m, f: setattr(m, "fields", _fields(m, f, [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 3)])),
            r"coordinate field 'z' has count 3; expected 1",
        ),
        (
            lambda m, f: setattr(m, "fields", _fields(m, f, [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 9, 1)])),
            r"field 'z' has unknown datatype 9",
        ),
        (
            lambda m, f: setattr(m, "fields", _fields(m, f, [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 0, 1)])),
            r"field 'z' has unknown datatype 0",
        ),
        (
            lambda m, f: setattr(m, "fields", _fields(m, f, [("x", 0, 7, 2), ("y", 8, 7, 1), ("z", 12, 7, 1)])),
            r"coordinate field 'x' has count 2",
        ),
        (
            lambda m, f: setattr(
                m, "fields", _fields(m, f, [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("x", 12, 7, 1)])
            ),
            r"declares field 'x' twice",
        ),
    ],
)
def test_malformed_cloud_raises(flavor, mutate, match):
    msg = _good(flavor)
    pointcloud2_to_xyz(msg)  # the unmutated message decodes
    mutate(msg, flavor)
    with pytest.raises(PointCloudFormatError, match=match):
        pointcloud2_to_arrays(msg)


@pytest.mark.parametrize("flavor", FLAVORS)
@pytest.mark.parametrize(
    "sec,nanosec,match",
    [
        (2147483647, 4294967295, r"stamp nanosec=4294967295 is out of range \(must be 0 <= nanosec < 1000000000"),
        (5, 1_000_000_000, r"stamp nanosec=1000000000 is out of range"),
        (2**31, 0, r"stamp sec=2147483648 does not fit builtin_interfaces/Time \(int32 seconds\)"),
        (-(2**31) - 1, 0, r"stamp sec=-2147483649 does not fit"),
    ],
)
def test_stamp_that_does_not_fit_time_is_malformed(flavor, sec, nanosec, match):
    """A stamp the outputs could not carry (or whose nanosec would carry into another second) is refused
    at decoding, with the other malformed clouds; the largest valid stamp decodes exactly."""
    msg = _good(flavor)
    if flavor == "rclpy" and not (-(2**31) <= sec < 2**31):
        pytest.skip("rclpy's Time refuses this sec itself (int32 field)")
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    with pytest.raises(PointCloudFormatError, match=match):
        pointcloud2_to_arrays(msg)
    msg.header.stamp.sec, msg.header.stamp.nanosec = 2**31 - 1, 999_999_999
    assert pointcloud2_to_arrays(msg).stamp_ns == (2**31 - 1) * 10**9 + 999_999_999


def test_missing_requested_field_names_it():
    with pytest.raises(PointCloudFormatError, match=r"no field 'rgb' \(fields: x, y, z, intensity, ring, time\)"):
        pointcloud2_to_arrays(_good(), ["intensity", "rgb"])


def test_field_names():
    assert field_names(_good()) == ["x", "y", "z", "intensity", "ring", "time"]


# --------------------------------------------------------------------------------------------------
# encoder
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("flavor", FLAVORS)
def test_encode_layout_and_header(rng, flavor):
    xyz = _points(rng, 7).astype(np.float32)
    msg = arrays_to_pointcloud2(
        xyz,
        {"intensity": np.arange(7, dtype=np.float32), "ring": np.arange(7, dtype=np.uint16), "valid": np.ones(7, bool)},
        stamp_ns=STAMP_NS,
        frame_id="velodyne64",
        flavor=flavor,
    )
    assert [(f.name, f.offset, f.datatype, f.count) for f in msg.fields] == [
        ("x", 0, 7, 1),
        ("y", 4, 7, 1),
        ("z", 8, 7, 1),
        ("intensity", 12, 7, 1),
        ("ring", 16, 4, 1),
        ("valid", 18, 2, 1),
    ]
    assert (msg.height, msg.width, msg.point_step, msg.row_step, msg.is_bigendian) == (1, 7, 19, 133, False)
    assert msg.is_dense is True
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id) == (
        1_700_000_000,
        123_456_789,
        "velodyne64",
    )
    if flavor == "rclpy":
        from sensor_msgs.msg import PointCloud2

        assert isinstance(msg, PointCloud2) and isinstance(msg.data, array.array) and msg.data.typecode == "B"
    else:
        assert msg.__msgtype__ == "sensor_msgs/msg/PointCloud2" and msg.data.dtype == np.uint8
    # independent check of the bytes of point 3
    rec = bytes(msg.data)[3 * 19 : 4 * 19]
    assert struct.unpack("<ffffHB", rec) == (*xyz[3].tolist(), 3.0, 3, 1)


@pytest.mark.parametrize("flavor", FLAVORS)
def test_encode_organised_float64_and_not_dense(rng, flavor):
    xyz = _points(rng, 24).reshape(4, 6, 3)
    xyz[1, 2] = np.nan
    msg = arrays_to_pointcloud2(
        xyz, {"t": np.arange(24, dtype=np.uint32).reshape(4, 6)}, flavor=flavor, xyz_dtype=np.float64
    )
    assert (msg.height, msg.width, msg.point_step, msg.is_dense) == (4, 6, 28, False)
    assert [f.datatype for f in msg.fields[:3]] == [8, 8, 8]
    full = pointcloud2_to_arrays(msg, ["t"], remove_invalid=False)
    np.testing.assert_array_equal(full.xyz.reshape(4, 6, 3), xyz.astype(np.float32))
    np.testing.assert_array_equal(full.fields["t"], np.arange(24))
    assert len(pointcloud2_to_arrays(msg)) == 23


@pytest.mark.parametrize(
    "xyz,fields,kw,match",
    [
        (np.zeros((5, 2)), None, {}, r"xyz has shape \(5, 2\)"),
        (np.zeros(3), None, {}, r"xyz has shape \(3,\)"),
        (np.zeros((5, 3)), {"i": np.zeros(4)}, {}, r"field 'i' has shape \(4,\); expected \(5,\)"),
        (np.zeros((5, 3)), {"i": np.zeros(5, np.int64)}, {}, r"field 'i' has dtype int64"),
        (np.zeros((5, 3)), {"x": np.zeros(5)}, {}, r"field 'x' collides"),
        (np.zeros((5, 3)), None, {"flavor": "ros1"}, r"unknown message flavor 'ros1'"),
        (np.zeros((5, 3)), None, {"xyz_dtype": np.int32}, r"xyz_dtype must be float32 or float64"),
        (np.zeros((5, 3)), None, {"stamp_ns": 2**31 * 10**9}, r"does not fit builtin_interfaces/Time"),
    ],
)
def test_encode_errors(xyz, fields, kw, match):
    with pytest.raises(PointCloudFormatError, match=match):
        arrays_to_pointcloud2(xyz, fields, **kw)


# --------------------------------------------------------------------------------------------------
# property round trips
# --------------------------------------------------------------------------------------------------

_FIELD_DTYPES = [np.int8, np.uint8, np.int16, np.uint16, np.int32, np.uint32, np.float32, np.float64]
_coords = hnp.arrays(
    np.float32, st.tuples(st.integers(0, 40), st.just(3)), elements=st.floats(-1e4, 1e4, width=32, allow_nan=False)
)


@st.composite
def _clouds(draw):
    xyz = draw(_coords)
    n = xyz.shape[0]
    fields = {}
    for i in range(draw(st.integers(0, 3))):
        dtype = np.dtype(draw(st.sampled_from(_FIELD_DTYPES)))
        count = draw(st.integers(1, 3))
        shape = (n,) if count == 1 else (n, count)
        if dtype.kind == "f":
            elems = st.floats(width=8 * dtype.itemsize, allow_nan=False, allow_infinity=False)
        else:
            info = np.iinfo(dtype)
            elems = st.integers(int(info.min), int(info.max))
        fields[f"f{i}"] = draw(hnp.arrays(dtype, shape, elements=elems))
    stamp_ns = draw(st.integers(0, 2**31 * 10**9 - 1))
    return xyz, fields, stamp_ns


@settings(max_examples=40, deadline=None)
@given(cloud=_clouds(), flavor=st.sampled_from(FLAVORS))
def test_property_numpy_pointcloud2_numpy(cloud, flavor):
    xyz, fields, stamp_ns = cloud
    msg = arrays_to_pointcloud2(xyz, fields, stamp_ns=stamp_ns, frame_id="lidar", flavor=flavor)
    if flavor == "rosbags":
        msg = _cdr_roundtrip(msg)
    out = pointcloud2_to_arrays(msg, list(fields), remove_invalid=False)
    np.testing.assert_array_equal(out.xyz, xyz)
    assert out.stamp_ns == stamp_ns and out.frame_id == "lidar"
    for name, arr in fields.items():
        assert out.fields[name].dtype == arr.dtype and out.fields[name].shape == arr.shape
        np.testing.assert_array_equal(out.fields[name], arr)


@settings(max_examples=30, deadline=None)
@given(cloud=_clouds(), data=st.data())
def test_property_validity_mask_is_shared(cloud, data):
    xyz, fields, _ = cloud
    n = xyz.shape[0]
    norms = np.linalg.norm(xyz.astype(np.float64), axis=1)
    assume(not np.any((norms > 0.9e-3) & (norms < 1.1e-3)))  # float32 vs float64 rounding at the threshold
    bad = data.draw(hnp.arrays(np.int8, n, elements=st.integers(0, 3)))
    xyz = xyz.copy()
    xyz[bad == 1, 0] = np.nan
    xyz[bad == 2, 2] = -np.inf
    xyz[bad == 3] = 0.0
    fields["index"] = np.arange(n, dtype=np.uint32)
    out = pointcloud2_to_arrays(arrays_to_pointcloud2(xyz, fields), list(fields))
    keep = (bad == 0) & (np.linalg.norm(xyz.astype(np.float64), axis=1) >= 1e-3)
    np.testing.assert_array_equal(out.mask, keep)
    np.testing.assert_array_equal(out.fields["index"], np.flatnonzero(keep))
    np.testing.assert_array_equal(out.xyz, xyz[keep])
    for name, arr in fields.items():
        np.testing.assert_array_equal(out.fields[name], arr[keep])
