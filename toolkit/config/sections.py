"""The sections of the configuration as frozen dataclasses, each setting with its rules.

Part of :mod:`toolkit.config`, whose docstring tells the file format; a setting's type and
:class:`Rule` (``Annotated[type, Rule(...)]``) are what loading checks its value against.
"""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass, field
from typing import Annotated

#: The range of every integer setting (they end up in int64 arrays).
INT64_MIN, INT64_MAX = -(2**63), 2**63 - 1
#: Largest declared latency or clock offset of a sensor (ns): one day.
MAX_SENSOR_TIME_NS = 86_400 * 10**9

#: Bumped when the meaning of existing keys changes; part of every config hash.
CONFIG_FORMAT = 1

#: File name of the packaged default configuration (inside the ``toolkit`` package).
DEFAULT_CONFIG_RESOURCE = "default_config.toml"

#: Field metadata of a setting added after configurations were first hashed (the 3-D lidar's):
#: at its default it is left out of the configuration's hash and of the configuration written
#: to a workspace, so a vehicle that does not use it keys every output exactly as before (a
#: laser-only workspace stays up to date, its tables byte for byte, when the role arrives).
#: Set to anything else, it is hashed like every other setting.
UNHASHED_AT_DEFAULT: dict[str, bool] = {"unhashed_at_default": True}

#: Topic roles, in the order ingest reports them. Any role may be absent from a vehicle
#: (``""``, or ``[]`` for the roles of several topics, in the file): ingest converts the roles
#: a log has, and a stage that needs a missing role refuses with one line naming it.
ROLES: tuple[str, ...] = (
    "lasers",
    "lidars",
    "imu",
    "gps",
    "heading",
    "wheels",
    "tf_static",
    "truth_pose",
    "truth_features",
)
#: Sensor roles that carry declared latencies and clock offsets.
TIMED_ROLES: tuple[str, ...] = ("lasers", "lidars", "imu", "gps", "heading", "wheels")
#: Roles of several topics (a vehicle carries several lasers, several lidars).
MULTI_TOPIC_ROLES: tuple[str, ...] = ("lasers", "lidars")


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


# --------------------------------------------------------------------------------------
# The configuration, section by section
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TopicsConfig:
    """Which topic plays which role; a role the vehicle lacks is ``None`` (``()`` for the
    roles of several topics: lasers, lidars)."""

    lasers: Annotated[tuple[str, ...], Rule(nonempty=True, unique=True)]
    imu: str | None
    gps: str | None
    heading: str | None
    wheels: str | None
    tf_static: str | None
    truth_pose: str | None
    truth_features: str | None
    #: 3-D lidars (sensor_msgs/PointCloud2), after the others: a field with a default.
    lidars: Annotated[tuple[str, ...], Rule(nonempty=True, unique=True)] = field(
        default=(), metadata=UNHASHED_AT_DEFAULT
    )

    def roles(self) -> tuple[str, ...]:
        """Every role: each field is one (a role added as a field is read too), in the order
        of :data:`ROLES`, any other after them."""
        names = [f.name for f in dataclasses.fields(self)]
        return tuple(sorted(names, key=lambda r: ROLES.index(r) if r in ROLES else len(ROLES)))

    def by_role(self) -> dict[str, tuple[str, ...]]:
        """Role -> topics (a role of several topics, a tuple field, may have several),
        leaving out absent roles, in the order of :meth:`roles`."""
        out: dict[str, tuple[str, ...]] = {}
        for role in self.roles():
            value = getattr(self, role)
            if value:
                out[role] = tuple(value) if isinstance(value, tuple) else (value,)
        return out

    def absent_roles(self) -> tuple[str, ...]:
        """Roles the configuration says the vehicle does not have."""
        present = self.by_role()
        return tuple(role for role in self.roles() if role not in present)

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
    lidars: Annotated[int, Rule(ge=-MAX_SENSOR_TIME_NS, le=MAX_SENSOR_TIME_NS)] = field(
        default=0, metadata=UNHASHED_AT_DEFAULT
    )

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
    #: How the increments change between rotations: "halve" (every one halved, the paper's)
    #: or "adapt" (each doubled after its step is taken, halved after both signs fail;
    #: toolkit.model.ascent).
    step_rule: Annotated[str, Rule(choices=("halve", "adapt"))] = "halve"
    #: Beyond the paper: a look-ahead penalty in eq. (4), alpha_11 |lead|^alpha_12 per point
    #: (toolkit.model.roughness), learned like the others from initial_lead with
    #: increment_lead; false is the paper's eq. (4).
    lead_term: bool = False
    initial_lead: Annotated[tuple[float, ...], Rule(length=2, ge=-1e6, le=1e6)] = (0.01, 1.0)
    increment_lead: Annotated[tuple[float, ...], Rule(length=2, gt=0.0, le=1e6)] = (
        0.005,
        0.5,
    )


#: Per-point time presets of the 3-D lidar drivers (:mod:`toolkit.mcapio.pointcloud2`), and
#: "auto" (chosen per topic from its fields' names) and "custom" (the ``time_*`` keys).
LIDAR_TIME_CHOICES: tuple[str, ...] = (
    "auto",
    "ouster",
    "velodyne",
    "nebula",
    "livox",
    "rslidar",
    "none",
    "custom",
)


@dataclass(frozen=True)
class LidarConfig:
    """How a 3-D lidar's clouds are read: each point's own time, which rings, what ranges.

    Every key is new since configurations were first hashed: at its default it keys nothing
    (:data:`UNHASHED_AT_DEFAULT`).
    """

    #: A driver's preset, "auto" (from the cloud's field names; ``config init`` says which it
    #: found) or "custom" (the four keys below).
    time: Annotated[str, Rule(choices=LIDAR_TIME_CHOICES)] = field(
        default="auto", metadata=UNHASHED_AT_DEFAULT
    )
    #: custom only: the per-point time field ("" = none: every point at the header stamp).
    time_field: str = field(default="", metadata=UNHASHED_AT_DEFAULT)
    time_unit: Annotated[str, Rule(choices=("s", "ms", "us", "ns"))] = field(
        default="ns", metadata=UNHASHED_AT_DEFAULT
    )
    #: "header": relative to the header stamp; "absolute": on a clock of its own.
    time_reference: Annotated[str, Rule(choices=("header", "absolute"))] = field(
        default="header", metadata=UNHASHED_AT_DEFAULT
    )
    #: Where the driver stamps the header: the sweep's first point or its last.
    header_at: Annotated[str, Rule(choices=("start", "end"))] = field(
        default="start", metadata=UNHASHED_AT_DEFAULT
    )
    #: Rings (beams) kept; empty keeps every ring.
    rings: Annotated[tuple[int, ...], Rule(ge=0, le=1023, unique=True)] = field(
        default=(), metadata=UNHASHED_AT_DEFAULT
    )
    #: Returns nearer than this are dropped (the vehicle's own body), m.
    min_range_m: Annotated[float, Rule(ge=0.0, le=1000.0)] = field(
        default=0.0, metadata=UNHASHED_AT_DEFAULT
    )
    #: Returns farther than this are dropped, m.
    max_range_m: Annotated[float, Rule(gt=0.0, le=10000.0)] = field(
        default=1000.0, metadata=UNHASHED_AT_DEFAULT
    )


@dataclass(frozen=True)
class ImuConfig:
    """What the IMU can measure: a sample it cannot have produced is rejected at ingest
    (:mod:`toolkit.ingestion.imucheck`), before any stage reads it.

    ``sensor_msgs/Imu`` carries no measuring range, so it is declared here. The defaults are
    the widest full scales of common MEMS IMUs (e.g. TDK InvenSense ICM-42688-P datasheet:
    gyro +/-2000 deg/s, accelerometer +/-16 g); a vehicle with a wider one sets its own.
    Every key is new since configurations were first hashed (:data:`UNHASHED_AT_DEFAULT`).
    """

    #: Gyro full scale, rad/s (2000 deg/s): a larger rate about any axis is no measurement.
    gyro_range_radps: Annotated[float, Rule(gt=0.0, le=1000.0)] = field(
        default=34.9, metadata=UNHASHED_AT_DEFAULT
    )
    #: Accelerometer full scale, m/s^2 (16 g, g = 9.80665 m/s^2).
    accel_range_mps2: Annotated[float, Rule(gt=0.0, le=100000.0)] = field(
        default=156.9, metadata=UNHASHED_AT_DEFAULT
    )
    #: The largest angular acceleration the vehicle's body can have, rad/s^2: a gyro sample
    #: farther from its neighbours' median than this allows over the time to them is a
    #: spike. A front tyre striking a 10 cm step at 10 m/s lifts the front axle by ~1.5 m/s
    #: within ~15 ms, ~70 rad/s^2 of pitch on a 1.5 m lever. Measured: four simulated
    #: 40-minute races and the real Husky log pass the test at 10 rad/s^2 with no sample
    #: flagged (at 5 rad/s^2, 20-46 a race and 1 on the Husky).
    max_angular_accel_radps2: Annotated[float, Rule(gt=0.0, le=100000.0)] = field(
        default=100.0, metadata=UNHASHED_AT_DEFAULT
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
class OnlineLearnConfig:
    """Learning while driving (sect. 8): the test-then-train replay of ``terrain online``
    (:mod:`toolkit.model.online`). It starts from ``[learn]``'s initial guess and
    increments, or from a model learned elsewhere.

    The defaults were measured (``benchmarks/README.md``, "Online: refits"): on two 20-mile
    tuning races no evaluation uses (805, 806), the whole search rerun every 2 km on a
    buffer of 64 rough and 1,024 smooth events, 10 rotations, ranked the test halves best
    (0.910-0.917 prequential against 0.901 for steps of 4 elements every 150 m on 64 + 256,
    the offline model 0.884); run beside the planner's loop, it leaves the loop only the
    swap of a model (``coordinates_per_update = 0``). A refit fits the buffer's rough
    events against the standings' reference, a sample of smooth events spread over the
    drive as the rough ones are (``refit_smooth``): on the tuning races a tie (0.910 both),
    chosen for that reason ("Online: a refit's smooth side").
    """

    #: Metres driven between two updates.
    update_every_m: Annotated[float, Rule(ge=1.0, le=100000.0)] = 150.0
    #: The buffer: the most recent rough and smooth labelled events kept.
    buffer_rough: Annotated[int, Rule(ge=1, le=100000)] = 64
    buffer_smooth: Annotated[int, Rule(ge=1, le=1000000)] = 1024
    #: Elements of B each update tries between refits (13: a whole rotation; 0: only
    #: refits learn).
    coordinates_per_update: Annotated[int, Rule(ge=0, le=15)] = 0
    #: Rough labels the buffer must hold before the model learns.
    min_rough: Annotated[int, Rule(ge=1, le=100000)] = 8
    step_rule: Annotated[str, Rule(choices=("halve", "adapt"))] = "halve"
    #: Score with B averaged over the versions (Polyak); measured, not better.
    average: bool = False
    #: Buffer share held out to accept an update; measured, not better.
    validation_share: Annotated[float, Rule(ge=0.0, le=0.5)] = 0.0
    #: Every this many metres (0: never) the whole search of sect. 6 is run again on the
    #: buffer from the start, beside the planner's loop; its model is taken at the first
    #: update ``refit_budget_s`` of driving after it began.
    refit_every_m: Annotated[float, Rule(ge=0.0)] = 2000.0
    refit_iterations: Annotated[int, Rule(ge=1, le=1000)] = 10
    refit_budget_s: Annotated[float, Rule(ge=0.0, le=100000.0)] = 60.0
    #: The smooth events a refit fits: the buffer's latest, or the standings' reference
    #: (a sample spread over the drive so far).
    refit_smooth: Annotated[str, Rule(choices=("buffer", "reference"))] = "reference"
    #: An update's step must raise the buffer's AUC by more than this (0: any rise).
    accept_margin: Annotated[float, Rule(ge=0.0, le=1.0)] = 0.0
    #: The standings' reference: at most this many smooth events spread over the drive so
    #: far (0: the buffer's smooth events, the last few hundred metres).
    reference_smooth: Annotated[int, Rule(ge=0, le=1000000)] = 1024
    #: Each log is a drive of its own, learned from the start; false: the logs are one drive
    #: (in the tables' order) and the model carries over from one to the next.
    restart_each_log: bool = True
    #: A ``model.json`` learned elsewhere to start from (its B, mu, and [learn]'s increments),
    #: relative to the workspace; "" starts from [learn]'s initial guess.
    start_model: str = ""
    #: The report's frozen early model: the online model as it stood after this distance of
    #: each log, m.
    frozen_after_m: Annotated[float, Rule(gt=0.0)] = 3000.0
    #: The report's stretches (prequential AUC against distance), m.
    stretch_m: Annotated[float, Rule(ge=100.0)] = 2000.0
    #: Updates between two checkpoints of the replay (a stopped replay resumes from the last).
    checkpoint_every: Annotated[int, Rule(ge=1, le=100000)] = 20


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
    lidar: LidarConfig = field(default_factory=LidarConfig)
    imu: ImuConfig = field(default_factory=ImuConfig)
    online: OnlineLearnConfig = field(default_factory=OnlineLearnConfig)


#: The TOML sections, in file order (every field of PipelineConfig that is a table).
SECTIONS: tuple[str, ...] = tuple(
    name
    for name, tp in typing.get_type_hints(PipelineConfig).items()
    if dataclasses.is_dataclass(tp)
)
