"""ROS 2 message definitions: the schema texts we write into MCAP logs, and their parsed form.

The ``.msg`` files under ``schemas/msg/<pkg>/<Type>.msg`` (installed as ``toolkit.schemas``) are the
source of truth. :func:`load_msgdef` concatenates a type's text with all its dependencies in the
layout rosbag2 writes and ``mcap_ros2`` parses (a line of 80 ``=`` then ``MSG: pkg/Type`` before
each dependency). :func:`parse_msgdef` turns the same definitions into a small typed tree
(:class:`MessageSpec`) that the CDR layout code walks. :func:`parse_schema_text` does the same for a
concatenated schema text read from a log, so logs written by other tools decode by their own
definitions.

Parsing of single ``.msg`` texts is delegated to ROS 2's own ``rosidl_adapter`` parser, vendored
as :mod:`toolkit.vendor.rosidl_adapter` (Apache-2.0, see its ``NOTICE``), so constants, default
values and bounds follow ROS 2 exactly.
"""

from __future__ import annotations

import contextlib
import io
import re
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from importlib.resources import files

from toolkit.errors import SchemaError
from toolkit.vendor.rosidl_adapter import parser as rosidl

#: The separator line rosbag2 writes between the blocks of a concatenated definition.
SEPARATOR = "=" * 80

#: Primitive (non-message) field types of ROS 2 ``.msg`` files, strings included.
PRIMITIVE_TYPES: frozenset[str] = frozenset(rosidl.PRIMITIVE_TYPES)

DefaultValue = bool | int | float | str | tuple[bool | int | float | str, ...]


@dataclass(frozen=True)
class FieldSpec:
    """One field of a message.

    ``type_name`` is a primitive name (``float64``, ``string``...) or a full message name
    (``geometry_msgs/msg/Vector3``, then ``nested`` holds its spec). ``array_length`` is the
    length of a fixed-size array (``float64[9]``) and ``None`` otherwise; ``upper_bound`` is the
    bound of a bounded sequence or string (``float32[<=10]``, ``string<=8``), which does not change
    the wire format.
    """

    name: str
    type_name: str
    is_array: bool
    array_length: int | None
    upper_bound: int | None
    is_primitive: bool
    nested: MessageSpec | None
    default: DefaultValue | None = None

    @property
    def is_sequence(self) -> bool:
        """True for an unbounded or bounded sequence (a uint32 count precedes it on the wire)."""
        return self.is_array and self.array_length is None

    @property
    def is_string(self) -> bool:
        """True when the element type is a (narrow or wide) string."""
        return self.type_name in ("string", "wstring")


@dataclass(frozen=True)
class MessageSpec:
    """A parsed message type: its full name, fields in wire order, and named constants."""

    name: str
    fields: tuple[FieldSpec, ...]
    constants: tuple[tuple[str, str, bool | int | float | str], ...] = ()

    def field(self, name: str) -> FieldSpec:
        """The field called ``name`` (SchemaError if there is none)."""
        for f in self.fields:
            if f.name == name:
                return f
        raise SchemaError(f"{self.name} has no field {name!r}")

    def constant(self, name: str) -> bool | int | float | str:
        """The value of the constant called ``name`` (SchemaError if there is none)."""
        for _type, cname, value in self.constants:
            if cname == name:
                return value
        raise SchemaError(f"{self.name} has no constant {name!r}")


def split_type_name(name: str) -> tuple[str, str]:
    """``"pkg/msg/Type"`` or ``"pkg/Type"`` -> ``("pkg", "Type")`` (SchemaError otherwise)."""
    parts = name.strip().split("/")
    if len(parts) == 3 and parts[1] == "msg":
        pkg, typ = parts[0], parts[2]
    elif len(parts) == 2:
        pkg, typ = parts
    else:
        raise SchemaError(f"not a ROS 2 message type name: {name!r} (expected 'pkg/msg/Type')")
    if not pkg or not typ:
        raise SchemaError(f"not a ROS 2 message type name: {name!r} (expected 'pkg/msg/Type')")
    return pkg, typ


def full_type_name(name: str) -> str:
    """The canonical ``pkg/msg/Type`` form of a message type name."""
    pkg, typ = split_type_name(name)
    return f"{pkg}/msg/{typ}"


def msg_text(name: str) -> str:
    """The text of one ``.msg`` file shipped with the toolkit (no dependencies)."""
    pkg, typ = split_type_name(name)
    resource = files("toolkit.schemas").joinpath("msg", pkg, f"{typ}.msg")
    try:
        return resource.read_text(encoding="utf-8")
    except (FileNotFoundError, NotADirectoryError, IsADirectoryError) as exc:
        raise SchemaError(f"no message definition for {pkg}/msg/{typ}", path=str(resource)) from exc


def _parse_one(pkg: str, typ: str, text: str) -> rosidl.MessageSpecification:
    """Parse a single ``.msg`` text; the vendored parser's stderr chatter is swallowed."""
    try:
        with contextlib.redirect_stderr(io.StringIO()):
            return rosidl.parse_message_string(pkg, typ, text)
    except Exception as exc:  # the vendored parser raises assorted exception types
        raise SchemaError(f"cannot parse the definition of {pkg}/msg/{typ}: {exc}") from exc


def _is_primitive(t: rosidl.BaseType) -> bool:
    """Whether a parsed field type is primitive (``string`` included): one without a package.

    The same test as the parser's ``BaseType.is_primitive_type``, which it leaves unannotated.
    """
    return t.pkg_name is None


def _dependencies(spec: rosidl.MessageSpecification) -> list[str]:
    """Full names of the message types a definition's fields refer to, in field order."""
    out: list[str] = []
    for f in spec.fields:
        if not _is_primitive(f.type):
            out.append(f"{f.type.pkg_name}/msg/{f.type.type}")
    return out


@cache
def _raw_spec(name: str) -> rosidl.MessageSpecification:
    pkg, typ = split_type_name(name)
    return _parse_one(pkg, typ, msg_text(name))


def dependency_order(name: str) -> list[str]:
    """``name`` and every type it depends on, depth-first in field order, each once."""
    order: list[str] = []
    seen: set[str] = set()

    def visit(type_name: str) -> None:
        if type_name in seen:
            return
        seen.add(type_name)
        order.append(type_name)
        for dep in _dependencies(_raw_spec(type_name)):
            visit(dep)

    visit(full_type_name(name))
    return order


@cache
def load_msgdef(name: str) -> str:
    """The full ROS 2 MCAP schema text (encoding ``ros2msg``) of a message type.

    The type's own definition comes first, then each dependency (recursively, depth-first in
    field order, each once) introduced by a line of 80 ``=`` and ``MSG: pkg/Type``: exactly
    what rosbag2 writes and ``mcap_ros2``'s decoder reads.
    """
    order = dependency_order(name)
    blocks = [msg_text(order[0]).rstrip("\n")]
    for dep in order[1:]:
        pkg, typ = split_type_name(dep)
        blocks.append(f"{SEPARATOR}\nMSG: {pkg}/{typ}\n{msg_text(dep).rstrip()}")
    return "\n".join(blocks) + "\n"


def _default(field: rosidl.Field) -> DefaultValue | None:
    value = field.default_value
    if value is None:
        return None
    if isinstance(value, list):
        return tuple(value)
    if isinstance(value, bool | int | float | str):
        return value
    raise SchemaError(f"unsupported default value {value!r} for field {field.name!r}")


def _build(
    name: str,
    lookup: Callable[[str], rosidl.MessageSpecification],
    stack: tuple[str, ...] = (),
) -> MessageSpec:
    """Convert a parsed definition (and, recursively, its dependencies) into a MessageSpec."""
    if name in stack:
        raise SchemaError(f"recursive message definition: {' -> '.join((*stack, name))}")
    raw = lookup(name)
    fields: list[FieldSpec] = []
    for f in raw.fields:
        t = f.type
        if _is_primitive(t):
            type_name: str = t.type
            nested = None
        else:
            type_name = f"{t.pkg_name}/msg/{t.type}"
            nested = _build(type_name, lookup, (*stack, name))
        size: int | None = t.array_size
        fixed = int(size) if t.is_array and size and not t.is_upper_bound else None
        upper = size if t.is_array and t.is_upper_bound else None
        if not t.is_array and _is_primitive(t) and t.string_upper_bound:
            upper = t.string_upper_bound
        fields.append(
            FieldSpec(
                name=f.name,
                type_name=type_name,
                is_array=bool(t.is_array),
                array_length=fixed,
                upper_bound=upper,
                is_primitive=_is_primitive(t),
                nested=nested,
                default=_default(f),
            )
        )
    constants = tuple((c.type, c.name, c.value) for c in raw.constants)
    return MessageSpec(name=name, fields=tuple(fields), constants=constants)


@cache
def parse_msgdef(name: str) -> MessageSpec:
    """The parsed tree of a message type shipped with the toolkit (dependencies resolved)."""
    return _build(full_type_name(name), _raw_spec)


def _split_schema_text(schema_name: str, schema_text: str) -> dict[str, str]:
    """Split a concatenated ``ros2msg`` schema into ``{pkg/msg/Type: its own text}``."""
    blocks: dict[str, str] = {}
    current = full_type_name(schema_name)
    for i, block in enumerate(re.split(r"^={3,}\s*$", schema_text, flags=re.MULTILINE)):
        m = re.search(r"^MSG:\s+(\S+)\s*$", block, flags=re.MULTILINE)
        if m:
            current = full_type_name(m.group(1))
            block = block[: m.start()] + block[m.end() :]
        elif i > 0:
            raise SchemaError(f"schema {schema_name}: block {i} has no 'MSG: pkg/Type' line")
        blocks.setdefault(current, block)
    return blocks


def parse_schema_text(schema_name: str, schema_text: str) -> MessageSpec:
    """The parsed tree of a concatenated ``ros2msg`` schema text, e.g. one read from a log.

    Types the text does not define are taken from the toolkit's own definitions (rosbag2 omits
    nothing, but hand-written schemas sometimes leave out ``builtin_interfaces/Time``).
    """
    blocks = _split_schema_text(schema_name, schema_text)
    cache: dict[str, rosidl.MessageSpecification] = {}

    def lookup(name: str) -> rosidl.MessageSpecification:
        if name not in cache:
            if name in blocks:
                pkg, typ = split_type_name(name)
                cache[name] = _parse_one(pkg, typ, blocks[name])
            else:
                cache[name] = _raw_spec(name)
        return cache[name]

    return _build(full_type_name(schema_name), lookup)


def known_types() -> list[str]:
    """Full names of every message type shipped with the toolkit, sorted."""
    root = files("toolkit.schemas").joinpath("msg")
    names: list[str] = []
    for pkg in root.iterdir():
        if not pkg.is_dir():
            continue
        for entry in pkg.iterdir():
            if entry.name.endswith(".msg"):
                names.append(f"{pkg.name}/msg/{entry.name[: -len('.msg')]}")
    return sorted(names)
