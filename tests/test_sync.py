"""ApproximateTimeSync: message_filters' ApproximateTime semantics plus stamp-ordered output."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from deepbbs_ros.errors import ConfigError
from deepbbs_ros.node.sync import ApproximateTimeSync

MS = 1_000_000  # ns


def _accounted(sync):
    """Messages emitted, still queued, or dropped for a counted reason."""
    st = sync.stats
    dropped = st["overflow"] + st["stale"] + st["late"] + st["cleared"]
    return 2 * st["emitted"] + sum(sync.queue_lengths()) + dropped


def _stamps(items):
    return [s for s, _ in items]


def test_pairs_closest_within_slop():
    out = []
    sync = ApproximateTimeSync(2, 10, 0.05, out.append)
    sync.add(0, 1000 * MS, "a0")
    assert out == []
    sync.add(1, 1020 * MS, "b0")  # 20 ms apart <= 50 ms slop
    assert out == [[(1000 * MS, "a0"), (1020 * MS, "b0")]]
    assert sync.queue_lengths() == [0, 0]


def test_no_pair_beyond_slop_and_slop_is_inclusive():
    out = []
    sync = ApproximateTimeSync(2, 10, 0.05, out.append)
    sync.add(0, 0, "a")
    sync.add(1, 51 * MS, "b")
    assert out == []
    sync.add(1, 50 * MS, "c")  # exactly slop
    assert [[p for _, p in t] for t in out] == [["a", "c"]]


def test_closest_candidate_wins():
    out = []
    sync = ApproximateTimeSync(2, 10, 0.1, out.append)
    sync.add(1, 950 * MS, "far")
    sync.add(1, 990 * MS, "near")
    sync.add(0, 1000 * MS, "src")
    assert _stamps(out[0]) == [1000 * MS, 990 * MS]
    # the older unmatched one can never be emitted in order any more: dropped and counted
    assert sync.stats["stale"] == 1 and sync.queue_lengths() == [0, 0]


def test_queue_size_drops_oldest():
    sync = ApproximateTimeSync(2, 3, 0.01)
    for k in range(5):
        sync.add(0, k * 100 * MS, k)
    assert sync.queue_lengths() == [3, 0]
    assert sync.stats["overflow"] == 2
    # the two oldest are gone: a partner for stamp 0 finds nothing, one for 200 ms pairs
    assert sync.add(1, 0, "x") is None
    got = sync.add(1, 200 * MS, "y")
    assert [p for _, p in got] == [2, "y"]


def test_same_stamp_replaces():
    sync = ApproximateTimeSync(2, 5, 0.0)
    sync.add(0, 5 * MS, "old")
    sync.add(0, 5 * MS, "new")
    assert sync.queue_lengths() == [1, 0]
    assert [p for _, p in sync.add(1, 5 * MS, "t")] == ["new", "t"]  # slop 0 = exact time


def test_emitted_in_stamp_order_and_late_refused(rng):
    # two 20 Hz streams with jitter, delivered with random interleaving and small reordering
    out = []
    sync = ApproximateTimeSync(2, 10, 0.02, out.append)
    events = []
    for k in range(200):
        base = k * 50 * MS
        for i in range(2):
            events.append((base + int(rng.integers(-5, 6)) * MS + int(rng.integers(0, 3)) * 7 * MS, i, k))
    order = np.argsort([e[0] + int(rng.integers(0, 30)) * MS for e in events], kind="stable")
    for j in order:
        stamp, i, k = events[j]
        sync.add(i, stamp, (i, k))
    assert len(out) > 150
    for i in range(2):
        s = [t[i][0] for t in out]
        assert all(b > a for a, b in zip(s, s[1:])), "stamps must increase on every input"
    for t in out:
        assert abs(t[0][0] - t[1][0]) <= 20 * MS
    st = sync.stats
    assert st["emitted"] == len(out)
    assert st["received"] == 400
    # every message is accounted for: emitted, still queued, or dropped for a counted reason
    assert _accounted(sync) == st["received"]


def test_jump_back_resets():
    out = []
    sync = ApproximateTimeSync(2, 10, 0.01, out.append, jump_back_s=1.0)
    sync.add(0, 100_000 * MS, "a")
    sync.add(1, 100_000 * MS, "b")
    # a bag restarted from its beginning: much older stamps
    sync.add(0, 1000 * MS, "c")
    sync.add(1, 1000 * MS, "d")
    assert [[p for _, p in t] for t in out] == [["a", "b"], ["c", "d"]]
    assert sync.stats["resets"] == 1
    # a small step back (reordering) is refused, not a reset
    sync.add(0, 990 * MS, "late")
    assert sync.stats["late"] == 1 and sync.stats["resets"] == 1


def test_a_lagging_input_is_no_time_jump():
    """One input's older scans still arriving after the other's newer one (its thread behind): each input is
    compared with its own newest stamp, so nothing is cleared and the pair forms when its partner arrives."""
    out = []
    sync = ApproximateTimeSync(2, 10, 0.05, out.append, jump_back_s=1.0)
    sync.add(1, 20_000 * MS, "t20")
    sync.add(0, 30_000 * MS, "s30")  # the source of the next pair overtakes the target of the last one
    sync.add(1, 20_000 * MS, "t20 again")  # 10 s older than s30: not a jump on its own input
    sync.add(1, 30_000 * MS, "t30")
    assert [[p for _, p in t] for t in out] == [["s30", "t30"]]
    assert sync.stats["resets"] == 0 and sync.stats["cleared"] == 0
    assert sync.stats["stale"] == 1  # t20 (replaced by "t20 again") can never pair after t30


def test_three_inputs():
    out = []
    sync = ApproximateTimeSync(3, 4, 0.03, out.append)
    sync.add(0, 100 * MS, "a")
    sync.add(1, 120 * MS, "b")
    assert out == []
    sync.add(2, 90 * MS, "c")  # spread 30 ms <= slop
    assert [p for _, p in out[0]] == ["a", "b", "c"]
    sync.add(0, 200 * MS, "a2")
    sync.add(1, 215 * MS, "b2")
    sync.add(2, 240 * MS, "c2")  # each within 40 ms of c2's partner search, but spread 40 ms > slop
    assert len(out) == 1


def test_thread_safety():
    out = []
    sync = ApproximateTimeSync(2, 10, 0.001, out.append, jump_back_s=1e6)

    def feed(i):
        for k in range(2000):
            sync.add(i, k * MS * 10, k)

    threads = [threading.Thread(target=feed, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    st = sync.stats
    assert _accounted(sync) == st["received"] == 4000
    for i in range(2):
        s = [t[i][0] for t in out]
        assert s == sorted(set(s))


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"n_inputs": 1, "queue_size": 1, "slop": 0.1}, "n_inputs"),
        ({"n_inputs": 2, "queue_size": 0, "slop": 0.1}, "queue_size"),
        ({"n_inputs": 2, "queue_size": 1, "slop": -1.0}, "slop"),
    ],
)
def test_bad_arguments(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        ApproximateTimeSync(**kwargs)


def test_bad_index():
    with pytest.raises(IndexError, match="out of range"):
        ApproximateTimeSync(2, 1, 0.1).add(2, 0, None)
