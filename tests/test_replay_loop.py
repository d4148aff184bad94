"""The replay loops' shared skeleton (replay/loop.py): every scan read is counted and reported once, every
stride-th position not skipped is kept, and Ctrl-C ends the block with the results so far, marked incomplete."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from deepbbs_ros.replay.loop import INTERRUPTED, counted, keep_on_interrupt, strided


def _results():
    return SimpleNamespace(frames_read=0, complete=True, errors=[])


def test_strided_counts_every_scan_and_keeps_every_stride_th_not_skipped():
    res, seen = _results(), []
    kept = [pos for pos, _ in strided(iter("abcdefghij"), res, 3, seen.append, skip={3})]
    assert kept == [0, 6, 9] and res.frames_read == 10 and seen == [1] * 10
    res = _results()
    assert [s for _, s in counted("xyz", res)] == ["x", "y", "z"] and res.frames_read == 3


def test_ctrl_c_keeps_what_was_read_and_marks_it_incomplete():
    def reader():
        yield from "ab"
        raise KeyboardInterrupt

    res, got = _results(), []
    with keep_on_interrupt(res):
        for _, scan in counted(reader(), res):
            got.append(scan)
    assert got == ["a", "b"] and res.frames_read == 2 and not res.complete and res.errors == [INTERRUPTED]
    with pytest.raises(ValueError), keep_on_interrupt(_results()):
        raise ValueError("other errors propagate")
