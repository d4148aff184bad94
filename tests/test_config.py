"""The typed configuration: defaults, YAML (plain and ROS parameter files), flat ROS names, errors."""

from pathlib import Path

import pytest

from deepbbs_ros.config import Config, load_config
from deepbbs_ros.errors import ConfigError, DeepBBSError

ROOT = Path(__file__).resolve().parents[1]


def test_defaults_validate():
    cfg = Config().validate()
    assert cfg.preprocess.num_points == 512 and cfg.registration.polish == "gicp" and not cfg.registration.refine
    assert cfg.model.xi == pytest.approx(0.4)


def test_flat_round_trip():
    cfg = Config()
    flat = cfg.to_flat()
    assert flat["preprocess.voxel_size"] == cfg.preprocess.voxel_size
    assert Config.from_flat(flat) == cfg


def test_yaml_round_trip_plain_and_ros(tmp_path):
    cfg = Config().replace(**{"preprocess.num_points": 512, "model.dgcnn_widths": [32, 32, 64]})
    plain = tmp_path / "plain.yaml"
    ros = tmp_path / "ros.yaml"
    cfg.to_yaml(plain)
    cfg.to_yaml(ros, node_name="deepbbs_registration")
    assert Config.from_yaml(plain) == cfg
    assert Config.from_yaml(ros) == cfg


def test_shipped_param_file_loads():
    cfg = Config.from_yaml(ROOT / "config" / "deepbbs_ros.yaml")
    assert cfg == Config()


@pytest.mark.parametrize(
    ("data", "match"),
    [
        ({"nope": {}}, "unknown section 'nope'"),
        ({"preprocess": {"voxel": 1}}, r"unknown parameter preprocess\.voxel"),
        ({"preprocess": {"num_points": "many"}}, r"preprocess\.num_points must be an integer"),
        ({"preprocess": {"num_points": 1}}, r"preprocess\.num_points must be >= 3"),
        ({"registration": {"device": "tpu"}}, r"registration\.device"),
        ({"node": {"publish_tf": "yes"}}, r"node\.publish_tf must be true or false"),
        ({"model": {"emb_dims": 30, "n_heads": 4}}, r"model\.emb_dims must be divisible"),
    ],
)
def test_bad_values_name_the_key(data, match):
    with pytest.raises(ConfigError, match=match):
        Config.from_dict(data)


def test_errors_share_one_base(tmp_path):
    with pytest.raises(DeepBBSError, match="file not found"):
        load_config(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("preprocess: [1, 2\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(bad)


def test_overrides_apply_last(tmp_path):
    path = tmp_path / "c.yaml"
    Config().replace(**{"preprocess.num_points": 256}).to_yaml(path)
    cfg = load_config(path, {"preprocess.voxel_size": 0.5})
    assert cfg.preprocess.num_points == 256 and cfg.preprocess.voxel_size == 0.5
    with pytest.raises(ConfigError, match="unknown parameter"):
        load_config(None, {"preprocess.bogus": 1})


def test_fast_preset_only_changes_the_speed_keys():
    cfg = Config.from_yaml(ROOT / "config" / "deepbbs_ros_fast.yaml")
    assert cfg.preprocess.num_points == 256 and cfg.registration.max_deep_iters == 1
    assert cfg.replace(**{"preprocess.num_points": 512, "registration.max_deep_iters": 2}) == Config()


def test_on_off_read_as_booleans_are_the_words():
    """ROS parameters and YAML 1.1 read ``on`` / ``off`` as booleans: a string setting takes them as the words."""
    cfg = Config.from_flat({"node.registration_process": True, "registration.network_process": False})
    assert (cfg.node.registration_process, cfg.registration.network_process) == ("on", "off")
    with pytest.raises(ConfigError, match="node.registration_process"):
        Config.from_flat({"node.registration_process": "maybe"})


@pytest.mark.parametrize(
    ("yaml_text", "match"),
    [  # one line naming the key and the closest valid key(s), not the section's whole key list
        ("eval:\n  strid: 10\n", r"^config: unknown parameter eval\.strid; did you mean eval\.stride\? \(in "),
        ("preprocess:\n  voxel: 0.3\n", r"unknown parameter preprocess\.voxel; did you mean preprocess\.voxel_size\?"),
        ("eval:\n  num_points: 9\n", r"eval\.num_points; did you mean preprocess\.num_points or train\.num_points\?"),
        ("evl:\n  stride: 10\n", r"unknown section 'evl'; did you mean eval\?"),
        ("voxel_size: 0.3\n", r"unknown section 'voxel_size'; did you mean preprocess\.voxel_size or "
                               r"odometry\.voxel_size\?"),
        ("/**:\n  ros__parameters:\n    node:\n      mod: pair\n",
         r"unknown parameter node\.mod; did you mean node\.mode\?"),
    ],
)
def test_misspelt_key_names_the_nearest(tmp_path, yaml_text, match):
    path = tmp_path / "c.yaml"
    path.write_text(yaml_text)
    with pytest.raises(ConfigError, match=match) as info:
        load_config(path)
    text = str(info.value)
    assert "\n" not in text and "(known" not in text and len(text) < 200 + len(str(path))


def test_unknown_key_without_a_near_one_lists_its_section():
    with pytest.raises(ConfigError, match=r"unknown parameter eval\.zzzzzz \(known in eval: .*stride"):
        Config.from_dict({"eval": {"zzzzzz": 1}})
    with pytest.raises(ConfigError, match=r"unknown parameter 'eval\.strid'; did you mean eval\.stride\?"):
        load_config(None, {"eval.strid": 3})  # --set / CLI overrides


def test_dotted_keys_in_a_file(tmp_path):
    """A ROS 2 parameter file may write dotted names (``preprocess.voxel_size: 0.4``), as ``-p`` does."""
    path = tmp_path / "p.yaml"
    path.write_text("/**:\n  ros__parameters:\n    preprocess.voxel_size: 0.4\n"
                    "    preprocess:\n      num_points: 256\n")
    cfg = load_config(path)
    assert cfg.preprocess.voxel_size == 0.4 and cfg.preprocess.num_points == 256
    path.write_text("preprocess.voxel_size: 0.4\npreprocess:\n  voxel_size: 0.5\n")
    with pytest.raises(ConfigError, match=r"preprocess\.voxel_size is given twice"):
        load_config(path)


def test_node_and_config_share_the_did_you_mean():
    from deepbbs_ros.config import nearest_keys

    flat = Config().to_flat()
    assert nearest_keys("node.mod", flat) == ["node.mode"]
    assert nearest_keys("base_frame", flat) == ["node.base_frame"]
    assert nearest_keys("qqqq.zzzz", flat) == []
    node = pytest.importorskip("deepbbs_ros.node.parameters")
    assert node.nearest_parameter is nearest_keys
