"""Loading a configuration: TOML over the built-in default, every key and value checked.

Part of :mod:`toolkit.config`. Every error is a ConfigError naming the file, the dotted key
and the offending value.
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
import importlib.resources
import math
import tomllib
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, TypeVar

from toolkit.config.sections import (
    DEFAULT_CONFIG_RESOURCE,
    INT64_MAX,
    INT64_MIN,
    PipelineConfig,
    Rule,
)
from toolkit.errors import ConfigError

_T = TypeVar("_T")

_NO_RULE = Rule()


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


def dotted_key(prefix: str, key: str) -> str:
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
        dotted = dotted_key(prefix, key)
        if key not in known:
            close = difflib.get_close_matches(key, list(known), n=1)
            hint = f"; did you mean '{dotted_key(prefix, close[0])}'?" if close else ""
            raise ConfigError(f"{dotted}: unknown key (got {value!r}){hint}", path=source)
        sub = known[key][0]
        if dataclasses.is_dataclass(sub) and isinstance(value, Mapping):
            _check_known_keys(typing.cast(type, sub), value, dotted, source)


def _build(cls: type[_T], data: Any, prefix: str, source: str | Path) -> _T:
    """Convert one TOML table into ``cls``, naming the dotted key of any problem. A key
    missing from ``data`` (the user's keys over the default file's) takes its field's
    default where it has one (a role declared since the default file was written)."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{prefix}: expected a table (got {data!r})", path=source)
    _check_known_keys(cls, data, prefix, source)
    kwargs: dict[str, Any] = {}
    defaults = {
        f.name
        for f in dataclasses.fields(typing.cast(Any, cls))
        if f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING
    }
    for name, (tp, rule) in _fields(cls).items():
        dotted = dotted_key(prefix, name)
        if name not in data:
            if name in defaults:
                continue
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
    if cfg.online.coordinates_per_update == 0 and cfg.online.refit_every_m <= 0.0:
        raise ConfigError(
            "online.coordinates_per_update: 0 leaves only refits to learn, and "
            "online.refit_every_m is 0 (never): set one of them",
            path=source,
        )
    closest = cfg.evaluate.baseline_closest_laser
    if closest is not None and closest not in cfg.topics.lasers:
        raise ConfigError(
            f"evaluate.baseline_closest_laser: not one of topics.lasers (got {closest!r})",
            path=source,
        )
