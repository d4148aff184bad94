"""deepbbs_ros: builds with colcon (ament_python) in a Jazzy workspace and installs with pip anywhere.

pip users: ``make test`` / ``make demo`` create ``.venv/`` and install everything (see README.md).
The ROS 2 Jazzy Python packages come from PyPI wheels (``ros-jazzy-*``): no ROS install needed.
"""

from glob import glob

from setuptools import find_namespace_packages, setup

package_name = "deepbbs_ros"

INSTALL_REQUIRES = [
    # ROS 2 Jazzy from PyPI wheels: real rclpy and Fast DDS in a plain virtual environment.
    "ros-jazzy-rclpy[fastrtps]",
    "ros-jazzy-common-interfaces",
    # torch: any recent release; the Makefile pins the CPU wheel (TORCH_SPEC) so CI stays fast,
    # a GPU user installs a CUDA build first and this range accepts it.
    "torch>=2.3",
    "numpy>=1.26",
    "scipy>=1.11",  # cKDTree neighbours, Rotation, Umeyama helpers
    "rosbags>=0.11",  # ROS 1 / ROS 2 (sqlite3, mcap) bags without a ROS install
    "mcap>=1.1",  # bare .mcap files
    "pyyaml>=6",
    "fpsample>=0.3",  # fast farthest-point sampling (bucket FPS)
    "small-gicp>=1.0",  # ICP / point-to-plane ICP / GICP baselines
    "kiss-icp>=1.0",  # KISS-ICP odometry baseline
    # KISS-Matcher (MIT SPARK): the global registration baseline of deepbbs-replay (kiss-matcher, kiss-matcher+gicp)
    "kiss-matcher>=1.0.2",
    "trimesh>=4",  # scene meshes for the LiDAR simulator
    "embreex>=4",  # Embree ray casting behind trimesh (fast, pip-only, no system libraries)
    "tqdm>=4.66",  # progress bars
    "rich>=13",  # result tables
    "matplotlib>=3.8",  # plots
    "ray>=2.40",  # fleet replay: recordings fanned out as tasks, locally or on a cluster (core only, no extras)
]

# mkdocs: tests/test_docs.py builds the docs site with --strict (broken links, anchors and missing files fail);
# evo: tests/test_metrics_exact.py checks the replay's ATE / APE / RPE against evo's own API
TEST_REQUIRES = ["pytest>=8", "hypothesis>=6.100", "ruff>=0.6", "mkdocs>=1.6", "evo>=1.38"]
# the localization benchmark's FPFH + RANSAC baseline (scripts/benchmarks/localization.py skips it without them);
# Open3D's Linux wheel also needs the system's libusb-1.0 (apt: libusb-1.0-0)
BENCH_REQUIRES = ["open3d>=0.18"]

setup(
    name=package_name,
    version="0.1.0",
    description="DeepBBS++ LiDAR scan registration for ROS 2 Jazzy: live node, offline replay, odometry benchmark",
    license="BSD-3-Clause",
    python_requires=">=3.10",
    # the data folders (models/, resources/) are packages too, so that setuptools ships their files without
    # "Package would be ignored" warnings; the training state under models/train_state stays in the repository
    packages=find_namespace_packages(include=["deepbbs_ros", "deepbbs_ros.*", "msg_adapters", "msg_adapters.*"],
                                     exclude=["deepbbs_ros.models.train_state*", "*.__pycache__"]),
    package_data={
        "deepbbs_ros.models": ["*.pt", "*.json"],
        "deepbbs_ros.resources": ["*.xml", "*.json"],  # verdict_model.json: the calibrated verdict
        # tf2_msgs definitions, built at install time (deepbbs_ros/interfaces.py)
        "deepbbs_ros.resources.interfaces.tf2_msgs": ["package.xml"],
        "deepbbs_ros.resources.interfaces.tf2_msgs.msg": ["*"],
        "deepbbs_ros.resources.interfaces.bond": ["package.xml"],  # bond/Status: Nav2's lifecycle manager's heartbeat
        "deepbbs_ros.resources.interfaces.bond.msg": ["*"],
    },
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*")),
        ("share/" + package_name + "/launch", glob("launch/*.py")),
        ("share/" + package_name + "/rviz", glob("rviz/*.rviz")),
    ],
    install_requires=INSTALL_REQUIRES,
    extras_require={"test": TEST_REQUIRES, "bench": BENCH_REQUIRES},
    zip_safe=False,
    entry_points={
        "console_scripts": [
            "deepbbs-sim = deepbbs_ros.cli.sim:main",
            "deepbbs-bag = deepbbs_ros.cli.bag:main",
            "deepbbs-bench = deepbbs_ros.cli.bench:main",
            "deepbbs-train = deepbbs_ros.cli.train:main",
            "deepbbs-replay = deepbbs_ros.cli.replay:main",
            "deepbbs-play = deepbbs_ros.cli.play:main",
            "deepbbs-node = deepbbs_ros.node.registration_node:main",
            "deepbbs-localizer = deepbbs_ros.node.managed:main",  # the managed (lifecycle) localization node
            "deepbbs-ros = deepbbs_ros.cli.ros:main",  # topic echo/hz, param get/set, reset, dds-profile (no ros2 CLI)
            # only deepbbs-* names on the PATH (sox has a `play`); colcon installs these same scripts into
            # lib/deepbbs_ros (setup.cfg), so `ros2 run deepbbs_ros deepbbs-node` and the launch file use them
        ],
    },
)
