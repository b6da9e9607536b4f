"""Pipeline configuration: TOML -> frozen dataclasses, validated, hashed and written back.

A configuration says which topic plays which role, the vehicle's geometry, sensor timing,
and the settings of every stage (the paper's names and units in the key names). The
built-in default, ``toolkit/default_config.toml``, is a byte-identical copy of
``pipelines/stanley2005.toml``; a user's file may give any subset of its keys (missing keys
take the default) but never an unknown one, so a typo fails loudly instead of being ignored.

Every error is a :class:`~toolkit.errors.ConfigError` naming the file, the dotted key and
the offending value. :func:`config_hash` hashes a canonical JSON form, so two runs with the
same settings agree, and :func:`dump_toml` writes the configuration in force (``WS/config.toml``)
in a form that :func:`load_config` reads back to an equal object.

The package's modules: :mod:`~toolkit.config.sections` (the dataclasses and their rules),
:mod:`~toolkit.config.loading` (TOML read over the default and checked) and
:mod:`~toolkit.config.dump` (hash and TOML text). Import from ``toolkit.config``.
"""

from toolkit.config.dump import (
    config_hash,
    dump_toml,
    escape_controls,
    to_dict,
    toml_value,
)
from toolkit.config.loading import (
    default_config,
    load_config,
    parse_config,
)
from toolkit.config.sections import (
    CONFIG_FORMAT,
    DEFAULT_CONFIG_RESOURCE,
    INT64_MAX,
    INT64_MIN,
    MAX_SENSOR_TIME_NS,
    MULTI_TOPIC_ROLES,
    ROLES,
    SECTIONS,
    TIMED_ROLES,
    EvaluateConfig,
    ImuConfig,
    LabelConfig,
    LearnConfig,
    LidarConfig,
    ModelConfig,
    OnlineLearnConfig,
    PipelineConfig,
    PoseConfig,
    ProjectConfig,
    RoleTimesNs,
    Rule,
    TablesConfig,
    TimeConfig,
    TopicsConfig,
    VehicleConfig,
)

__all__ = [
    "CONFIG_FORMAT",
    "DEFAULT_CONFIG_RESOURCE",
    "INT64_MAX",
    "INT64_MIN",
    "MAX_SENSOR_TIME_NS",
    "ROLES",
    "SECTIONS",
    "MULTI_TOPIC_ROLES",
    "TIMED_ROLES",
    "EvaluateConfig",
    "LabelConfig",
    "LearnConfig",
    "ModelConfig",
    "PipelineConfig",
    "PoseConfig",
    "ImuConfig",
    "OnlineLearnConfig",
    "LidarConfig",
    "ProjectConfig",
    "RoleTimesNs",
    "Rule",
    "TablesConfig",
    "TimeConfig",
    "TopicsConfig",
    "VehicleConfig",
    "config_hash",
    "default_config",
    "dump_toml",
    "load_config",
    "parse_config",
    "to_dict",
    "escape_controls",
    "toml_value",
]
