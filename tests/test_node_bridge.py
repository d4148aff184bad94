"""A global search slower than the scan period, over real DDS: the pose it finds is carried through the scans that
arrived meanwhile (node/bridge.py) and tracking goes on with no loss; scans dropped unanswered are said once.

The map and the scans are tests/test_node_localization.py's simulated drive; the scans are made before they are sent,
at 10 Hz at most. The search is made to outlast the period by the node's test hook ``NodeLocalization.search_gate``
(the search waits until a dozen scans more arrived: the registration itself is the real one), and the pace of the
scans against the node's is set in scans, not seconds (``track_gate``, and a stream that waits for the node where a
test says so), so that a loaded machine gives the same sequence as a quiet one.
"""

from __future__ import annotations

import itertools
import time

import numpy as np
import pytest

from deepbbs_ros.node.dds import apply_default_profile

apply_default_profile()  # before the first DDS participant of this process

rclpy = pytest.importorskip("rclpy")

import test_node  # noqa: E402
import test_node_localization  # noqa: E402
from test_node import Harness, _check_pose, wait_for  # noqa: E402
from test_node_localization import _config, _registration, _write_map  # noqa: E402

from msg_adapters.transforms import pose_stamped_to_matrix  # noqa: E402

ros = test_node.ros  # the module fixture: rclpy context
drive = test_node_localization.drive  # the module fixture: the simulated drive and its map
PERIOD = 0.1  # s: 10 Hz


def _harness(drive_data, tmp_path, name: str, trajectory: bool = True, **extra) -> Harness:
    from deepbbs_ros.datasets.maps import write_map

    sim, points, poses, _ = drive_data
    if trajectory:
        _write_map(tmp_path / "map.pcd", points, poses)
    else:  # the map alone (from another tool): the node's places come from its free space
        write_map(tmp_path / "map.pcd", points, None, None)
    cfg = _config(**{"localization.map_path": str(tmp_path / "map.pcd"), "node.localization_odom": "none",
                     "node.base_frame": "", **extra})
    return Harness(cfg, name, registration=_registration(cfg))


def _clouds(sim, scan, frames) -> list[tuple[int, np.ndarray]]:
    """(stamp, points) of ``frames``, made before any is sent (a simulated scan takes most of a period to make)."""
    return [(sim.stamp_ns(k), scan(k)[0]) for k in frames]


def _stream(h: Harness, clouds: list[tuple[int, np.ndarray]], go=None) -> dict[int, float]:
    """Send ``clouds`` ((stamp, points)) a period apart at least; ``go(i)``, when given, is waited for before the i-th
    (a stream no faster than the node, counted in scans). -> stamp -> time.perf_counter() sent (the node's clock)."""
    sent: dict[int, float] = {}
    last = -np.inf
    for i, (stamp, xyz) in enumerate(clouds):
        assert go is None or h.wait_for(lambda i=i: go(i), 120.0), f"the node never got to scan {i}: {h.node.stats()}"
        time.sleep(max(last + PERIOD - time.perf_counter(), 0.0))
        sent[stamp] = last = time.perf_counter()
        h.send("source_cloud", xyz, stamp, "lidar")
    return sent


def _handed_on(h: Harness, clouds: list[tuple[int, np.ndarray]]):
    """``go`` for :func:`_stream`: the scan before the i-th was decoded and prepared (the input thread holds one
    waiting scan: a second sent meanwhile would push it out on a machine slower than the stream)."""
    loc = h.node.localization
    return lambda i: i == 0 or (loc.last_arrival is not None and loc.last_arrival >= clouds[i - 1][0])


def _search_waits_for(h: Harness, n: int) -> None:
    """Every search waits until ``n`` scans more arrived (kept for the bridge): it outlasts ``n`` scan periods."""
    loc = h.node.localization
    loc.search_gate = lambda: h.wait_for(lambda: loc._bridge.arrived >= n, 120.0)


@pytest.mark.parametrize("trajectory", [True, False], ids=["with_trajectory", "map_alone"])
def test_slow_search_then_tracking_with_no_loss(ros, drive, tmp_path, capfd, trajectory):
    """The first search lasts 12 scans (they arrive meanwhile): once it places its scan, the node follows the pose
    through the scans that arrived (their poses published, right), round after round while more arrive (one for every
    two it follows: tracking faster than the stream), and every scan sent after the first pose is answered with the
    right pose; never lost, one 'followed' line; the scans the bridge passed over are counted and said in one line at
    most. The same with a map given without its trajectory (a robot that boots anywhere in a map from another tool: the
    whole map's free space searched)."""
    sim, _, _, scan = drive
    during, after = _clouds(sim, scan, range(12, 25)), _clouds(sim, scan, range(25, 42))  # 3 s of driving at 10 Hz
    h = _harness(drive, tmp_path, "bridge_node", trajectory, **{"node.error_log_period": 60.0})
    loc = h.node.localization
    try:
        _search_waits_for(h, len(during) - 1)
        sent = _stream(h, during, go=_handed_on(h, during))  # the search's scan and those that arrive meanwhile
        # then one scan for every two the bridge follows, and once it caught up, each once the one before is answered
        prev = [during[-1][0]] + [stamp for stamp, _ in after]
        handed = _handed_on(h, [during[-1], *after])
        sent.update(_stream(h, after, go=lambda i: handed(i + 1) and (
            (loc._bridging and loc.bridged >= 2 * (i + 1)) or loc.answered(prev[i]))))
        frames = range(12, 42)
        assert h.wait_for(lambda: loc.tracker is not None and loc.tracker.last_stamp_ns == sim.stamp_ns(frames[-1])
                          and not h.node.worker.busy, 120.0), loc.diagnostics()
        assert h.wait_for(lambda: len(h.poses) >= h.node.outputs.published, 5.0)
        got = {pose_stamped_to_matrix(m)[1]: pose_stamped_to_matrix(m)[0] for m in h.poses}
        truth = {sim.stamp_ns(k): sim.pose_at(k) for k in frames}
        for stamp, T in got.items():
            _check_pose(T, truth[stamp])
        first = min(got)
        assert first == sim.stamp_ns(frames[0]), "the search's scan is the first placed"
        # the search's end, on the node's clock (this process's perf_counter, as `sent`): a scan received before it
        # arrived during the search (thinned by the bridge); sent[first] + first_pose_s would be earlier by the first
        # scan's delivery, and a scan sent in between is one the node rightly counts as of the search's time
        found_at = loc._found_t
        assert found_at >= sent[first] + loc.first_pose_s
        during = [s for s in got if s > first and sent[s] < found_at]  # arrived during the search, answered after it
        assert loc.first_pose_s > 10 * PERIOD and len(during) >= 8, (loc.first_pose_s, sorted(got))
        later = [s for s in sent if sent[s] > found_at]  # every scan sent after the first pose is answered
        assert later and all(s in got for s in later), (sorted(got), later)
        assert loc.state == "tracking" and loc.bridged >= 3 and loc.events.get("lost", 0) == 0, loc.diagnostics()
        assert h.wait_for(lambda: h.diagnostics().get("localization.scans followed after a search", "0") != "0", 5.0)
        log = capfd.readouterr().err
        assert log.count("localization found") == 1 and log.count("followed the pose through") == 1, log
        assert "localization lost" not in log and "fell behind" not in log, log
        assert ("a grid over its free space" in log) != trajectory, log  # the map alone: places from its free space
        dropped = h.node._drops.total  # the node's count; its next /diagnostics says the same
        assert h.wait_for(lambda: h.diagnostics().get("localization.scans dropped unanswered", "0") == str(dropped),
                          5.0), (dropped, h.diagnostics())
        lines = [ln for ln in log.splitlines() if "dropped unanswered" in ln]
        assert len(lines) == (dropped > 0) and (not lines or "dropped so far" in lines[0]), (dropped, lines)
    finally:
        h.close()


def test_bridge_slower_than_the_stream_ends_and_says_so(ros, drive, tmp_path, capfd):
    """Tracking slower than the stream, counted in scans rather than seconds (so the same on a loaded machine): every
    scan the bridge follows waits (the test hook ``track_gate``) until the test sent two more and both arrived. The
    bridge cannot catch up, so it does not try to: it ends once as many scans arrived as its window holds
    (node/bridge.py gains(): after following half of it), long before it would have followed them all, and the log
    line says so; the worker goes on from the last pose followed, never lost, to the last scan sent; every pose
    published is right."""
    import re

    from deepbbs_ros.node.bridge import BRIDGE_MAX

    sim, _, _, scan = drive
    during = _clouds(sim, scan, range(12, 25))  # the search's scan and the 12 that arrive during the search
    later = iter(_clouds(sim, scan, range(25, 49)))  # sent while the bridge follows: two for every scan it follows
    h = _harness(drive, tmp_path, "slow_bridge_node", **{"node.error_log_period": 60.0})
    loc = h.node.localization
    sent: list[int] = []

    def two_more_arrive() -> None:  # on the worker thread, before a tracked scan's registration
        if not loc._bridging:
            return  # the worker's own scans after the bridge: no wait
        for stamp, xyz in itertools.islice(later, 2):  # one at a time: the input thread holds one waiting scan
            start = loc._bridge.arrived
            h.send("source_cloud", xyz, stamp, "lidar")
            sent.append(stamp)
            wait_for(lambda start=start: loc._bridge.arrived > start, 120.0)

    try:
        _search_waits_for(h, len(during) - 1)
        loc.track_gate = two_more_arrive
        stamps = list(_stream(h, during, go=_handed_on(h, during)))
        assert h.wait_for(lambda: loc.last_bridge != "" and not h.node.worker.busy, 120.0), loc.diagnostics()
        line = loc.last_bridge
        m = re.search(r"(\d+) scan\(s\) arrived while it followed the last (\d+)\)", line)
        assert m, line
        arrived, followed = map(int, m.groups())
        assert arrived >= BRIDGE_MAX > followed >= 1, line  # cut within its first window
        assert loc.bridged == followed, (loc.bridged, line)
        stamps += sent
        # the worker goes on from the last pose followed (its slot: the newest scan each time) and keeps the pose
        assert h.wait_for(lambda: loc.tracker.last_stamp_ns == stamps[-1] and not h.node.worker.busy, 120.0), (
            loc.diagnostics())
        assert loc.state == "tracking" and loc.events.get("lost", 0) == 0, loc.diagnostics()
        assert h.wait_for(lambda: len(h.poses) >= h.node.outputs.published, 5.0)
        truth = {sim.stamp_ns(k): sim.pose_at(k) for k in range(12, 49)}
        for msg in h.poses:
            _check_pose(pose_stamped_to_matrix(msg)[0], truth[pose_stamped_to_matrix(msg)[1]])
        assert "fell behind the stream" in capfd.readouterr().err
    finally:
        h.close()


def test_drops_are_said_once_and_counted(ros, drive, tmp_path, capfd):
    """Without the bridge (``localization.bridge_scans`` 0), the scans that wait for a long search are dropped: the
    first drop is one log line naming why and the counter, later ones are only counted (/diagnostics)."""
    sim, _, _, scan = drive
    clouds = _clouds(sim, scan, range(12, 20))
    h = _harness(drive, tmp_path, "drops_node", **{"localization.bridge_scans": 0, "node.error_log_period": 60.0})
    try:  # the search waits until every scan was received (none kept: the bridge is off)
        h.node.localization.search_gate = lambda: h.wait_for(lambda: h.node.stats()["received"] >= len(clouds), 120.0)
        _stream(h, clouds)
        assert h.wait_for(lambda: h.node.localization.placed >= 1 and not h.node.worker.busy, 60.0)
        drops = h.node.worker.dropped + sum(i.dropped for i in h.node.inputs)
        assert drops >= 3, h.node.stats()
        assert h.wait_for(lambda: h.diagnostics().get("localization.scans dropped unanswered") == str(drops), 5.0), (
            h.diagnostics())
        log = capfd.readouterr().err
        lines = [ln for ln in log.splitlines() if "dropped unanswered" in ln]
        assert len(lines) == 1 and "1 dropped so far" in lines[0] and "registration" in lines[0], log
    finally:
        h.close()


def test_scan_bridge_takes_the_first_two_then_spread():
    """ScanBridge.take: the scans after the found one less the newest, at most BRIDGE_MAX, the first two and the last
    of them kept; the ones before the found scan and those taken are forgotten."""
    from types import SimpleNamespace

    from deepbbs_ros.node.bridge import BRIDGE_MAX, ScanBridge

    b = ScanBridge(30)
    for s in range(25):
        b.add(SimpleNamespace(stamp_ns=s))
    got = [c.stamp_ns for c in b.take(4)]
    assert len(got) == BRIDGE_MAX and got[:2] == [5, 6] and got[-1] == 23 and got == sorted(got), got
    assert b.dropped == 25 - 1 - 1 - BRIDGE_MAX  # all but the found scan (4), those taken and the newest (24)
    assert [c.stamp_ns for c in b.take(23)] == [] and len(b) == 1  # the newest stays (the worker's next job)
    assert ScanBridge(0).take(0) == [] and np.isfinite(len(ScanBridge(0)))
    c = ScanBridge(30)  # the node's rounds take the newest too (the worker's slot may lose it to the next arrival)
    for s in range(10):
        c.add(SimpleNamespace(stamp_ns=s))
    assert [x.stamp_ns for x in c.take(4, leave_newest=False)] == [5, 6, 7, 8, 9] and len(c) == 0 and c.dropped == 4
    d = ScanBridge(30)  # the scans received once the pose was found are never thinned: only the search's are
    for s in range(25):
        d.add(SimpleNamespace(stamp_ns=s, t_recv=float(s)))
    got = [x.stamp_ns for x in d.take(4, leave_newest=False, keep_since=21.5)]
    assert got[:2] == [5, 6] and got[-3:] == [22, 23, 24] and len(got) == BRIDGE_MAX and got == sorted(got), got
    assert got[-4] == 21  # the last of the search's time kept too (the velocity into the new ones)


def test_bridge_follows_while_it_gains_on_the_stream():
    """gains(): a round of the bridge goes on while fewer scans arrived during it than it holds (tracking is faster
    than the stream: the next round is smaller) and ends once as many arrived (the backlog cannot shrink: a machine too
    slow for the stream), whatever the wall-clock time; ScanBridge counts the arrivals, and the scans a round handed out
    and did not follow go back (restore), counted as dropped once a later scan is answered."""
    from types import SimpleNamespace

    from deepbbs_ros.node.bridge import ScanBridge, gains

    assert gains(12, 0) and gains(12, 11) and not gains(12, 12) and not gains(1, 1) and not gains(0, 0)
    # a tracker faster than the stream (60 ms a scan, 100 ms apart), 12 scans behind: over every 12 it follows, 7 or 8
    # arrive (the phase of the first), so the backlog shrinks until it is caught up
    cost, period, backlog, t, starts = 60, 100, 12, 0, []
    while backlog:
        starts.append(t)
        t += cost
        backlog += (t // period - (t - cost) // period) - 1  # arrivals during this scan, less the scan followed
        w = starts[-12:]
        assert gains(12, t // period - w[0] // period), (len(starts), backlog)
    assert len(starts) == 28  # about 12 / (1 - 0.6): caught up, within the bound of 12 a scan of backlog
    slow = 150  # ms: slower than the stream: 12 arrived once it followed 8 (cut there, within its first window)
    assert [gains(12, k * slow // period) for k in (7, 8)] == [True, False]
    b = ScanBridge(30)
    for s in range(10):
        b.add(SimpleNamespace(stamp_ns=s))
    assert b.arrived == 10
    got = b.take(2, leave_newest=False)
    assert [x.stamp_ns for x in got] == list(range(3, 10)) and len(b) == 0
    b.restore(got[3:])  # the round ended after 3, 4, 5: 6..9 back
    b.add(SimpleNamespace(stamp_ns=10))
    dropped = b.dropped
    b.forget_until(10)  # the worker answered scan 10: 6..9 were dropped
    assert b.dropped - dropped == 4 and len(b) == 0 and b.arrived == 11


def test_tracker_retries_at_rest_when_the_prediction_is_far_off(drive):
    """MapTracker: a scan rejected at once from the constant-velocity prediction (25 m ahead: the sensor stopped) is
    registered once more by GICP from the last pose at rest and placed right (without: rejected, 'no local search')."""
    from deepbbs_ros.core.localization import MapLocalizer
    from deepbbs_ros.core.tracking import MapTracker

    sim, points, poses, scan = drive
    cfg = _config()
    loc = MapLocalizer(points, cfg, registration=_registration(cfg), trajectory=poses)
    tracker = MapTracker(loc, cfg)
    k = 40
    T = scan(k)[1]
    back = T.copy()
    back[:3, 3] -= 25.0 * T[:3, 0]  # 25 m behind along the heading, 0.1 s earlier: the prediction is 25 m ahead
    s0, s1 = sim.stamp_ns(k) - 200_000_000, sim.stamp_ns(k) - 100_000_000
    tracker.state, tracker._poses = "tracking", [(s0, back), (s1, T.copy())]
    loc._track_scores.extend([1.0, 1.0])  # the recent tracked scans' scores
    assert np.linalg.norm(tracker.predict(sim.stamp_ns(k))[:3, 3] - T[:3, 3]) > 20.0
    res = tracker.step(scan(k)[0], sim.stamp_ns(k))
    # answered by GICP from the last pose, not by the slower local search among the places (what it took without)
    assert res.valid and tracker.state == "tracking" and res.path == "gicp", (res.reason, res.path)
    _check_pose(res.T_map_scan, T)


def test_tracked_covariance_is_the_sandwich_at_the_pose(drive):
    """A tracked pose's covariance is the cluster-robust sandwich of the GICP pairs of the scan on its crop at the
    pose it carries (core/covariance.py, computed here from the pairs directly: the localization's pairs,
    leave-one-cell-out estimator, Student's t widening and weak-direction prior), for every tracked scan."""
    from deepbbs_ros.core.covariance import (
        LOCALIZATION_INFLATION,
        LOCALIZATION_MAX_POINTS,
        matched_pairs,
        sandwich_covariance,
    )
    from deepbbs_ros.core.localization import MapLocalizer
    from deepbbs_ros.core.tracking import MapTracker

    sim, points, poses, scan = drive
    cfg = _config()
    corr = cfg.localization.refine_corr_dist
    assert corr > 0
    loc = MapLocalizer(points, cfg, registration=_registration(cfg), trajectory=poses)
    seen = []
    own = loc._covariance

    def spy(src, crop, T, timings):
        pairs = matched_pairs(src.polish_cloud, crop.pre.polish_cloud, np.linalg.solve(crop.T_map_place, T), corr,
                              1, LOCALIZATION_MAX_POINTS)
        seen.append((T, sandwich_covariance(pairs, T, LOCALIZATION_INFLATION, weak_sigma=corr / np.sqrt(3.0),
                                            student=True)))
        return own(src, crop, T, timings)

    loc._covariance = spy
    tracker = MapTracker(loc, cfg)
    tracker.state, tracker._poses = "tracking", [(sim.stamp_ns(29), scan(29)[1])]
    for k in (30, 31, 32):
        res = tracker.step(scan(k)[0], sim.stamp_ns(k))
        assert res.valid and res.path != "global", (res.reason, res.path)
        T, want = seen[-1]
        np.testing.assert_array_equal(res.T_map_scan, T)
        np.testing.assert_allclose(res.covariance, want, rtol=1e-6, atol=1e-12)
    assert len(seen) == 3
