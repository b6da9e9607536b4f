"""Where every field of a ROS 2 message sits on the wire: CDR layout planning.

ROS 2 serialises a message as *plain CDR, little-endian*: encoding version 1 ``PLAIN_CDR``
(XCDR1) of OMG DDS-XTypes 1.3, section 7.4 "Data Representation", which is the classic OMG
CDR of CORBA 3.x Part 2, section 9.3 "CDR Transfer Syntax". The rules the toolkit relies on are
few, and this is the one place they are written down:

1. **Header.** A payload starts with the 4-byte encapsulation header ``00 01 00 00``: the
   representation identifier ``CDR_LE`` (big-endian ``0x0001``) and two option bytes of zero.
2. **Alignment.** Every primitive of size 2, 4 or 8 starts at an offset that is a multiple of
   its size, counted from the *end* of the header (offset 4 of the payload is offset 0 for
   alignment). The gap is zero bytes of padding. 1-byte primitives are never padded.
3. **Primitives.** ``bool``, ``byte``, ``char``, ``uint8``, ``int8`` take 1 byte, ``(u)int16`` 2,
   ``(u)int32`` and ``float32`` 4, ``(u)int64`` and ``float64`` 8, all little-endian; a bool is
   0 or 1.
4. **Strings.** A ``string`` is a uint32 length (aligned to 4) counting the bytes *including* a
   terminating NUL, then the UTF-8 bytes, then the NUL. No padding follows.
5. **Sequences.** A sequence (``float32[]``, bounded or not) is a uint32 element count (aligned
   to 4) followed by the elements; the first element is aligned to its own size only if there
   is one. A fixed-size array (``float64[9]``) has no count, only its elements.
6. **Nested messages** are written field by field in place, with no header and no alignment of
   their own. A message with no fields is written as one uint8 (zero), as ROS 2 does.

Once the length of every string and sequence of a message is known, every field therefore
sits at a fixed offset. This module flattens a :class:`~toolkit.mcapio.msgdefs.MessageSpec`
into its wire-level fields (:class:`Leaf`, named by dotted path: ``header.stamp.sec``), calls
the tuple of those lengths the message's *shape* (:meth:`Plan.shape_key`), and turns a type and
a shape into a numpy structured dtype covering one whole payload (:meth:`Plan.layout`). A batch
of payloads sharing a shape is then one numpy structured array: that is how
:mod:`toolkit.mcapio.cdr` decodes and :mod:`toolkit.mcapio.cdr_encode` encodes thousands of
messages without Python work per field per message.

Messages holding arrays of nested messages or arrays of strings (``tf2_msgs/TFMessage``,
``terrain_msgs/RoughFeatureArray``) have no such layout (:attr:`Plan.has_fixed_layout` is
False); they are encoded and decoded one message at a time.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, Literal

import numpy as np

from toolkit.errors import CdrError, SchemaError
from toolkit.mcapio.msgdefs import (
    FieldSpec,
    MessageSpec,
    full_type_name,
    parse_msgdef,
    parse_schema_text,
)

#: Encapsulation header of little-endian plain CDR (XCDR1), as ROS 2 writes it (rule 1).
CDR_LE_HEADER = b"\x00\x01\x00\x00"

#: Wire types of ROS 2 primitives (rule 3). ``char`` is uint8 in ROS 2.
PRIMITIVE_DTYPES: dict[str, np.dtype[Any]] = {
    "bool": np.dtype("u1"),
    "byte": np.dtype("u1"),
    "char": np.dtype("u1"),
    "uint8": np.dtype("u1"),
    "int8": np.dtype("i1"),
    "int16": np.dtype("<i2"),
    "uint16": np.dtype("<u2"),
    "int32": np.dtype("<i4"),
    "uint32": np.dtype("<u4"),
    "int64": np.dtype("<i8"),
    "uint64": np.dtype("<u8"),
    "float32": np.dtype("<f4"),
    "float64": np.dtype("<f8"),
}

#: Name, in a payload's structured dtype, of the 4 header bytes.
ENCAP = "#encap"

#: The uint32 length prefix of strings and sequences (rules 4 and 5).
U32 = struct.Struct("<I")

LeafKind = Literal["scalar", "fixed", "sequence", "string", "empty", "complex"]


def length_name(path: str) -> str:
    """Name, in a payload's structured dtype, of the uint32 length prefix of field ``path``."""
    return f"{path}#n"


def nul_name(path: str) -> str:
    """Name, in a payload's structured dtype, of the NUL terminating string field ``path``."""
    return f"{path}#nul"


@dataclass(frozen=True)
class Leaf:
    """One wire-level field of a flattened message.

    ``path`` is the dotted field path (``header.stamp.sec``). ``kind`` is:

    - ``scalar``: one primitive; ``fixed``: a fixed-size primitive array of ``count`` elements;
    - ``sequence``: a primitive sequence; ``string``: a string;
    - ``empty``: the placeholder uint8 of a field-less message (path ends in ``#empty``);
    - ``complex``: an array of messages or of strings, which has no fixed layout.

    ``dtype`` is the wire dtype of one element (None for strings and complex leaves); ``spec``
    the field it comes from (None for ``empty``).
    """

    path: str
    kind: LeafKind
    type_name: str
    dtype: np.dtype[Any] | None = None
    count: int = 1
    spec: FieldSpec | None = None

    @property
    def size(self) -> int:
        """Bytes of one element, which is also its alignment (1 for strings)."""
        return 1 if self.dtype is None else self.dtype.itemsize

    @property
    def is_bool(self) -> bool:
        return self.type_name == "bool"


def flatten(spec: MessageSpec, prefix: str = "") -> list[Leaf]:
    """The leaves of ``spec`` in wire order; nested messages (not arrays of them) are inlined."""
    if not spec.fields:
        return [Leaf(f"{prefix}#empty", "empty", "uint8", PRIMITIVE_DTYPES["uint8"])]
    leaves: list[Leaf] = []
    for f in spec.fields:
        path = f"{prefix}{f.name}"
        if f.type_name == "wstring":
            raise SchemaError(f"{spec.name}.{f.name}: wstring fields are not supported")
        if f.nested is not None:
            if f.is_array:
                leaves.append(Leaf(path, "complex", f.type_name, spec=f))
            else:
                leaves.extend(flatten(f.nested, f"{path}."))
        elif f.is_string:
            leaves.append(Leaf(path, "complex" if f.is_array else "string", f.type_name, spec=f))
        else:
            dt = PRIMITIVE_DTYPES[f.type_name]
            if not f.is_array:
                leaves.append(Leaf(path, "scalar", f.type_name, dt, spec=f))
            elif f.array_length is not None:
                leaves.append(Leaf(path, "fixed", f.type_name, dt, f.array_length, spec=f))
            else:
                leaves.append(Leaf(path, "sequence", f.type_name, dt, spec=f))
    return leaves


def align(offset: int, size: int) -> int:
    """The first offset at or after ``offset`` where a ``size``-byte primitive may start.

    Offsets are absolute in the payload; alignment counts from the end of the 4-byte header
    (rule 2), so ``align(5, 8) == 12`` and ``align(12, 8) == 12``.
    """
    if size <= 1:
        return offset
    return 4 + (offset - 4 + size - 1) // size * size


#: One entry of a structured dtype's ``formats``: a dtype, or a dtype and a sub-array shape.
_Format = np.dtype[Any] | tuple[np.dtype[Any], tuple[int]]


@dataclass
class Plan:
    """Everything about a message type's wire layout that does not depend on one shape.

    ``leaves`` are the wire-level fields in order; ``dynamic`` those whose length is part of
    the shape (strings and primitive sequences), in order: a *shape key* is the tuple of their
    length prefixes. Built once per type by :func:`plan_for`.
    """

    spec: MessageSpec
    leaves: tuple[Leaf, ...]
    dynamic: tuple[Leaf, ...]
    has_fixed_layout: bool
    _layouts: dict[tuple[tuple[int, ...], int], np.dtype[Any]] = field(default_factory=dict)

    @property
    def name(self) -> str:
        """The full type name (``pkg/msg/Type``)."""
        return self.spec.name

    @property
    def paths(self) -> frozenset[str]:
        """Dotted paths a caller may give values for (every leaf but ``#empty`` placeholders)."""
        return frozenset(leaf.path for leaf in self.leaves if leaf.kind != "empty")

    def shape_key(self, shape: Mapping[str, int]) -> tuple[int, ...]:
        """The shape key of ``shape`` ({dotted path: uint32 length prefix}), checked."""
        try:
            key = tuple(int(shape[leaf.path]) for leaf in self.dynamic)
        except KeyError as exc:
            raise CdrError(f"{self.name}: shape lacks the length of {exc.args[0]!r}") from exc
        if any(v < 0 or v > 0xFFFFFFFF for v in key):
            raise CdrError(f"{self.name}: shape lengths must fit in a uint32: {dict(shape)}")
        return key

    def layout(self, key: tuple[int, ...], itemsize: int | None = None) -> np.dtype[Any]:
        """The structured dtype of one payload of shape ``key`` (cached per key and itemsize).

        Fields: ``#encap`` (4 header bytes), each leaf by its dotted path (a fixed array or a
        sequence as a sub-array ``(count,)``, a string as ``S<len-1>`` without its NUL), each
        length prefix ``<path>#n`` and each string terminator ``<path>#nul``; padding is left
        unnamed. A string of length prefix 0 or 1 and an empty sequence have no data field.
        ``itemsize`` defaults to the exact payload length; a larger one allows trailing bytes.
        """
        cache_key = (key, -1 if itemsize is None else itemsize)
        dt = self._layouts.get(cache_key)
        if dt is None:
            dt = self._build_layout(key, itemsize)
            self._layouts[cache_key] = dt
        return dt

    def _build_layout(self, key: tuple[int, ...], itemsize: int | None) -> np.dtype[Any]:
        if not self.has_fixed_layout:
            raise CdrError(f"{self.name} has no fixed layout (it holds arrays of messages)")
        names: list[str] = [ENCAP]
        formats: list[_Format] = [(np.dtype("u1"), (4,))]
        offsets: list[int] = [0]
        lengths = dict(zip((leaf.path for leaf in self.dynamic), key, strict=True))

        def add(name: str, fmt: _Format, at: int) -> None:
            names.append(name)
            formats.append(fmt)
            offsets.append(at)

        off = len(CDR_LE_HEADER)
        for leaf in self.leaves:
            if leaf.dtype is not None and leaf.kind in ("scalar", "empty"):
                off = align(off, leaf.size)
                add(leaf.path, leaf.dtype, off)
                off += leaf.size
            elif leaf.dtype is not None and leaf.kind == "fixed":
                off = align(off, leaf.size)
                add(leaf.path, (leaf.dtype, (leaf.count,)), off)
                off += leaf.size * leaf.count
            elif leaf.dtype is not None and leaf.kind == "sequence":
                off = align(off, 4)
                add(length_name(leaf.path), np.dtype("<u4"), off)
                off += 4
                count = lengths[leaf.path]
                if count:
                    off = align(off, leaf.size)
                    add(leaf.path, (leaf.dtype, (count,)), off)
                    off += leaf.size * count
            elif leaf.kind == "string":
                off = align(off, 4)
                add(length_name(leaf.path), np.dtype("<u4"), off)
                off += 4
                nbytes = lengths[leaf.path]
                if nbytes > 1:
                    add(leaf.path, np.dtype(f"S{nbytes - 1}"), off)
                if nbytes > 0:
                    add(nul_name(leaf.path), np.dtype("u1"), off + nbytes - 1)
                off += nbytes
        size = off if itemsize is None else itemsize
        if size < off:
            raise CdrError(f"{self.name}: itemsize {size} is shorter than the layout ({off})")
        return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": size})

    def read_shape(self, data: bytes, index: int) -> tuple[tuple[int, ...], int]:
        """Read one payload's length prefixes: its shape key and the end offset of its last field.

        ``index`` is the payload's position in its batch, for error messages. Raises
        :class:`CdrError` if the header is not plain little-endian CDR or a field runs past the
        end of ``data``.
        """
        check_header(self.name, data, index)
        n = len(data)
        off = len(CDR_LE_HEADER)
        key: list[int] = []
        for leaf in self.leaves:
            if leaf.kind in ("scalar", "empty"):
                off = align(off, leaf.size) + leaf.size
            elif leaf.kind == "fixed":
                off = align(off, leaf.size) + leaf.size * leaf.count
            else:  # sequence or string: read the uint32 prefix
                off = align(off, 4)
                if off + 4 > n:
                    raise _truncated(self.name, index, leaf.path, off + 4, n)
                count = U32.unpack_from(data, off)[0]
                off += 4
                key.append(count)
                if count:
                    off = align(off, leaf.size) + leaf.size * count
            if off > n:
                raise _truncated(self.name, index, leaf.path, off, n)
        return tuple(key), off


def _truncated(type_name: str, index: int, path: str, need: int, have: int) -> CdrError:
    return CdrError(
        f"{type_name}: payload {index} is truncated in field {path!r} "
        f"(needs at least {need} bytes, has {have})"
    )


def check_header(type_name: str, data: bytes, index: int) -> None:
    """Refuse payload number ``index`` unless it starts with a little-endian plain CDR header."""
    if len(data) < 4:
        raise CdrError(f"{type_name}: payload {index} has {len(data)} bytes, no CDR header")
    if data[0] != 0 or data[1] != 1:
        raise CdrError(
            f"{type_name}: payload {index} has encapsulation {data[:2].hex()}, "
            "only little-endian plain CDR (0001) is supported"
        )


@lru_cache(maxsize=256)
def plan_for_spec(spec: MessageSpec) -> Plan:
    """The layout plan of a parsed message type (cached)."""
    leaves = tuple(flatten(spec))
    dynamic = tuple(leaf for leaf in leaves if leaf.kind in ("sequence", "string"))
    fixed = not any(leaf.kind == "complex" for leaf in leaves)
    return Plan(spec, leaves, dynamic, fixed)


@lru_cache(maxsize=256)
def _plan_for_name(type_name: str) -> Plan:
    return plan_for_spec(parse_msgdef(type_name))


def plan_for(type_name: str | MessageSpec, schema_text: str | None = None) -> Plan:
    """The layout plan of a type: a toolkit type name, a parsed spec, or a log's schema text.

    With ``schema_text`` (a concatenated ``ros2msg`` definition, as a log carries), the type is
    laid out by that definition rather than by the toolkit's own ``.msg`` files.
    """
    if isinstance(type_name, MessageSpec):
        return plan_for_spec(type_name)
    if schema_text is not None:
        return plan_for_spec(parse_schema_text(type_name, schema_text))
    return _plan_for_name(full_type_name(type_name))


def layout(spec: MessageSpec, shape: Mapping[str, int]) -> np.dtype[Any]:
    """The numpy structured dtype covering a whole payload of ``spec`` with the given shape.

    ``shape`` maps the dotted path of every string and sequence field (``"header.frame_id"``,
    ``"ranges"``) to its uint32 length prefix as it appears on the wire: the element count of a
    sequence, the byte count *including the NUL* of a string. Field names and offsets are those
    of :meth:`Plan.layout`; the itemsize is the exact payload length.
    """
    plan = plan_for_spec(spec)
    return plan.layout(plan.shape_key(shape))


__all__ = [
    "CDR_LE_HEADER",
    "ENCAP",
    "PRIMITIVE_DTYPES",
    "U32",
    "Leaf",
    "LeafKind",
    "Plan",
    "align",
    "check_header",
    "flatten",
    "layout",
    "length_name",
    "nul_name",
    "plan_for",
    "plan_for_spec",
]
