"""launch/deepbbs_registration.launch.py, checked without ``launch``/``launch_ros`` (no PyPI wheels).

The file is compiled and its syntax tree inspected (nothing is imported or stubbed): it must start the
executable that setup.py installs where ``ros2 run`` / launch_ros look (lib/deepbbs_ros), under the
node name the shipped parameter file is keyed by, with that file (installed to share/deepbbs_ros/config)
as the default ``params_file``, the node's real input names as remappings, and the shipped Fast DDS
profile in the node's environment.
"""

from __future__ import annotations

import ast
import configparser
import py_compile
import re
from pathlib import Path

import yaml

from deepbbs_ros.config import Config
from deepbbs_ros.node import parameters, registration_node
from deepbbs_ros.node import remaps as node_remaps
from deepbbs_ros.node.dds import PROFILE_ENV_VARS, default_profile_path, profile_env

REPO = Path(__file__).resolve().parents[1]
LAUNCH = REPO / "launch" / "deepbbs_registration.launch.py"


def _tree() -> ast.Module:
    return ast.parse(LAUNCH.read_text(), filename=str(LAUNCH))


def _calls(tree: ast.AST, name: str) -> list[ast.Call]:
    out = []
    for n in ast.walk(tree):
        if isinstance(n, ast.Call):
            f = n.func
            if (isinstance(f, ast.Name) and f.id == name) or (isinstance(f, ast.Attribute) and f.attr == name):
                out.append(n)
    return out


def _kw(call: ast.Call, key: str) -> ast.expr:
    for k in call.keywords:
        if k.arg == key:
            return k.value
    raise AssertionError(f"{ast.unparse(call.func)}(...) has no {key}= argument")


def _node_call() -> ast.Call:
    nodes = _calls(_tree(), "Node")
    assert len(nodes) == 1, "exactly one launch_ros Node expected"
    return nodes[0]


def test_launch_file_compiles(tmp_path):
    py_compile.compile(str(LAUNCH), cfile=str(tmp_path / "launch.pyc"), doraise=True)
    tree = _tree()
    funcs = [n.name for n in tree.body if isinstance(n, ast.FunctionDef)]
    assert "generate_launch_description" in funcs
    imported = {
        (n.module if isinstance(n, ast.ImportFrom) else a.name).split(".")[0]
        for n in ast.walk(tree)
        if isinstance(n, (ast.Import, ast.ImportFrom))
        for a in n.names
    }
    # only ROS launch machinery, the standard library and this package
    assert imported <= {"os", "sys", "launch", "launch_ros", "ament_index_python", "deepbbs_ros"}, imported


def test_launch_starts_the_installed_executable():
    node = _node_call()
    assert ast.literal_eval(_kw(node, "package")) == "deepbbs_ros"
    executable = ast.literal_eval(_kw(node, "executable"))
    assert ast.literal_eval(_kw(node, "name")) == registration_node.NODE_NAME
    # setup.py declares that console script, pointing at the node's main ...
    setup = (REPO / "setup.py").read_text()
    m = re.search(rf'"{re.escape(executable)}\s*=\s*([\w.]+):(\w+)"', setup)
    assert m, f"console script {executable!r} not in setup.py"
    assert (m.group(1), m.group(2)) == ("deepbbs_ros.node.registration_node", "main")
    # ... and setup.cfg installs scripts into lib/<package>, where launch_ros / ros2 run look for them
    cfg = configparser.ConfigParser(interpolation=None)
    cfg.read(REPO / "setup.cfg")
    assert cfg["install"]["install_scripts"] == "$base/lib/deepbbs_ros"
    assert cfg["develop"]["script_dir"] == "$base/lib/deepbbs_ros"


def test_launch_default_params_file_is_the_shipped_yaml():
    tree = _tree()
    decl = _declared()
    default = _kw(decl["params_file"], "default_value")
    # os.path.join(get_package_share_directory("deepbbs_ros"), "config", "deepbbs_ros.yaml")
    assert isinstance(default, ast.Call) and ast.unparse(default.func) == "os.path.join", ast.unparse(default)
    parts = [ast.literal_eval(a) for a in default.args[1:]]
    share = default.args[0]
    if isinstance(share, ast.Name):  # share = get_package_share_directory("deepbbs_ros") assigned above
        assigns = [n for n in ast.walk(tree) if isinstance(n, ast.Assign)
                   and any(isinstance(t, ast.Name) and t.id == share.id for t in n.targets)]
        share = assigns[0].value
    assert ast.unparse(share) == "get_package_share_directory('deepbbs_ros')"
    rel = Path(*parts)
    assert rel == Path("config", "deepbbs_ros.yaml")
    # setup.py installs config/* into share/deepbbs_ros/config
    assert '("share/" + package_name + "/config", glob("config/*"))' in (REPO / "setup.py").read_text()
    shipped = REPO / rel
    assert shipped.is_file()
    # the node's parameters are the first entry (config_file, KISS-ICP's name, defaulting to params_file); the
    # YAML is keyed by the /** wildcard (any node name)
    params = _kw(_node_call(), "parameters")
    assert isinstance(params, ast.List) and ast.unparse(params.elts[0]) == "LaunchConfiguration('config_file')"
    assert _resolve(_declared(), "config_file", {}) == _resolve(_declared(), "params_file", {})
    assert _resolve(_declared(), "config_file", {"params_file": "/mine.yaml"}) == "/mine.yaml"
    assert _resolve(_declared(), "config_file", {"config_file": "/kiss.yaml"}) == "/kiss.yaml"
    doc = yaml.safe_load(shipped.read_text())
    assert list(doc) == ["/**"] and "ros__parameters" in doc["/**"]
    # every parameter it sets is one the node declares in odometry mode or localization (other modes note them as
    # unused)
    flat: dict[str, object] = {}

    def walk(d: dict, prefix: str = "") -> None:
        for k, v in d.items():
            if isinstance(v, dict):
                walk(v, f"{prefix}{k}.")
            else:
                flat[f"{prefix}{k}"] = v

    walk(doc["/**"]["ros__parameters"])
    declared = {**parameters.node_parameters(Config(), "odometry"),
                **parameters.node_parameters(Config(), "pair", "localization")}
    unknown = sorted(set(flat) - set(declared))
    assert not unknown, f"{shipped.name} sets parameters the node does not declare: {unknown}"
    # the override dict sets node.mode and use_sim_time from launch arguments
    override = ast.unparse(params.elts[1])
    assert "'node.mode': LaunchConfiguration('mode')" in override and "'use_sim_time'" in override


def test_launch_remaps_the_node_inputs():
    declared = set(_declared())
    remaps = _kw(_node_call(), "remappings")
    pairs = {ast.literal_eval(t.elts[0]): ast.unparse(t.elts[1]) for t in remaps.elts}
    inputs = (*node_remaps.PAIR_INPUTS, node_remaps.ODOM_INPUT)
    assert set(pairs) == set(inputs)
    for name in inputs:
        assert pairs[name] == f"LaunchConfiguration('{name}')" and name in declared
    assert {"params_file", "mode", "use_sim_time"} <= declared


def test_launch_applies_the_fastdds_profile():
    node = _node_call()
    env = _kw(node, "additional_env")
    assert ast.unparse(env) == "profile_env()"
    imports = [n for n in ast.walk(_tree()) if isinstance(n, ast.ImportFrom) and n.module == "deepbbs_ros.node.dds"]
    assert imports and any(a.name == "profile_env" for a in imports[0].names)
    # what that call gives at launch time: the shipped profile (installed as package data) ...
    assert default_profile_path().is_file()
    assert re.search(r'"deepbbs_ros\.resources": \[[^]]*"\*\.xml"', (REPO / "setup.py").read_text())  # test_packaging
    assert profile_env({}) == {k: str(default_profile_path()) for k in PROFILE_ENV_VARS}
    # ... unless the user chose a profile or another RMW
    assert profile_env({"FASTDDS_DEFAULT_PROFILES_FILE": "/mine.xml"}) == {}
    assert profile_env({"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}) == {}


def _declared() -> dict[str, ast.Call]:
    decl: dict[str, ast.Call] = {}
    for c in _calls(_tree(), "DeclareLaunchArgument"):
        name = c.args[0]
        if isinstance(name, ast.Constant):
            decl[name.value] = c
    # DeclareLaunchArgument(kiss, default_value=LaunchConfiguration(ours)) for kiss, ours in KISS_ICP_ALIASES
    aliases = [n for n in _tree().body if isinstance(n, ast.Assign)
               and any(isinstance(t, ast.Name) and t.id == "KISS_ICP_ALIASES" for t in n.targets)]
    if aliases:
        for kiss, ours in ast.literal_eval(aliases[0].value).items():
            decl[kiss] = ast.parse(f"DeclareLaunchArgument({kiss!r}, default_value=LaunchConfiguration({ours!r}))",
                                   mode="eval").body
    return decl


def _resolve(decl: dict[str, ast.Call], name: str, given: dict[str, str]) -> str:
    """A launch argument's value as ``ros2 launch ... name:=value`` makes it: ``given``, else its default, a
    literal or another argument (``LaunchConfiguration('x')``, followed)."""
    if name in given:
        return given[name]
    default = _kw(decl[name], "default_value")
    if isinstance(default, ast.Call) and ast.unparse(default.func) == "LaunchConfiguration":
        return _resolve(decl, ast.literal_eval(default.args[0]), given)
    if isinstance(default, ast.Constant):
        return str(default.value)
    return ast.unparse(default)


def _node_setting(param: str, given: dict[str, str]) -> str:
    """The value the launch file gives the node's ``param`` with arguments ``given``."""
    override = _kw(_node_call(), "parameters").elts[1]
    value = dict(zip([ast.literal_eval(k) for k in override.keys], override.values))[param]
    if isinstance(value, ast.Call) and ast.unparse(value.func) == "ParameterValue":
        value = value.args[0]
    assert isinstance(value, ast.Call) and ast.unparse(value.func) == "LaunchConfiguration", ast.unparse(value)
    return _resolve(_declared(), ast.literal_eval(value.args[0]), given)


def test_launch_has_the_arguments_kiss_icp_users_expect():
    """This file's names and KISS-ICP's current ones (ros/launch/odometry.launch.py: topic, base_frame,
    lidar_odom_frame, publish_odom_tf, invert_odom_tf, visualize, use_sim_time, bagfile, config_file,
    position_covariance, orientation_covariance) set the same node settings; KISS-ICP's name wins when both
    are given; the defaults are the node's own."""
    decl = _declared()
    kiss = {"topic", "base_frame", "lidar_odom_frame", "publish_odom_tf", "invert_odom_tf", "visualize",
            "use_sim_time", "bagfile", "config_file", "position_covariance", "orientation_covariance"}
    ours = {"odom_frame", "publish_tf", "invert_tf", "target_mode", "mode", "params_file"}
    assert kiss | ours <= set(decl), sorted(kiss | ours - set(decl))
    assert ast.unparse(_kw(decl["cloud"], "default_value")) == "LaunchConfiguration('topic')"  # topic:= feeds cloud
    flat = Config().to_flat()
    for param, our_arg, kiss_arg, value in [
        ("node.odom_frame", "odom_frame", "lidar_odom_frame", "odom_lidar"),
        ("node.publish_tf", "publish_tf", "publish_odom_tf", "false"),
        ("node.invert_tf", "invert_tf", "invert_odom_tf", "true"),
        ("node.base_frame", "base_frame", "base_frame", ""),
        ("node.target_mode", "target_mode", "target_mode", "latched"),
        ("localization.map_path", "map_path", "map_path", "/maps/town.pcd"),
        ("use_sim_time", "use_sim_time", "use_sim_time", "true"),
        ("node.publish_aligned_cloud", "visualize", "visualize", "true"),
    ]:
        if param in flat:  # the node's own default when nothing is given
            assert _node_setting(param, {}).lower() == str(flat[param]).lower(), (param, _node_setting(param, {}))
        assert _node_setting(param, {our_arg: value}) == value, (param, our_arg)
        assert _node_setting(param, {kiss_arg: value}) == value, (param, kiss_arg)
        assert _node_setting(param, {our_arg: "other", kiss_arg: value}) == value, (param, "KISS-ICP's name wins")
    # the covariances: accepted, not used, said so in one line when given
    text = LAUNCH.read_text()
    assert "LogInfo" in text and "position_covariance" in text and "orientation_covariance" in text
    for name in ("position_covariance", "orientation_covariance"):
        assert _resolve(decl, name, {}) == ""


def test_launch_bagfile_plays_into_the_node():
    """bagfile:= starts deepbbs-play on it, only when given: odometry mode on the node's cloud topic; pair mode
    the scan on source_cloud and the scan before it on target_cloud (--previous-topic), so that they pair."""
    from deepbbs_ros.cli.play import build_parser

    decl = _declared()
    assert _resolve(decl, "bagfile", {}) == ""
    plays = [c for c in _calls(_tree(), "ExecuteProcess") if "bagfile" in ast.unparse(c)]
    assert len(plays) == 2, [ast.unparse(c) for c in plays]
    text = LAUNCH.read_text()
    assert "'-m', 'deepbbs_ros.cli.play'" in ast.unparse(_tree()) and '"--previous-topic"' in text
    flags = {a for action in build_parser()._actions for a in action.option_strings}
    for flag in ("--cloud-topic", "--previous-topic", "--wait", "--quiet"):
        assert flag in flags and f'"{flag}"' in text
    conditions = sorted(ast.unparse(_kw(c, "condition")) for c in plays)
    assert conditions == ["IfCondition(_bag_and_mode('odometry'))", "IfCondition(_bag_and_mode('pair'))"]
    pair = next(c for c in plays if "pair" in ast.unparse(_kw(c, "condition")))
    cmd = ast.unparse(_kw(pair, "cmd"))
    assert ("'--cloud-topic', LaunchConfiguration('source_cloud'), '--previous-topic', "
            "LaunchConfiguration('target_cloud')") in cmd, cmd
    odom = next(c for c in plays if "odometry" in ast.unparse(_kw(c, "condition")))
    assert "'--cloud-topic', LaunchConfiguration('cloud')" in ast.unparse(_kw(odom, "cmd"))


def test_rviz_config_is_shipped_and_shows_the_outputs():
    rviz = REPO / "rviz" / "deepbbs_ros.rviz"
    assert '("share/" + package_name + "/rviz", glob("rviz/*.rviz"))' in (REPO / "setup.py").read_text()
    doc = yaml.safe_load(rviz.read_text())
    displays = {d["Name"]: d for d in doc["Visualization Manager"]["Displays"]}
    topic = {name: d.get("Topic", {}).get("Value") for name, d in displays.items()}
    node = "/" + registration_node.NODE_NAME
    assert displays["Input cloud"]["Class"] == "rviz_default_plugins/PointCloud2" and topic["Input cloud"]
    assert topic["Aligned cloud"] == f"{node}/aligned_cloud"
    assert displays["Trajectory"]["Class"] == "rviz_default_plugins/Odometry"
    assert topic["Trajectory"] == f"{node}/odometry"
    assert "rviz_default_plugins/TF" in {d["Class"] for d in displays.values()}
    assert doc["Visualization Manager"]["Global Options"]["Fixed Frame"] == Config().node.odom_frame
    assert "rviz" in ast.unparse(_tree()) and "deepbbs_ros.rviz" in LAUNCH.read_text()
