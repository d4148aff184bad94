"""The :class:`Config` tree (one section per area) and its conversions: nested dict, dotted names, YAML files
(plain or ROS 2 parameter files), ``replace`` and :func:`load_config`."""

from __future__ import annotations

import dataclasses
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from deepbbs_ros.config.keys import did_you_mean
from deepbbs_ros.config.localization import LocalizationConfig
from deepbbs_ros.config.node import NodeConfig
from deepbbs_ros.config.odometry import OdometryConfig
from deepbbs_ros.config.offline import EvalConfig, TrainConfig
from deepbbs_ros.config.preprocess import PreprocessConfig
from deepbbs_ros.config.registration import ModelConfig, RegistrationConfig
from deepbbs_ros.errors import ConfigError


@dataclass
class Config:
    """The whole configuration; one section per area."""

    preprocess: PreprocessConfig = field(default_factory=PreprocessConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    registration: RegistrationConfig = field(default_factory=RegistrationConfig)
    node: NodeConfig = field(default_factory=NodeConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    localization: LocalizationConfig = field(default_factory=LocalizationConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)

    def validate(self) -> Config:
        for f in dataclasses.fields(self):
            getattr(self, f.name).validate()
        return self

    # -- conversion -----------------------------------------------------------------------------
    def to_dict(self) -> dict[str, dict[str, Any]]:
        """Nested plain dict (YAML/JSON friendly)."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> Config:
        """Build from nested sections; missing keys keep their defaults, unknown keys are errors."""
        data = dict(data or {})
        cfg = cls()
        sections = {f.name: f for f in dataclasses.fields(cls)}
        data = _nest_dotted(data, sections)
        for name, values in data.items():
            if name not in sections:
                hint = did_you_mean(name, list(sections) + list(cls().to_flat()))
                raise ConfigError(f"config: unknown section {name!r}" + (hint or f" (known: {', '.join(sections)})"))
            if values is None:
                continue
            if not isinstance(values, dict):
                raise ConfigError(f"config: section {name!r} must be a mapping, got {type(values).__name__}")
            setattr(cfg, name, _build_section(type(getattr(cfg, name)), name, values))
        return cfg.validate()

    def to_flat(self) -> dict[str, Any]:
        """Dotted names as used for ROS parameters: ``{"preprocess.voxel_size": 0.3, ...}``."""
        return {f"{s}.{k}": v for s, sec in self.to_dict().items() for k, v in sec.items()}

    @classmethod
    def from_flat(cls, flat: dict[str, Any]) -> Config:
        """Inverse of :meth:`to_flat`; keys without a dot are errors."""
        nested: dict[str, dict[str, Any]] = {}
        for key, value in flat.items():
            section, sep, name = key.partition(".")
            if not sep or not name:
                raise ConfigError(f"config: parameter {key!r} is not of the form 'section.name'")
            nested.setdefault(section, {})[name] = value
        return cls.from_dict(nested)

    def replace(self, **flat: Any) -> Config:
        """A copy with some dotted keys changed: ``cfg.replace(**{"preprocess.num_points": 512})``."""
        merged = self.to_flat()
        for key in flat:
            if key not in merged:
                raise ConfigError(f"config: unknown parameter {key!r}{did_you_mean(key, merged)}")
        merged.update(flat)
        return Config.from_flat(merged)

    @classmethod
    def from_yaml(cls, path: str | Path) -> Config:
        """Load plain sections, or a ROS 2 parameter file (``<node>: ros__parameters: ...``)."""
        import yaml

        path = Path(path)
        try:
            data = yaml.safe_load(path.read_text())
        except FileNotFoundError as err:
            raise ConfigError(f"config: file not found: {path}") from err
        except yaml.YAMLError as err:
            raise ConfigError(f"config: {path} is not valid YAML: {err}".replace("\n", " ")) from err
        if data is None:
            return cls()
        if not isinstance(data, dict):
            raise ConfigError(f"config: {path} must hold a mapping at the top level")
        data = _unwrap_ros_params(data)
        try:
            return cls.from_dict(data)
        except ConfigError as err:
            raise ConfigError(f"{err} (in {path})") from err

    def to_yaml(self, path: str | Path | None = None, node_name: str | None = None) -> str:
        """Dump as YAML; with ``node_name`` as a ROS 2 parameter file. Writes ``path`` if given."""
        import yaml

        data: dict[str, Any] = self.to_dict()
        if node_name:
            data = {node_name: {"ros__parameters": data}}
        text = yaml.safe_dump(data, sort_keys=False)
        if path is not None:
            Path(path).write_text(text)
        return text


def _unwrap_ros_params(data: dict[str, Any]) -> dict[str, Any]:
    """``{node: {ros__parameters: {...}}}`` or ``{/**: {ros__parameters: ...}}`` -> the inner dict."""
    if len(data) == 1:
        (inner,) = data.values()
        if isinstance(inner, dict) and "ros__parameters" in inner:
            params = dict(inner["ros__parameters"])
            params.pop("use_sim_time", None)
            return params
    return data


def _nest_dotted(data: dict[str, Any], sections: Any) -> dict[str, Any]:
    """Dotted top-level keys of a known section (``preprocess.voxel_size: 0.3``, as a ROS 2 parameter file
    may write them) moved into their section; a key given both ways is an error."""
    out: dict[str, Any] = {}
    dotted = []
    for key, value in data.items():
        section, sep, name = str(key).partition(".")
        if sep and name and section in sections:
            dotted.append((key, section, name, value))
        else:
            out[key] = value
    for key, section, name, value in dotted:
        inner = out.get(section)
        if inner is None:
            inner = out[section] = {}
        elif not isinstance(inner, dict):
            continue  # from_dict names the bad section
        else:
            inner = out[section] = dict(inner)
        if name in inner:
            raise ConfigError(f"config: {key} is given twice (as {key} and under {section}:)")
        inner[name] = value
    return out


def _build_section(cls: type, section: str, values: dict[str, Any]) -> Any:
    hints = typing.get_type_hints(cls)
    known = {f.name for f in dataclasses.fields(cls)}
    kwargs = {}
    for key, value in values.items():
        if key not in known:
            hint = did_you_mean(f"{section}.{key}", Config().to_flat())
            raise ConfigError(f"config: unknown parameter {section}.{key}"
                              + (hint or f" (known in {section}: {', '.join(sorted(known))})"))
        kwargs[key] = _coerce(value, hints[key], f"{section}.{key}")
    return cls(**kwargs)


def _coerce(value: Any, hint: Any, key: str) -> Any:
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        for arg in typing.get_args(hint):
            if arg is type(None) and value is None:
                return None
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        return _coerce(value, args[0], key)
    if origin is list:
        (item,) = typing.get_args(hint)
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"config: {key} must be a list, got {value!r}")
        return [_coerce(v, item, f"{key}[{i}]") for i, v in enumerate(value)]
    if hint is bool:
        if isinstance(value, bool):
            return value
        raise ConfigError(f"config: {key} must be true or false, got {value!r}")
    if hint is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        if isinstance(value, float) and value.is_integer():
            return int(value)
        raise ConfigError(f"config: {key} must be an integer, got {value!r}")
    if hint is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        raise ConfigError(f"config: {key} must be a number, got {value!r}")
    if hint is str:
        if isinstance(value, str):
            return value
        if isinstance(value, bool):  # YAML 1.1 and ROS parameters (-p name:=on / off) read on / off as booleans
            return "on" if value else "off"
        raise ConfigError(f"config: {key} must be a string, got {value!r}")
    return value


def load_config(path: str | Path | None = None, overrides: dict[str, Any] | None = None) -> Config:
    """Defaults, then a YAML file (if given), then dotted overrides: the order every CLI uses."""
    cfg = Config.from_yaml(path) if path else Config()
    if overrides:
        cfg = cfg.replace(**overrides)
    return cfg
