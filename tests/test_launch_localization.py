"""launch/localization.launch.py and config/nav2_localization.yaml, checked without ``launch`` / ``launch_ros`` / Nav2
(no PyPI wheels): the launch file's syntax tree is inspected (nothing imported or stubbed), the params file is
loaded into the typed config and, with real rclpy, into the managed node under its name."""

from __future__ import annotations

import ast
import py_compile
import re
from pathlib import Path

import yaml

from deepbbs_ros.config import Config
from deepbbs_ros.node import managed, parameters
from deepbbs_ros.node import remaps as node_remaps

REPO = Path(__file__).resolve().parents[1]
LAUNCH = REPO / "launch" / "localization.launch.py"
PARAMS = REPO / "config" / "nav2_localization.yaml"


def _tree() -> ast.Module:
    return ast.parse(LAUNCH.read_text(), filename=str(LAUNCH))


def _calls(name: str) -> list[ast.Call]:
    return [n for n in ast.walk(_tree()) if isinstance(n, ast.Call)
            and ((isinstance(n.func, ast.Name) and n.func.id == name)
                 or (isinstance(n.func, ast.Attribute) and n.func.attr == name))]


def _kw(call: ast.Call, key: str) -> ast.expr:
    for k in call.keywords:
        if k.arg == key:
            return k.value
    raise AssertionError(f"{ast.unparse(call.func)}(...) has no {key}= argument")


def _constants() -> dict[str, object]:
    return {t.id: ast.literal_eval(n.value) for n in _tree().body if isinstance(n, ast.Assign)
            for t in n.targets if isinstance(t, ast.Name) and isinstance(n.value, ast.Constant)}


def _declared() -> dict[str, str]:
    """launch argument -> its default (source text)."""
    return {ast.literal_eval(c.args[0]): ast.unparse(_kw(c, "default_value")) for c in _calls("DeclareLaunchArgument")}


def _flat(section: dict) -> dict[str, object]:
    out: dict[str, object] = {}

    def walk(d: dict, prefix: str = "") -> None:
        for k, v in d.items():
            if isinstance(v, dict):
                walk(v, f"{prefix}{k}.")
            else:
                out[f"{prefix}{k}"] = v

    walk(section)
    return out


def test_launch_file_compiles_and_declares_nav2s_arguments(tmp_path):
    py_compile.compile(str(LAUNCH), cfile=str(tmp_path / "launch.pyc"), doraise=True)
    tree = _tree()
    assert "generate_launch_description" in [n.name for n in tree.body if isinstance(n, ast.FunctionDef)]
    imported = {(n.module if isinstance(n, ast.ImportFrom) else a.name).split(".")[0]
                for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom)) for a in n.names}
    assert imported <= {"os", "launch", "launch_ros", "ament_index_python", "lifecycle_msgs", "deepbbs_ros"}, imported
    decl = _declared()
    # nav2_bringup's localization_launch.py arguments, and the scans' topic
    assert {"namespace", "use_sim_time", "autostart", "params_file", "map", "log_level", "cloud"} <= set(decl)
    defaults = (decl["namespace"], decl["use_sim_time"], decl["autostart"], decl["map"])
    assert defaults == ("''", "'false'", "'true'", "''")
    assert decl["params_file"] == "os.path.join(share, 'config', 'nav2_localization.yaml')"
    assert '("share/" + package_name + "/config", glob("config/*"))' in (REPO / "setup.py").read_text()
    assert '("share/" + package_name + "/launch", glob("launch/*.py"))' in (REPO / "setup.py").read_text()


def test_launch_starts_the_managed_node_and_the_lifecycle_manager():
    consts = _constants()
    assert consts["NODE_NAME"] == managed.NODE_NAME and consts["MANAGER_NAME"] == "lifecycle_manager_localization"
    (node,) = _calls("LifecycleNode")
    assert ast.literal_eval(_kw(node, "package")) == "deepbbs_ros"
    executable = ast.literal_eval(_kw(node, "executable"))
    m = re.search(rf'"{re.escape(executable)}\s*=\s*([\w.]+):(\w+)"', (REPO / "setup.py").read_text())
    assert m and (m.group(1), m.group(2)) == ("deepbbs_ros.node.managed", "main"), executable
    assert ast.unparse(_kw(node, "name")) == "NODE_NAME"
    params = _kw(node, "parameters")
    assert ast.unparse(params.elts[0]) == "LaunchConfiguration('params_file')"
    override = ast.unparse(params.elts[1])
    assert "'localization.map_path': ParameterValue(LaunchConfiguration('map'), value_type=str)" in override
    assert "'use_sim_time': use_sim_time" in override
    remaps = {ast.literal_eval(t.elts[0]): ast.unparse(t.elts[1]) for t in _kw(node, "remappings").elts}
    assert remaps == {node_remaps.PAIR_INPUTS[0]: "LaunchConfiguration('cloud')"}
    assert ast.unparse(_kw(node, "additional_env")) == "profile_env()"
    assert "'--log-level', LaunchConfiguration('log_level')" in ast.unparse(_kw(node, "arguments"))
    # the lifecycle manager: Nav2's executable, the node by name, autostart, only where it is to be used
    (manager,) = [c for c in _calls("Node") if "nav2_lifecycle_manager" in ast.unparse(c)]
    assert ast.literal_eval(_kw(manager, "executable")) == "lifecycle_manager"
    assert ast.unparse(_kw(manager, "name")) == "MANAGER_NAME"
    text = ast.unparse(_kw(manager, "parameters"))
    assert "'node_names': [NODE_NAME]" in text and "'autostart': autostart" in text
    assert ast.unparse(_kw(manager, "condition")) == "IfCondition(LaunchConfiguration('use_lifecycle_manager'))"
    # without it, autostart by launch_ros's lifecycle events: configure, then activate on reaching inactive
    emitted = {ast.unparse(_kw(c, "transition_id")) for c in _calls("ChangeState")}
    assert emitted == {"Transition.TRANSITION_CONFIGURE", "Transition.TRANSITION_ACTIVATE"}
    (handler,) = _calls("OnStateTransition")
    assert ast.literal_eval(_kw(handler, "goal_state")) == "inactive"


def test_params_file_is_nav2s_layout_and_loads_into_the_config(tmp_path):
    """config/nav2_localization.yaml: a section per node name; the localizer's keys are parameters the managed node
    declares (nested as it reads them), valid for the typed config; the manager's list the node, no bond."""
    doc = yaml.safe_load(PARAMS.read_text())
    assert list(doc) == [managed.NODE_NAME, "lifecycle_manager_localization"]
    flat = _flat(doc[managed.NODE_NAME]["ros__parameters"])
    assert flat.pop("use_sim_time") is False
    cfg = managed.localizer_defaults()
    declared = parameters.node_parameters(cfg, cfg.node.mode, cfg.node.target_mode)
    unknown = sorted(set(flat) - set(declared))
    assert not unknown, f"{PARAMS.name} sets parameters the managed node does not declare: {unknown}"
    loaded = Config.from_flat({**Config().to_flat(), **flat})  # types and ranges checked (ConfigError otherwise)
    assert loaded.node.target_mode == "localization" and loaded.localization.map_path == ""
    # the same section as a one-node parameter file reads with --config too
    one = tmp_path / "one.yaml"
    one.write_text(yaml.safe_dump({managed.NODE_NAME: doc[managed.NODE_NAME]}))
    assert Config.from_yaml(one).to_flat() == loaded.to_flat()
    lm = doc["lifecycle_manager_localization"]["ros__parameters"]
    assert lm["node_names"] == [managed.NODE_NAME] and lm["autostart"] is True and lm["bond_timeout"] == 4.0
    assert lm["service_timeout"] >= 30.0  # configure (model, map, warm-up) takes seconds: more than Nav2's 5 s default


def test_params_file_reaches_the_node_under_its_name(tmp_path):
    """Real rclpy: the shipped file given with --params-file applies to the managed node by its default name (the
    key is Nav2's plain node name), and every key is one the node declares (no warning)."""
    import pytest

    rclpy = pytest.importorskip("rclpy")
    from rclpy.context import Context

    doc = yaml.safe_load(PARAMS.read_text())
    doc[managed.NODE_NAME]["ros__parameters"]["localization"]["min_probability"] = 0.65
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(doc))
    ctx = Context()
    rclpy.init(args=["x", "--ros-args", "--params-file", str(path)], context=ctx)
    try:
        node = managed.LocalizerNode(context=ctx)
        try:
            assert node.get_name() == managed.NODE_NAME and node.parameter_warnings == []
            assert node.get_parameter("localization.min_probability").value == 0.65
            assert node.get_parameter("node.target_mode").value == "localization"
        finally:
            node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)
