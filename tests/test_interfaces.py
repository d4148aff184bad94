"""tf2_msgs from its definition: generated with the ROS wheels' rosidl generators, compiled, and usable by rclpy
(the route `make venv` / `deepbbs-ros build-interfaces` takes; here built into a temporary folder, not installed)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap

import pytest

pytest.importorskip("rosidl_generator_c")
if shutil.which("gcc") is None or shutil.which("g++") is None:
    pytest.skip("needs gcc and g++", allow_module_level=True)

from deepbbs_ros import interfaces  # noqa: E402


def test_tf2_msgs_builds_and_serialises(tmp_path):
    stage = interfaces.build_package("tf2_msgs", tmp_path, install=False)
    libs = {p.name for p in (stage / "lib").iterdir()}
    for ts in ("rosidl_generator_c", "rosidl_generator_py", "rosidl_typesupport_c", "rosidl_typesupport_fastrtps_c",
               "rosidl_typesupport_introspection_c"):  # fmt: skip
        assert f"libtf2_msgs__{ts}.so" in libs
        if ts.startswith("rosidl_typesupport"):
            assert (stage / "tf2_msgs" / f"tf2_msgs_s__{ts}.so").is_file()
    assert (stage / "share" / "tf2_msgs" / "msg" / "TFMessage.idl").is_file() and (stage / "setup.py").is_file()
    # the staged package, first on the paths: a TFMessage through the Fast DDS (CDR) type support and back
    code = textwrap.dedent("""
        import tf2_msgs, sys
        assert tf2_msgs.__file__.startswith(sys.argv[1]), tf2_msgs.__file__
        from tf2_msgs.msg import TFMessage
        from geometry_msgs.msg import TransformStamped
        from rclpy.serialization import serialize_message, deserialize_message
        t = TransformStamped(child_frame_id="base_link")
        t.header.frame_id = "odom"
        t.header.stamp.sec = 7
        t.transform.translation.x, t.transform.rotation.z, t.transform.rotation.w = 1.5, 0.6, 0.8
        out = deserialize_message(serialize_message(TFMessage(transforms=[t, t])), TFMessage)
        assert out == TFMessage(transforms=[t, t]), out
        print("ok", len(serialize_message(TFMessage(transforms=[t]))))
    """)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(stage), env.get("PYTHONPATH", "")])
    env["LD_LIBRARY_PATH"] = os.pathsep.join([str(stage / "lib"), env.get("LD_LIBRARY_PATH", "")])
    res = subprocess.run([sys.executable, "-c", code, str(stage)], capture_output=True, text=True, env=env, timeout=120)
    assert res.returncode == 0 and res.stdout.startswith("ok"), res.stdout + res.stderr
