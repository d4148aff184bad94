"""Thread settings: an offline run (deepbbs-replay) computes on a fixed thread count (``eval.threads``, 1), the live
nodes on every core, and "every core" is the CPUs the process may use (taskset, a container's cpuset). That a replay's
figures then do not depend on the cores is checked end to end in tests/test_fleet.py."""

from __future__ import annotations

import os

import numpy as np
import pytest

from deepbbs_ros.baselines import SmallGicpRegistration, one_cpu
from deepbbs_ros.config import Config
from deepbbs_ros.core.polish import (
    cpu_cores,
    polish,
    prepare_polish_cloud,
    threads_or_all,
)
from deepbbs_ros.replay.runner import OFFLINE_THREAD_KEYS, offline_threads

needs_affinity = pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="no CPU affinity on this platform")


def test_an_offline_run_takes_every_thread_count_from_eval_threads():
    cfg = Config()
    assert cfg.eval.threads == 1 and cfg.registration.polish_threads == 0 and cfg.odometry.threads == 0
    used = offline_threads(cfg)
    assert all(used.to_flat()[key] == 1 for key in OFFLINE_THREAD_KEYS)
    assert SmallGicpRegistration("gicp", used).num_threads == 1
    four = offline_threads(cfg.replace(**{"eval.threads": 4}))
    assert all(four.to_flat()[key] == 4 for key in OFFLINE_THREAD_KEYS)
    assert offline_threads(cfg.replace(**{"eval.threads": 0})).to_flat() == cfg.replace(**{"eval.threads": 0}).to_flat()
    assert cfg.to_flat() == Config().to_flat()  # the config given is left as it was


def test_the_gicp_anchor_node_keeps_every_core():
    """The node's GICP anchor computes on the threads of the DeepBBS++ node's precision stage (every core), not on
    an offline run's one thread: the latency benchmark compares the two nodes."""
    pytest.importorskip("rclpy")
    from deepbbs_ros.node.gicp_anchor import GicpRegistration

    assert GicpRegistration(Config()).gicp.num_threads == cpu_cores()
    assert GicpRegistration(Config().replace(**{"registration.polish_threads": 3})).gicp.num_threads == 3


@needs_affinity
def test_every_core_is_the_cpus_the_process_may_use():
    cpus = os.sched_getaffinity(0)
    assert cpu_cores() == len(cpus) and threads_or_all(0) == len(cpus) and threads_or_all(5) == 5
    with one_cpu():
        one = os.sched_getaffinity(0)
        assert len(one) == 1 and one <= cpus  # the CPU the thread runs on: a fleet's tasks do not share one
        assert cpu_cores() == 1 and threads_or_all(0) == 1
    assert os.sched_getaffinity(0) == cpus  # restored
    with one_cpu(False):
        assert os.sched_getaffinity(0) == cpus
    with pytest.raises(RuntimeError), one_cpu():
        raise RuntimeError("restored on an error too")
    assert os.sched_getaffinity(0) == cpus


def test_a_gicp_cloud_is_the_same_on_any_number_of_threads(street_pair):
    """The precision stage's voxel grid, k-d tree and covariances do not depend on the thread count (small_gicp's
    parallel voxel grid would cut voxels at its blocks' edges and write them in the order its threads finish)."""
    (ng, ground), _, _ = street_pair(3, 30000, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], road=True)
    pts = np.concatenate([ng, ground])
    one, two = (prepare_polish_cloud(pts, 0.5, 20, threads=n) for n in (1, 2))
    assert one.n_points == two.n_points
    np.testing.assert_array_equal(one.points(), two.points())
    np.testing.assert_array_equal(np.asarray(one.cloud.covs()), np.asarray(two.cloud.covs()))


def test_exact_gicp_gives_the_one_thread_pose_to_the_last_bit(street_pair):
    """``registration.exact_gicp``: the GICP solve on one thread whatever ``polish_threads`` (its sums in index order),
    so a pose is the same on any machine; the clouds keep their threads."""
    src, tgt, T = street_pair(5, 30000, [4.0, 0.3, -0.2], [1.2, 0.3, 0.03], road=True)
    clouds = [prepare_polish_cloud(np.concatenate(c), 0.5, 20, threads=2) for c in (src, tgt)]
    T0 = T.copy()
    T0[:3, 3] += [0.5, -0.4, 0.1]

    def solve(**flat):
        cfg = Config().replace(**{"registration.polish_max_trans": 0.0, **flat}).registration
        return polish(clouds[0], clouds[1], T0, cfg)

    ref = solve(**{"registration.polish_threads": 1})
    assert ref.applied and np.linalg.norm(ref.T_target_source[:3, 3] - T[:3, 3]) < 0.1  # it solves the pair
    for _ in range(3):
        exact = solve(**{"registration.polish_threads": 2, "registration.exact_gicp": True})
        np.testing.assert_array_equal(exact.T_target_source, ref.T_target_source)


def test_pin_chooses_the_avx2_kernels_and_keeps_the_users_own(monkeypatch):
    """deepbbs_ros.cpu_kernels.pin: the AVX2 kernels of OpenBLAS, torch and numpy on an x86-64 CPU with AVX2 (the
    same sums on any such computer); a setting the user made wins; DEEPBBS_CPU_KERNELS=native sets nothing."""
    from deepbbs_ros import cpu_kernels

    monkeypatch.setattr(cpu_kernels, "_has_avx2", lambda: True)
    monkeypatch.setattr(cpu_kernels.platform, "machine", lambda: "x86_64")
    env = {"OPENBLAS_CORETYPE": "Zen"}
    assert cpu_kernels.pin(env).startswith("avx2")
    assert env["OPENBLAS_CORETYPE"] == "Zen" and env["ATEN_CPU_CAPABILITY"] == "avx2"
    assert env["NPY_DISABLE_CPU_FEATURES"] in cpu_kernels.NUMPY_ABOVE_AVX2.values()
    assert "except numpy" in cpu_kernels.state()  # this process imported numpy long ago: it keeps its own kernels
    env = {"DEEPBBS_CPU_KERNELS": "native"}
    assert cpu_kernels.pin(env) == "native (DEEPBBS_CPU_KERNELS=native)" and set(env) == {"DEEPBBS_CPU_KERNELS"}
    monkeypatch.setattr(cpu_kernels, "_has_avx2", lambda: False)
    env = {}
    assert cpu_kernels.pin(env) == "native (no AVX2 found)" and env == {}
    monkeypatch.setattr(cpu_kernels.platform, "machine", lambda: "aarch64")
    assert cpu_kernels.pin({}) == "native (aarch64 CPU)"


def test_a_process_that_imports_deepbbs_ros_first_runs_numpy_and_torch_on_avx2_kernels():
    """In a fresh process ``import deepbbs_ros`` comes before numpy and torch load: numpy dispatches nothing above
    AVX2 and torch runs its AVX2 kernels; numpy imported first keeps its own, and the state says so."""
    import subprocess
    import sys

    from deepbbs_ros import cpu_kernels

    if not cpu_kernels._has_avx2():
        pytest.skip("this CPU has no AVX2: the kernels stay the CPU's own")
    env = {k: v for k, v in os.environ.items()
           if k not in (*cpu_kernels.ENV, "NPY_DISABLE_CPU_FEATURES", "DEEPBBS_CPU_KERNELS")}
    code = ("import deepbbs_ros, numpy, torch\n"
            "from numpy._core._multiarray_umath import __cpu_features__ as f\n"
            "from deepbbs_ros import cpu_kernels\n"
            "import os\n"
            "above = [k for k in os.environ['NPY_DISABLE_CPU_FEATURES'].split() if f.get(k)]\n"
            "print(cpu_kernels.state(), torch.backends.cpu.get_cpu_capability(), above)\n")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert out.split() == ["avx2", "AVX2", "[]"], out
    late = subprocess.run([sys.executable, "-c", "import numpy, deepbbs_ros.cpu_kernels as c; print(c.state())"],
                          env=env, capture_output=True, text=True, check=True).stdout
    assert late.strip() == "avx2 except numpy (imported before deepbbs_ros)"
