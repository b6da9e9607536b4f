"""Whether a log's own definition of a message type is the layout the toolkit assumes.

The fast decoder (:func:`~toolkit.mcapio.cdr.decode_batch` given a type *name*) lays a
payload out by the toolkit's own ``.msg`` files (``schemas/msg``). A log carries its own
definition of every type (the MCAP Schema record, encoding ``ros2msg``), and the bytes follow
that one: a ``sensor_msgs/msg/NavSatFix`` whose schema declares ``longitude`` before
``latitude`` has its longitude first on the wire. Reading it by the toolkit's layout would
swap the two silently.

:func:`layout_difference` compares two parsed definitions field by field, as the wire sees
them: names, primitive types, order, fixed array lengths and sequences, nested types (and,
recursively, their fields). Comments, blank lines, constants, default values and the bounds
of bounded strings and sequences leave the bytes unchanged and are ignored, so the schema
texts rosbag2, ``mcap_ros2`` and the toolkit's simulator write for a standard type all match.
:func:`field_mismatch` asks the narrower question a converter cares about: are the fields it
reads present, by name, with the types the standard layout gives them?
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from functools import cache
from itertools import zip_longest

from mcap.well_known import SchemaEncoding

from toolkit.errors import SchemaError, ToolkitError
from toolkit.mcapio.msgdefs import (
    FieldSpec,
    MessageSpec,
    full_type_name,
    known_types,
    parse_msgdef,
    parse_schema_text,
)
from toolkit.mcapio.records import Channel


def field_type(f: FieldSpec) -> str:
    """A field's type as the wire sees it: ``float64``, ``float64[9]``, ``float64[]`` (a
    bounded sequence too: its bound does not change the bytes), ``pkg/msg/Type``."""
    if not f.is_array:
        return f.type_name
    if f.array_length is not None:
        return f"{f.type_name}[{f.array_length}]"
    return f"{f.type_name}[]"


def _where(index: int, owner: MessageSpec, top: bool) -> str:
    """``field 3`` for a field of the message itself, ``field 1 of std_msgs/msg/Header`` for
    one of a nested message (``index`` counts from 1)."""
    return f"field {index}" if top else f"field {index} of {owner.name}"


def layout_difference(standard: MessageSpec, log: MessageSpec, prefix: str = "") -> str | None:
    """The first place ``log``'s definition departs from ``standard``'s on the wire, as a
    phrase that follows "its schema <type> " (None when the two lay out the same bytes).

    E.g. "declares `longitude` where the standard layout has `latitude` (field 3)", "declares
    `latitude` as float32 where the standard layout has float64 (field 3)", "lacks
    `position_covariance_type` (field 7 of the standard layout)", "declares an extra field
    `extra` (field 8)". Nested fields are named by dotted path (``header.seq``).
    """
    top = not prefix
    pairs = zip_longest(standard.fields, log.fields)
    for index, (std, got) in enumerate(pairs, start=1):
        where = _where(index, standard, top)
        if std is None or got is None:  # zip_longest pads the shorter side only
            if got is not None:
                return f"declares an extra field `{prefix}{got.name}` ({where})"
            if std is not None:
                return f"lacks `{prefix}{std.name}` ({where} of the standard layout)"
            continue
        if got.name != std.name:
            return (
                f"declares `{prefix}{got.name}` where the standard layout has "
                f"`{prefix}{std.name}` ({where})"
            )
        if field_type(got) != field_type(std):
            return (
                f"declares `{prefix}{got.name}` as {field_type(got)} where the standard "
                f"layout has {field_type(std)} ({where})"
            )
        if std.nested is not None and got.nested is not None:
            inner = layout_difference(std.nested, got.nested, f"{prefix}{std.name}.")
            if inner is not None:
                return inner
    return None


def _chain(spec: MessageSpec, path: str) -> list[FieldSpec] | None:
    """The fields a dotted path runs through (``transforms.header.frame_id``: through an
    array of messages too), or None when ``spec`` has no such path."""
    chain: list[FieldSpec] = []
    current: MessageSpec | None = spec
    for name in path.split("."):
        if current is None:
            return None
        f = next((f for f in current.fields if f.name == name), None)
        if f is None:
            return None
        chain.append(f)
        current = f.nested
    return chain


def field_mismatch(standard: MessageSpec, log: MessageSpec, paths: Iterable[str]) -> str | None:
    """The first of ``paths`` (dotted, as the converters read them) that ``log`` lacks or
    types otherwise than ``standard``, as a phrase ("has no field `latitude`", "declares
    `latitude` as float32 where the standard layout has float64"); None when every path is
    there with its standard type (a path through a nested message must cross it with the
    same array shape; a path ending on a nested message must lay it out as the standard)."""
    for path in paths:
        want = _chain(standard, path)
        if want is None:
            raise ValueError(f"{standard.name} has no field {path!r}")  # a converter's typo
        have = _chain(log, path)
        if have is None:
            return f"has no field `{path}`"
        names = path.split(".")
        for depth, (std, got) in enumerate(zip(want, have, strict=True), start=1):
            same_shape = (std.is_array, std.array_length) == (got.is_array, got.array_length)
            both_nested = std.nested is not None and got.nested is not None
            if not same_shape or (not both_nested and std.type_name != got.type_name):
                return (
                    f"declares `{'.'.join(names[:depth])}` as {field_type(got)} where the "
                    f"standard layout has {field_type(std)}"
                )
        last_std, last_got = want[-1], have[-1]
        if last_std.nested is not None and last_got.nested is not None:
            inner = layout_difference(last_std.nested, last_got.nested, f"{path}.")
            if inner is not None:
                return inner
    return None


@cache
def _known_types() -> frozenset[str]:
    return frozenset(known_types())


def standard_spec(type_name: str) -> MessageSpec | None:
    """The toolkit's own definition of a type (its standard layout), None for a type the
    toolkit ships no definition of or a schema name that is no ROS type name."""
    try:
        name = full_type_name(type_name)
    except ToolkitError:
        return None
    return parse_msgdef(name) if name in _known_types() else None


@dataclass(frozen=True)
class ChannelLayout:
    """A channel's message type as the toolkit knows it and as the log defines it, compared
    once per channel (:func:`channel_layout`).

    ``standard`` is the toolkit's definition (None: it ships none); ``log`` and ``log_text``
    the log's own (None: the log carries no ``ros2msg`` text); ``difference`` the first place
    the log's departs from the standard layout (:func:`layout_difference`; None when they
    agree or one of them is missing).
    """

    type_name: str
    standard: MessageSpec | None
    log: MessageSpec | None
    log_text: str | None
    difference: str | None

    @property
    def is_standard(self) -> bool:
        """True when the toolkit's fast layout of the type may decode the channel's bytes:
        the toolkit ships the type and the log's schema, if it carries one, agrees with it."""
        return self.standard is not None and self.difference is None


def channel_layout(channel: Channel) -> ChannelLayout:
    """Parse a channel's schema and compare it with the toolkit's layout of its type, once
    per channel (SchemaError: the name is no ROS type name, or the ``ros2msg`` text cannot
    be parsed). A channel without a ``ros2msg`` text has only its type's name to go by."""
    name = full_type_name(channel.schema_name)
    standard = standard_spec(name)
    if channel.schema_encoding != SchemaEncoding.ROS2 or not channel.schema_data:
        return ChannelLayout(name, standard, None, None, None)
    try:
        text = bytes(channel.schema_data).decode("utf-8")
        log = parse_schema_text(name, text)
    except (UnicodeDecodeError, ValueError) as exc:  # SchemaError passes as it is
        raise SchemaError(f"{name}: {exc}") from exc
    difference = None if standard is None else layout_difference(standard, log)
    return ChannelLayout(name, standard, log, text, difference)


__all__ = [
    "ChannelLayout",
    "channel_layout",
    "field_mismatch",
    "field_type",
    "layout_difference",
    "standard_spec",
]
