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
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
import hashlib
import importlib.resources
import json
import math
import tomllib
import types
import typing
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, TypeVar

from toolkit.errors import ConfigError

#: The range of every integer setting (they end up in int64 arrays).
INT64_MIN, INT64_MAX = -(2**63), 2**63 - 1
#: Largest declared latency or clock offset of a sensor (ns): one day.
MAX_SENSOR_TIME_NS = 86_400 * 10**9

#: Bumped when the meaning of existing keys changes; part of every config hash.
CONFIG_FORMAT = 1

#: File name of the packaged default configuration (inside the ``toolkit`` package).
DEFAULT_CONFIG_RESOURCE = "default_config.toml"

#: Topic roles, in the order ingest reports them. Any role may be absent from a vehicle
#: (``""``, or ``[]`` for lasers, in the file): ingest converts the roles a log has, and a
#: stage that needs a missing role refuses with one line naming it.
ROLES: tuple[str, ...] = (
    "lasers",
    "imu",
    "gps",
    "heading",
    "wheels",
    "tf_static",
    "truth_pose",
    "truth_features",
)
#: Sensor roles that carry declared latencies and clock offsets.
TIMED_ROLES: tuple[str, ...] = ("lasers", "imu", "gps", "heading", "wheels")

_T = TypeVar("_T")


@dataclass(frozen=True)
class Rule:
    """Validation rules of one setting, attached with ``Annotated[type, Rule(...)]``.

    Bounds apply to the number, or to each element of a list; length rules to the list.
    """

    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    choices: tuple[str, ...] | None = None
    length: int | None = None
    min_length: int | None = None
    nonempty: bool = False
    unique: bool = False


_NO_RULE = Rule()


# --------------------------------------------------------------------------------------
# The configuration, section by section
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TopicsConfig:
    """Which topic plays which role; a role the vehicle lacks is ``None`` (``()`` for lasers)."""

    lasers: Annotated[tuple[str, ...], Rule(nonempty=True, unique=True)]
    imu: str | None
    gps: str | None
    heading: str | None
    wheels: str | None
    tf_static: str | None
    truth_pose: str | None
    truth_features: str | None

    def by_role(self) -> dict[str, tuple[str, ...]]:
        """Role -> topics (lasers may be several), leaving out absent roles."""
        out: dict[str, tuple[str, ...]] = {}
        if self.lasers:
            out["lasers"] = self.lasers
        for role in ROLES[1:]:
            topic = getattr(self, role)
            if topic is not None:
                out[role] = (topic,)
        return out

    def absent_roles(self) -> tuple[str, ...]:
        """Roles the configuration says the vehicle does not have."""
        present = self.by_role()
        return tuple(role for role in ROLES if role not in present)

    def role_of(self, topic: str) -> str | None:
        """The role a topic plays, or None if the configuration does not use it."""
        for role, topics in self.by_role().items():
            if topic in topics:
                return role
        return None


@dataclass(frozen=True)
class VehicleConfig:
    """Vehicle geometry; base_link is on the ground below the rear-axle centre (x fwd, z up)."""

    model: str
    wheelbase_m: Annotated[float, Rule(gt=0.0)]
    track_m: Annotated[float, Rule(gt=0.0)]
    wheel_radius_m: Annotated[float, Rule(gt=0.0)]
    base_frame: Annotated[str, Rule(nonempty=True)]
    imu_frame: Annotated[str, Rule(nonempty=True)]
    gps_frame: Annotated[str, Rule(nonempty=True)]
    #: Mount positions within 100 m of base_link, orientations within one turn.
    imu_position_m: Annotated[tuple[float, ...], Rule(length=3, ge=-100.0, le=100.0)]
    imu_orientation_rad: Annotated[tuple[float, ...], Rule(length=3, ge=-6.3, le=6.3)]
    gps_antenna_position_m: Annotated[tuple[float, ...], Rule(length=3, ge=-100.0, le=100.0)]


@dataclass(frozen=True)
class RoleTimesNs:
    """One signed nanosecond value per timed sensor role, at most a day either way (a
    sensor clock a day off is a wrong date, not an offset; the bound also keeps every
    corrected stamp inside int64)."""

    lasers: Annotated[int, Rule(ge=-MAX_SENSOR_TIME_NS, le=MAX_SENSOR_TIME_NS)]
    imu: Annotated[int, Rule(ge=-MAX_SENSOR_TIME_NS, le=MAX_SENSOR_TIME_NS)]
    gps: Annotated[int, Rule(ge=-MAX_SENSOR_TIME_NS, le=MAX_SENSOR_TIME_NS)]
    heading: Annotated[int, Rule(ge=-MAX_SENSOR_TIME_NS, le=MAX_SENSOR_TIME_NS)]
    wheels: Annotated[int, Rule(ge=-MAX_SENSOR_TIME_NS, le=MAX_SENSOR_TIME_NS)]

    def for_role(self, role: str) -> int:
        """The value for a role (0 for roles without timing, e.g. tf_static)."""
        return int(getattr(self, role)) if role in TIMED_ROLES else 0


@dataclass(frozen=True)
class TimeConfig:
    """Declared sensor timing: corrected t = stamp + clock_offset_ns - latency_ns."""

    max_header_skew_ns: Annotated[int, Rule(gt=0)]
    latency_ns: RoleTimesNs
    clock_offset_ns: RoleTimesNs

    def correction_ns(self, role: str) -> int:
        """What to add to a stamp of this role to get the log-clock measurement time."""
        return self.clock_offset_ns.for_role(role) - self.latency_ns.for_role(role)


@dataclass(frozen=True)
class PoseConfig:
    """Unscented Kalman filter settings (sect. 3: GPS, compass, IMU, wheels at 100 Hz)."""

    output_rate_hz: Annotated[float, Rule(gt=0.0, le=1000.0)]
    gps_min_status: Annotated[int, Rule(ge=-1, le=2)]
    accel_noise_mps2: Annotated[float, Rule(gt=0.0)]
    gyro_noise_radps: Annotated[float, Rule(gt=0.0)]
    accel_bias_walk_mps2: Annotated[float, Rule(ge=0.0)]
    gyro_bias_walk_radps: Annotated[float, Rule(ge=0.0)]
    gps_noise_m: Annotated[float, Rule(gt=0.0)]
    gps_vertical_noise_m: Annotated[float, Rule(gt=0.0)]
    heading_noise_rad: Annotated[float, Rule(gt=0.0)]
    wheel_speed_noise_mps: Annotated[float, Rule(gt=0.0)]
    gate_chi2_gps: Annotated[float, Rule(gt=0.0)]
    gate_chi2_heading: Annotated[float, Rule(gt=0.0)]
    gate_chi2_wheels: Annotated[float, Rule(gt=0.0)]
    # Van der Merwe's spread: below 1e-3 the central weight (1 - n/(alpha^2 (n + kappa)))
    # reaches -1e7 and the sigma-point covariance loses all precision.
    sigma_alpha: Annotated[float, Rule(ge=1e-3, le=1.0)]
    sigma_beta: Annotated[float, Rule(ge=0.0)]
    #: Van der Merwe's kappa (0 or 3 - n in the literature): n + kappa must stay positive
    #: for the state's n of 15-17, so within [-10, 100].
    sigma_kappa: Annotated[float, Rule(ge=-10.0, le=100.0)]
    initial_position_std_m: Annotated[float, Rule(gt=0.0)]
    initial_velocity_std_mps: Annotated[float, Rule(gt=0.0)]
    initial_attitude_std_rad: Annotated[float, Rule(gt=0.0)]
    initial_wheel_scale_std: Annotated[float, Rule(gt=0.0)]
    wheel_scale_walk_per_sqrt_s: Annotated[float, Rule(ge=0.0)]
    reinit_after_gated_fixes: Annotated[int, Rule(ge=0)]
    orientation_noise_rad: Annotated[float, Rule(gt=0.0)]
    gate_chi2_attitude: Annotated[float, Rule(gt=0.0)]
    track_min_distance_m: Annotated[float, Rule(gt=0.0)]
    #: Without any GPS fix: ``inertial`` lets wheel and non-holonomic updates correct every
    #: state through the accelerometer (heading and gyro bias from the centripetal term, for a
    #: fast vehicle with a good IMU); ``odometry`` conditions them on position, yaw, z gyro
    #: bias and wheel scale, so the heading is the gyro's integral and the position the
    #: integral of the velocity the wheels measure (robot_localization's odom-frame practice,
    #: for a slow robot whose accelerometer errors at walking speed equal degrees per second
    #: of yaw rate). See ``toolkit.fusion.ukf.PoseUKF._conditioned``.
    dead_reckoning: Annotated[str, Rule(choices=("inertial", "odometry"))] = "inertial"


@dataclass(frozen=True)
class LabelConfig:
    """Data labeling (sect. 5): FIR high-pass of the z accelerometer, shock per event."""

    #: At most 1,000 taps (the paper's 40; 100,000 never finished): the filter's cost and
    #: its start-up transient grow with the length.
    fir_taps: Annotated[int, Rule(ge=3, le=1000)]
    fir_stop_hz: Annotated[float, Rule(gt=0.0)]
    #: Where the passband (gain 1 within 5 %) starts; must be above fir_stop_hz and below
    #: the IMU's Nyquist frequency (checked by the label stage, which knows the rate).
    fir_pass_hz: Annotated[float, Rule(gt=0.0)]
    #: From 0.1 m (one event a few IMU samples long at race speed; 1e-6 m made billions of
    #: events and 22.9 GB) to 1 km.
    event_length_m: Annotated[float, Rule(ge=0.1, le=1000.0)]
    shock_statistic: Annotated[str, Rule(choices=("max_abs", "rms"))]
    min_speed_mps: Annotated[float, Rule(ge=0.0)]
    rough_threshold_g_per_mph: Annotated[float, Rule(gt=0.0)]
    gravity_mps2: Annotated[float, Rule(gt=0.0)]
    #: Who owns a filtered impact (max_abs only): "impact", the one event whose span holds
    #: its crest, or "span_peak", every event the filter's response reaches (the peak over the
    #: span, as before issue 26). See toolkit.model.shock_attribution.
    attribution: Annotated[str, Rule(choices=("impact", "span_peak"))] = "impact"


@dataclass(frozen=True)
class ModelConfig:
    """Roughness model inputs (sect. 4): which points are scored for each rear wheel."""

    wheel_window_radius_m: Annotated[float, Rule(gt=0.0, le=5.0)]
    #: 0 = no cap; otherwise at most 1,000 (a patch costs N^2 / 2 pairs: 500 k a tyre).
    max_points_per_wheel: Annotated[int, Rule(ge=0, le=1000)]
    #: Which points a patch with more than max_points_per_wheel keeps: "hash" (a uniform,
    #: reproducible sample of all lasers, the paper's), "nearest_laser" (the nearest laser's
    #: first) or "freshest" (those seen last before the event). toolkit.model.patches.
    point_sample: Annotated[str, Rule(choices=("hash", "freshest", "nearest_laser"))] = (
        "nearest_laser"
    )


@dataclass(frozen=True)
class LearnConfig:
    """Coordinate ascent (sect. 6) on Tp - lambda_fp * Fp over (alpha, upsilon, omega, zeta)."""

    lambda_fp: Annotated[float, Rule(ge=0.0, le=1e6)]
    #: Full rotations of the search; the increments halve each time (past ~50 they are
    #: below float32's resolution), so at most 1,000.
    iterations: Annotated[int, Rule(ge=1, le=1000)]
    #: Each within +-1e6 (weights) and, for the exponents, positive (checked below): 1e300
    #: overflowed every score.
    initial_alpha: Annotated[tuple[float, ...], Rule(length=10, ge=-1e6, le=1e6)]
    initial_upsilon: Annotated[float, Rule(gt=0.0, le=100.0)]
    #: The number of largest pair scores summed: at most 10,000 (each patch keeps that many
    #: scores; 1e9 asked 3 TiB).
    initial_omega: Annotated[int, Rule(ge=1, le=10000)]
    initial_zeta: Annotated[float, Rule(gt=0.0, le=100.0)]
    increment_alpha: Annotated[tuple[float, ...], Rule(length=10, gt=0.0, le=1e6)]
    increment_upsilon: Annotated[float, Rule(gt=0.0, le=100.0)]
    increment_omega: Annotated[float, Rule(gt=0.0, le=10000.0)]
    increment_zeta: Annotated[float, Rule(gt=0.0, le=100.0)]
    #: What a step of the search must improve on the training split: "objective" (eq. 6,
    #: the paper's), "auc" or "pauc" (toolkit.model.ascent); mu is eq. (6)'s either way.
    accept: Annotated[str, Rule(choices=("objective", "auc", "pauc"))] = "auc"
    #: Early stopping: about this share of training events held out to pick the rotation that
    #: ranks them best (every round(1 / share)-th block of 50 consecutive events; 0: none, the
    #: paper's search; model.json records the share actually held out).
    validation_share: Annotated[float, Rule(ge=0.0, le=0.5)] = 0.0
    #: Beyond the paper: a look-ahead penalty in eq. (4), alpha_11 |lead|^alpha_12 per point
    #: (toolkit.model.roughness), learned like the others from initial_lead with
    #: increment_lead; false is the paper's eq. (4).
    lead_term: bool = False
    initial_lead: Annotated[tuple[float, ...], Rule(length=2, ge=-1e6, le=1e6)] = (0.01, 1.0)
    increment_lead: Annotated[tuple[float, ...], Rule(length=2, gt=0.0, le=1e6)] = (
        0.005,
        0.5,
    )


@dataclass(frozen=True)
class ProjectConfig:
    """Which of the projected points the cloud keeps (its size on disk is the user's call)."""

    #: "all": every return; "near_path": only those within the tables' radius
    #: (``[model] wheel_window_radius_m``) plus ``near_path_margin_m`` of a rear tyre's
    #: path, the points the tables can use (the rest of the road and its sides are left out).
    keep: Annotated[str, Rule(choices=("all", "near_path"))] = "all"
    near_path_margin_m: Annotated[float, Rule(ge=0.1, le=100.0)] = 0.2


@dataclass(frozen=True)
class TablesConfig:
    """Training/test split (sect. 7: first stretch of road trains, the next one tests)."""

    split_method: Annotated[str, Rule(choices=("distance",))]
    split_scope: Annotated[str, Rule(choices=("all_logs", "per_log"))]
    train_fraction: Annotated[float, Rule(gt=0.0, lt=1.0)]
    min_points_per_wheel: Annotated[int, Rule(ge=2, le=1000)]
    #: A point counts for an event when seen at most this long before the rear axle reached
    #: it, s (on a loop of the course, terrain seen minutes earlier is not "ahead").
    max_lookahead_s: Annotated[float, Rule(gt=0.0, le=3600.0)] = 60.0


@dataclass(frozen=True)
class EvaluateConfig:
    """ROC operating points, the baseline's laser choice, and speed-control settings (sect. 7)."""

    fpr_points: Annotated[tuple[float, ...], Rule(min_length=1, gt=0.0, lt=1.0, unique=True)]
    baseline_closest_laser: str | None
    slow_fractions: Annotated[tuple[float, ...], Rule(min_length=1, gt=0.0, le=1.0, unique=True)]
    decel_mps2: Annotated[float, Rule(gt=0.0)]
    recovery_mps2: Annotated[float, Rule(gt=0.0)]
    hold_distance_m: Annotated[float, Rule(ge=0.0)]
    lookahead_m: Annotated[float, Rule(ge=0.0)]
    #: The reactive controller's recovery rates swept with slow_fractions, m/s^2.
    recovery_rates_mps2: Annotated[tuple[float, ...], Rule(min_length=1, gt=0.0, unique=True)] = (
        0.25,
        0.5,
        1.0,
    )
    #: Shock counted as experienced: only what exceeds this floor, G.
    shock_floor_g: Annotated[float, Rule(ge=0.0)] = 0.3
    #: The race's obstacle test (toolkit.model.baseline): grid cell, m; obstacle height, m;
    #: pose error at zero time, m; its variance growth, m^2/s; the test's confidence.
    baseline_cell_m: Annotated[float, Rule(ge=0.01, le=10.0)] = 0.25
    baseline_delta_m: Annotated[float, Rule(ge=0.0)] = 0.15
    baseline_sigma0_m: Annotated[float, Rule(gt=0.0)] = 0.03
    baseline_growth_m2_per_s: Annotated[float, Rule(ge=0.0)] = 0.0025
    baseline_confidence: Annotated[float, Rule(gt=0.5, lt=1.0)] = 0.95
    #: Bootstrap resamples of the test events for the ROC's confidence intervals, and the seed.
    bootstrap_resamples: Annotated[int, Rule(ge=10, le=100000)] = 1000
    bootstrap_seed: Annotated[int, Rule(ge=0)] = 0
    #: Also train the model on the closest laser's points alone. Off by default: the model
    #: and the race test already meet on the same points (the race test on the model's
    #: points), and with the nearest laser first the two sets differ in a few patches only
    #: (five 20-mile races: the same AUC to three decimals), for a whole search's time.
    model_on_closest_laser: bool = False


@dataclass(frozen=True)
class PipelineConfig:
    """The whole configuration: one frozen dataclass per TOML section."""

    name: Annotated[str, Rule(nonempty=True)]
    topics: TopicsConfig
    vehicle: VehicleConfig
    time: TimeConfig
    pose: PoseConfig
    project: ProjectConfig
    label: LabelConfig
    model: ModelConfig
    learn: LearnConfig
    tables: TablesConfig
    evaluate: EvaluateConfig


#: The TOML sections, in file order (every field of PipelineConfig that is a table).
SECTIONS: tuple[str, ...] = tuple(
    name
    for name, tp in typing.get_type_hints(PipelineConfig).items()
    if dataclasses.is_dataclass(tp)
)


# --------------------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------------------


def default_config() -> PipelineConfig:
    """The built-in default (equal to ``pipelines/stanley2005.toml``)."""
    return _finish(_default_raw(), _DEFAULT_SOURCE)


def load_config(path: str | Path) -> PipelineConfig:
    """Read a TOML configuration; keys it omits take the built-in default's values."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"cannot read configuration: {exc.strerror or exc}", path=path) from exc
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"not UTF-8 text: {exc}", path=path) from exc
    return parse_config(text, source=path)


def parse_config(text: str, source: str | Path = "<string>") -> PipelineConfig:
    """Parse TOML text over the built-in default; ``source`` names it in errors."""
    user = _parse_toml(text, source)
    _check_known_keys(PipelineConfig, user, "", source)
    return _finish(_merge(_default_raw(), user), source)


_DEFAULT_SOURCE = f"<built-in default {DEFAULT_CONFIG_RESOURCE}>"


def _default_raw() -> dict[str, Any]:
    """The packaged default as parsed TOML (a fresh dict on every call)."""
    resource = importlib.resources.files("toolkit").joinpath(DEFAULT_CONFIG_RESOURCE)
    try:
        text = resource.read_text(encoding="utf-8")
    except OSError as exc:  # an installation without its package data
        raise ConfigError(f"cannot read the built-in default: {exc}", path=_DEFAULT_SOURCE) from exc
    return _parse_toml(text, _DEFAULT_SOURCE)


def _parse_toml(text: str, source: str | Path) -> dict[str, Any]:
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"invalid TOML: {exc}", path=source) from exc


def _finish(raw: Mapping[str, Any], source: str | Path) -> PipelineConfig:
    cfg = _build(PipelineConfig, raw, "", source)
    _validate(cfg, source)
    return cfg


def _merge(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    """Deep-merge tables; any non-table value (lists included) in ``over`` replaces."""
    out = copy.deepcopy(dict(base))
    for key, value in over.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = _merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def _join(prefix: str, key: str) -> str:
    return f"{prefix}.{key}" if prefix else key


def _split(tp: Any) -> tuple[Any, Rule]:
    """``Annotated[T, Rule(...)]`` -> (T, rule); a bare T has no rules."""
    if typing.get_origin(tp) is Annotated:
        base, *extras = typing.get_args(tp)
        rule = next((e for e in extras if isinstance(e, Rule)), _NO_RULE)
        return base, rule
    return tp, _NO_RULE


def _fields(cls: type) -> dict[str, tuple[Any, Rule]]:
    """Field name -> (type, rule), in declaration order."""
    hints = typing.get_type_hints(cls, include_extras=True)
    return {f.name: _split(hints[f.name]) for f in dataclasses.fields(cls)}


def _check_known_keys(cls: type, data: Mapping[str, Any], prefix: str, source: str | Path) -> None:
    """Every key must name a field; nested tables are checked recursively."""
    known = _fields(cls)
    for key, value in data.items():
        dotted = _join(prefix, key)
        if key not in known:
            close = difflib.get_close_matches(key, list(known), n=1)
            hint = f"; did you mean '{_join(prefix, close[0])}'?" if close else ""
            raise ConfigError(f"{dotted}: unknown key (got {value!r}){hint}", path=source)
        sub = known[key][0]
        if dataclasses.is_dataclass(sub) and isinstance(value, Mapping):
            _check_known_keys(typing.cast(type, sub), value, dotted, source)


def _build(cls: type[_T], data: Any, prefix: str, source: str | Path) -> _T:
    """Convert one TOML table into ``cls``, naming the dotted key of any problem."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{prefix}: expected a table (got {data!r})", path=source)
    _check_known_keys(cls, data, prefix, source)
    kwargs: dict[str, Any] = {}
    for name, (tp, rule) in _fields(cls).items():
        dotted = _join(prefix, name)
        if name not in data:
            raise ConfigError(f"{dotted}: missing key", path=source)
        kwargs[name] = _convert(tp, data[name], dotted, rule, source)
    return cls(**kwargs)


def _convert(tp: Any, value: Any, key: str, rule: Rule, source: str | Path) -> Any:
    """Type-check and convert one value, then apply the field's rule."""

    def fail(problem: str) -> ConfigError:
        return ConfigError(f"{key}: {problem} (got {value!r})", path=source)

    if dataclasses.is_dataclass(tp):
        return _build(typing.cast(type, tp), value, key, source)
    origin = typing.get_origin(tp)
    if origin is tuple:
        item_tp = typing.get_args(tp)[0]
        if not isinstance(value, list):
            raise fail("expected a list")
        items = tuple(_scalar(item_tp, v, f"{key}[{i}]", rule, source) for i, v in enumerate(value))
        if rule.length is not None and len(items) != rule.length:
            raise fail(f"expected exactly {rule.length} values")
        if rule.min_length is not None and len(items) < rule.min_length:
            raise fail(f"expected at least {rule.min_length} value(s)")
        if rule.unique and len(set(items)) != len(items):
            raise fail("values must be unique")
        return items
    if origin in (types.UnionType, typing.Union):  # str | None: "" means absent
        if value == "":
            return None
        inner = next(a for a in typing.get_args(tp) if a is not type(None))
        return _scalar(inner, value, key, rule, source)
    return _scalar(tp, value, key, rule, source)


def _scalar(tp: Any, value: Any, key: str, rule: Rule, source: str | Path) -> Any:
    def fail(problem: str) -> ConfigError:
        return ConfigError(f"{key}: {problem} (got {value!r})", path=source)

    if tp is bool:
        if not isinstance(value, bool):
            raise fail("expected true or false")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise fail("expected a string")
        if rule.nonempty and not value:
            raise fail("must not be empty")
        if rule.choices is not None and value not in rule.choices:
            raise fail("expected one of " + ", ".join(repr(c) for c in rule.choices))
        return value
    number: int | float
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise fail("expected an integer")
        if not INT64_MIN <= value <= INT64_MAX:  # every integer ends up in int64 arrays
            raise fail("must fit a signed 64-bit integer")
        number = value
    elif tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise fail("expected a number")
        number = float(value)
        if not math.isfinite(number):
            raise fail("expected a finite number")
    else:  # pragma: no cover - a field type this loader does not know is a programming error
        raise TypeError(f"unsupported config field type {tp!r} for {key}")
    inside = (
        (rule.gt is None or number > rule.gt)
        and (rule.ge is None or number >= rule.ge)
        and (rule.lt is None or number < rule.lt)
        and (rule.le is None or number <= rule.le)
    )
    if not inside:
        raise fail(f"must be {_valid_range(rule)}")
    return number


def _valid_range(rule: Rule) -> str:
    """The valid range of a number in words: "at least 3", "in [3, 1000]", "in (0, 10]"."""
    lo = f"[{rule.ge:g}" if rule.ge is not None else f"({rule.gt:g}" if rule.gt is not None else ""
    hi = f"{rule.le:g}]" if rule.le is not None else f"{rule.lt:g})" if rule.lt is not None else ""
    if lo and hi:
        return f"in {lo}, {hi}"
    if rule.ge is not None:
        return f"at least {rule.ge:g}"
    if rule.gt is not None:
        return f"greater than {rule.gt:g}"
    if rule.le is not None:
        return f"at most {rule.le:g}"
    return f"less than {rule.lt:g}"


def _validate(cfg: PipelineConfig, source: str | Path) -> None:
    """Rules that span several keys."""
    seen: dict[str, str] = {}
    for role, topics in cfg.topics.by_role().items():
        for topic in topics:
            if topic in seen:
                raise ConfigError(
                    f"topics.{role}: topic {topic!r} also plays the role topics.{seen[topic]}",
                    path=source,
                )
            seen[topic] = role
    fpr = cfg.evaluate.fpr_points
    if list(fpr) != sorted(fpr):
        raise ConfigError(f"evaluate.fpr_points: must be increasing (got {list(fpr)!r})", source)
    for i in (1, 3, 5, 7, 9):  # eq. 4's exponents: |0|^a is infinite for a <= 0
        if not cfg.learn.initial_alpha[i] > 0.0:
            raise ConfigError(
                f"learn.initial_alpha: alpha_{i + 1} is an exponent of eq. 4 and must be "
                f"positive (got {cfg.learn.initial_alpha[i]!r})",
                path=source,
            )
    if not cfg.learn.initial_lead[1] > 0.0:
        raise ConfigError(
            "learn.initial_lead: its second value (alpha_12) is an exponent and must be "
            f"positive (got {cfg.learn.initial_lead[1]!r})",
            path=source,
        )
    closest = cfg.evaluate.baseline_closest_laser
    if closest is not None and closest not in cfg.topics.lasers:
        raise ConfigError(
            f"evaluate.baseline_closest_laser: not one of topics.lasers (got {closest!r})",
            path=source,
        )


# --------------------------------------------------------------------------------------
# Hashing and writing
# --------------------------------------------------------------------------------------


def to_dict(cfg: PipelineConfig) -> dict[str, Any]:
    """Plain JSON-ready dict (tuples become lists, absent topics stay None)."""
    return typing.cast(dict[str, Any], json.loads(json.dumps(dataclasses.asdict(cfg))))


def config_hash(cfg: PipelineConfig, sections: Iterable[str] | None = None) -> str:
    """sha256 (hex) of the canonical JSON of ``cfg``, or only of the named sections
    (``"tables"``) and single keys (``"model.wheel_window_radius_m"``).

    Hashing only what a stage reads lets an up-to-date check ignore changes to settings the
    stage does not use. The format number is part of every hash.
    """
    full = to_dict(cfg)
    if sections is None:
        body: dict[str, Any] = full
    else:
        wanted = sorted(set(sections))
        body = {}
        for name in wanted:
            section, _, key = name.partition(".")
            if section not in full or (key and key not in full[section]):
                raise ValueError(f"unknown config section or key: {name!r}")
            if not key:
                body[section] = full[section]
            elif section not in wanted:  # a whole section asked for holds the key already
                body.setdefault(section, {})[key] = full[section][key]
    canonical = json.dumps(
        {"config_format": CONFIG_FORMAT, "config": body},
        sort_keys=True,
        separators=(",", ":"),
        ensure_ascii=True,
        allow_nan=False,
    )
    return hashlib.sha256(canonical.encode("ascii")).hexdigest()


def dump_toml(cfg: PipelineConfig) -> str:
    """TOML text that :func:`parse_config` reads back to an object equal to ``cfg``."""
    from toolkit import __version__

    lines = [
        f"# Configuration in force, written by terrain {__version__}.",
        f"# config_hash = {config_hash(cfg)}",
        "",
    ]
    _dump_table(cfg, "", lines)
    return "\n".join(lines).rstrip("\n") + "\n"


def _dump_table(obj: Any, prefix: str, lines: list[str]) -> None:
    nested = []
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if dataclasses.is_dataclass(value):
            nested.append((f.name, value))
        else:
            lines.append(f"{f.name} = {toml_value(value)}")
    for name, value in nested:
        dotted = _join(prefix, name)
        lines.extend(["", f"[{dotted}]"])
        _dump_table(value, dotted, lines)


def toml_value(value: Any) -> str:
    """A configuration value as TOML text (None as ``""``, tuples as arrays)."""
    if value is None:
        return '""'
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, str):
        return _toml_string(value)
    if isinstance(value, tuple | list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {value!r} as TOML")


def _toml_string(text: str) -> str:
    """A TOML basic string: quotes, backslashes and control characters escaped."""
    out = ['"']
    for ch in text:
        if ch == '"':
            out.append('\\"')
        elif ch == "\\":
            out.append("\\\\")
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04x}")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)
