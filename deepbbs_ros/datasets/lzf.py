"""LZF compression in liblzf's format, in pure Python (no C extension): what PCD's ``binary_compressed`` encoding
stores its data with (datasets/pcd.py)."""

from __future__ import annotations


def lzf_decompress(data: bytes, expected_size: int) -> bytes:
    """Decompress liblzf data to exactly ``expected_size`` bytes; ValueError on corrupt input."""
    out = bytearray()
    i, n = 0, len(data)
    try:
        while i < n:
            ctrl = data[i]
            i += 1
            if ctrl < 32:  # literal run of ctrl + 1 bytes
                length = ctrl + 1
                if i + length > n:
                    raise ValueError("literal run past the end of the compressed data")
                out += data[i : i + length]
                i += length
            else:  # back reference: length (3 bits, maybe extended), offset (13 bits)
                length = ctrl >> 5
                if length == 7:
                    length += data[i]
                    i += 1
                ref = len(out) - ((ctrl & 0x1F) << 8) - data[i] - 1
                i += 1
                length += 2
                if ref < 0:
                    raise ValueError("back reference before the start of the output")
                if ref + length <= len(out):
                    out += out[ref : ref + length]
                else:  # overlapping copy (a run): byte by byte
                    for k in range(length):
                        out.append(out[ref + k])
            if len(out) > expected_size:
                break
    except IndexError:
        raise ValueError("compressed data ends inside a token") from None
    if len(out) != expected_size:
        raise ValueError(f"decompressed to {len(out)} bytes, header says {expected_size}")
    return bytes(out)


def lzf_compress(data: bytes) -> bytes:
    """Compress with liblzf's format (3-byte hash matches, offsets < 8192, lengths <= 264)."""
    data = bytes(data)
    n = len(data)
    out = bytearray()
    table: dict[bytes, int] = {}
    lit_start = 0
    i = 0

    def flush_literals(end: int) -> None:
        start = lit_start
        while start < end:
            chunk = data[start : min(start + 32, end)]
            out.append(len(chunk) - 1)
            out.extend(chunk)
            start += len(chunk)

    while i < n - 2:
        key = data[i : i + 3]
        ref = table.get(key)
        table[key] = i
        if ref is not None and i - ref - 1 < 8192:
            max_len = min(264, n - i)
            length = 3
            while length < max_len and data[ref + length] == data[i + length]:
                length += 1
            flush_literals(i)
            off = i - ref - 1
            code = length - 2
            if code < 7:
                out.append((code << 5) | (off >> 8))
            else:
                out.append((7 << 5) | (off >> 8))
                out.append(code - 7)
            out.append(off & 0xFF)
            i += length
            lit_start = i
        else:
            i += 1
    flush_literals(n)
    return bytes(out)
