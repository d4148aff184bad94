"""PCD reading/writing: the three encodings, NaNs, COUNT > 1, padding fields, bad headers, LZF."""

from __future__ import annotations

import numpy as np
import pytest

from deepbbs_ros.datasets.pcd import lzf_compress, lzf_decompress, read_pcd, write_pcd
from deepbbs_ros.errors import DatasetError

ENCODINGS = ("ascii", "binary", "binary_compressed")


def _cloud(rng: np.random.Generator, n: int = 300) -> dict[str, np.ndarray]:
    xyz = (rng.normal(size=(n, 3)) * 30).astype(np.float32)
    xyz[[3, 17]] = np.nan  # Apollo scans hold NaN returns
    return {
        "points": xyz,
        "intensity": rng.uniform(0, 255, n).astype(np.float32),
        "ring": rng.integers(0, 64, n).astype(np.uint16),
        "normal": rng.normal(size=(n, 3)),  # float64, COUNT 3
    }


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_round_trip_every_encoding(tmp_path, rng, encoding):
    cloud = _cloud(rng)
    path = tmp_path / f"c_{encoding}.pcd"
    write_pcd(path, cloud, encoding)
    back = read_pcd(path)
    assert list(back) == ["x", "y", "z", "intensity", "ring", "normal"]
    xyz = np.stack([back["x"], back["y"], back["z"]], axis=1)
    assert xyz.dtype == np.float32 and back["ring"].dtype == np.uint16 and back["normal"].shape == (300, 3)
    np.testing.assert_array_equal(xyz, cloud["points"])  # NaN == NaN for assert_array_equal
    np.testing.assert_array_equal(back["intensity"], cloud["intensity"])
    np.testing.assert_array_equal(back["ring"], cloud["ring"])
    np.testing.assert_array_equal(back["normal"], cloud["normal"])
    assert np.isnan(back["x"][3]) and np.isnan(back["z"][17])


def test_reads_handwritten_pcl_style_ascii_with_padding_and_organised_cloud(tmp_path):
    text = (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z _ intensity\n"
        "SIZE 4 4 4 1 4\nTYPE F F F U F\nCOUNT 1 1 1 4 1\nWIDTH 2\nHEIGHT 2\n"
        "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 4\nDATA ascii\n"
        "1 2 3 0 0 0 0 10\nnan nan nan 0 0 0 0 0\n-1.5 0.25 4 0 0 0 0 7\n0 0 1e2 0 0 0 0 1\n"
    )
    (tmp_path / "a.pcd").write_text(text)
    d = read_pcd(tmp_path / "a.pcd")
    assert list(d) == ["x", "y", "z", "intensity"]  # padding "_" is dropped
    np.testing.assert_array_equal(d["x"], np.array([1, np.nan, -1.5, 0], np.float32))
    np.testing.assert_array_equal(d["z"], np.array([3, np.nan, 4, 100], np.float32))
    np.testing.assert_array_equal(d["intensity"], np.array([10, 0, 7, 1], np.float32))


def test_lzf_round_trip_and_known_stream():
    rng = np.random.default_rng(1)
    data = rng.integers(0, 256, 3000, dtype=np.uint8).tobytes() + bytes(5000) + b"xyz" * 700
    comp = lzf_compress(data)
    assert len(comp) < len(data) // 2
    assert lzf_decompress(comp, len(data)) == data
    # liblzf stream written by hand: literal "abc" then a back reference (offset 3, length 6)
    assert lzf_decompress(bytes([2, 97, 98, 99, (4 << 5) | 0, 2]), 9) == b"abcabcabc"
    with pytest.raises(ValueError, match="back reference before the start"):
        lzf_decompress(bytes([(1 << 5), 9]), 3)
    with pytest.raises(ValueError, match="header says 10"):
        lzf_decompress(bytes([2, 97, 98, 99]), 10)


B = "DATA binary\n"
HEADER = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\n"


@pytest.mark.parametrize(
    ("header", "match"),
    [
        (HEADER.replace("SIZE 4 4 4", "SIZE 4 4") + B, r"line 3: bad PCD header: SIZE has 2 entries"),
        (HEADER.replace("TYPE F F F", "TYPE F F Q") + B, r"line 4: bad PCD header: field 'z' has unsupported"),
        (HEADER.replace("WIDTH 1", "WIDTH one") + B, r"must be integers"),
        (HEADER.replace("VERSION 0.7", "COLOUR red") + B, r"line 1: bad PCD header: unknown keyword"),
        (HEADER + "DATA zip\n", r"DATA 'zip' is not one of ascii, binary, binary_compressed"),
        (HEADER, r"no DATA line"),
    ],
)
def test_bad_header_names_file_and_line(tmp_path, header, match):
    path = tmp_path / "bad.pcd"
    path.write_text(header)
    with pytest.raises(DatasetError, match=match) as info:
        read_pcd(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize("encoding", ["binary", "binary_compressed"])
def test_truncated_data_is_an_error(tmp_path, rng, encoding):
    path = tmp_path / "t.pcd"
    write_pcd(path, {"points": rng.normal(size=(500, 3)).astype(np.float32)}, encoding)
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) - 40])
    with pytest.raises(DatasetError, match="truncated"):
        read_pcd(path)


def test_ascii_row_with_wrong_column_count(tmp_path):
    path = tmp_path / "a.pcd"
    path.write_text(HEADER.replace("POINTS 1", "POINTS 2").replace("WIDTH 1", "WIDTH 2") + "DATA ascii\n1 2 3\n4 5\n")
    with pytest.raises(DatasetError, match=r"line 11: 2 values, 3 expected"):
        read_pcd(path)
