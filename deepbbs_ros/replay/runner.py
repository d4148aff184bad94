"""Replay loops: the Apollo pair protocol, scan-to-scan odometry and localization in a prior map, over any
iterable of scans.

The loops stream the recording once (only the scans still needed are kept), run every selected
method on the same inputs, and fill a :class:`PairResults` / :class:`OdometryResults` /
:class:`LocalizationResults` as they go, so that an interruption (Ctrl-C) or a reader fault leaves
everything computed so far in the results (``complete = False``). No ROS import, no output files
(see :mod:`deepbbs_ros.replay.report`).

Modules: :mod:`~deepbbs_ros.replay.pair_loop`, :mod:`~deepbbs_ros.replay.odometry_loop`,
:mod:`~deepbbs_ros.replay.localization_loop`, what they share (reading, counting, Ctrl-C) in
:mod:`~deepbbs_ros.replay.loop`; this one holds the thread settings of an offline run, and every loop's names are
imported from here too.
"""

from __future__ import annotations

from deepbbs_ros.config import Config
from deepbbs_ros.replay.localization_loop import LocalizationRecord, LocalizationResults, run_localization
from deepbbs_ros.replay.odometry_loop import OdometryResults, robustness_plan, run_odometry
from deepbbs_ros.replay.pair_loop import PairRecord, PairResults, iter_pairs, random_perturbation, run_pairs

__all__ = [
    "OFFLINE_THREAD_KEYS", "LocalizationRecord", "LocalizationResults", "OdometryResults", "PairRecord", "PairResults",
    "iter_pairs", "offline_threads", "random_perturbation", "robustness_plan", "run_localization", "run_odometry",
    "run_pairs",
]

# --------------------------------------------------------------------------------------------------
# the threads of an offline run
# --------------------------------------------------------------------------------------------------
#: the thread settings ``eval.threads`` replaces in an offline run (small_gicp in DeepBBS++'s precision stage and
#: odometry, torch in the network); the baselines (small_gicp, KISS-ICP) read ``eval.threads`` itself
OFFLINE_THREAD_KEYS = ("registration.polish_threads", "odometry.threads", "registration.threads")


def offline_threads(config: Config) -> Config:
    """The config an offline run uses: every thread setting ``eval.threads`` (when > 0; 0 leaves each section's).

    small_gicp sums its GICP terms in per-thread partial sums over an OpenMP ``schedule(guided)`` loop (one
    thread whatever the count with ``registration.exact_gicp``) and writes odometry's voxel grid
    (``preprocess_points``) in the order its threads finish (the precision stage's grid is built on one thread,
    core/polish.py); KISS-ICP sums with TBB's ``parallel_reduce``, grouped by the CPUs it may use. With one thread
    each sum runs in index order (KISS-ICP and KISS-Matcher on one CPU, :func:`deepbbs_ros.baselines.one_cpu`), so
    one thread (the default) gives the same figures, bit for bit, on any number of cores and in a Ray task (1 CPU,
    Ray's ``OMP_NUM_THREADS=1``) as in a single run on every core. The results folder's config_used.yaml records
    the settings applied."""
    n = config.eval.threads
    if n <= 0:
        return config
    return config.replace(**{key: n for key in OFFLINE_THREAD_KEYS})


