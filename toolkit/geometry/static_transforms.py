"""The one rule for a usable static transform (``/tf_static``), in one place.

``config init`` reads a log's mounts by it, ingest keeps by it what it writes to
``tf_static.json``, and the stages reading that file (pose, project, label:
:func:`~toolkit.geometry.mounts.read_tf_static`) accept only what it keeps.

A transform is usable when its translation is finite and its rotation a finite quaternion of
norm above :data:`MIN_QUATERNION_NORM`; it is kept with its quaternion normalised. An
unusable one is dropped and counted by reason (:data:`DROP_REASONS`).

A child frame has one parent and one transform. A repeat of the same transform (same parent,
translation and rotation within :data:`SAME_TOLERANCE`, ``q`` and ``-q`` alike) is merged
silently (counted as ``repeats``). A different one for a child frame already seen replaces
it, as tf2 replaces a static transform by a newer one of the same child (the last kept):
said in a warning naming the frame and both transforms, and counted (``conflicting``).
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

#: A rotation quaternion of a smaller norm is no rotation (all zeros: an unset message).
MIN_QUATERNION_NORM = 1e-9
#: Two transforms of one child frame closer than this (m, and per normalised quaternion
#: component) are the same one published again.
SAME_TOLERANCE = 1e-9

#: Why a transform is dropped, in the order they are checked.
DROP_REASONS: tuple[str, ...] = (
    "non_finite_translation",
    "non_finite_rotation",
    "zero_rotation",
    "conflicting",
)
_REASON_WORDS = {
    "non_finite_translation": "NaN or inf in its translation",
    "non_finite_rotation": "NaN or inf in its rotation",
    "zero_rotation": "a rotation quaternion of zero norm",
}
#: At most this many dropped transforms are named in the warning saying them.
_NAMED_AT_MOST = 5


@dataclass(frozen=True)
class TransformRecord:
    """One static transform, ``parent_from_child``, as numbers: stamped ``t_ns``, a
    translation (m) and a rotation quaternion (x, y, z, w). As read from a log it may be
    unusable (even of other lengths than 3 and 4); as kept by :func:`select_static_transforms`
    it is usable and normalised."""

    parent: str
    child: str
    t_ns: int
    translation_m: tuple[float, ...]
    rotation_xyzw: tuple[float, ...]

    def describe(self) -> str:
        """The transform for people (frames quoted, numbers to 6 significant digits)."""
        t = ", ".join(f"{v:.6g}" for v in self.translation_m)
        q = ", ".join(f"{v:.6g}" for v in self.rotation_xyzw)
        return f"{self.parent!r} -> {self.child!r} translation ({t}) m, rotation xyzw ({q})"

    def to_json(self) -> dict[str, Any]:
        """The transform as ``tf_static.json`` holds it."""
        return {
            "parent_frame": self.parent,
            "child_frame": self.child,
            "t_ns": int(self.t_ns),
            "translation_m": list(self.translation_m),
            "rotation_xyzw": list(self.rotation_xyzw),
        }


def transform_problem(translation_m: Sequence[float], rotation_xyzw: Sequence[float]) -> str:
    """Why a transform is unusable (one of :data:`DROP_REASONS`), or "" when it is usable."""
    if len(translation_m) != 3 or not all(math.isfinite(v) for v in translation_m):
        return "non_finite_translation"
    if len(rotation_xyzw) != 4 or not all(math.isfinite(v) for v in rotation_xyzw):
        return "non_finite_rotation"
    if not math.isfinite(math.hypot(*rotation_xyzw)):  # finite parts, a norm beyond floats
        return "non_finite_rotation"
    if math.hypot(*rotation_xyzw) <= MIN_QUATERNION_NORM:
        return "zero_rotation"
    return ""


def usable_transform(record: TransformRecord) -> TransformRecord | str:
    """``record`` with its quaternion normalised when usable, else why not
    (:func:`transform_problem`)."""
    problem = transform_problem(record.translation_m, record.rotation_xyzw)
    if problem:
        return problem
    norm = math.hypot(*record.rotation_xyzw)
    rotation = tuple(float(v) / norm for v in record.rotation_xyzw)
    translation = tuple(float(v) for v in record.translation_m)
    return TransformRecord(record.parent, record.child, int(record.t_ns), translation, rotation)


def same_transform(a: TransformRecord, b: TransformRecord) -> bool:
    """Whether two usable (normalised) transforms are one: same frames, translations and
    rotations within :data:`SAME_TOLERANCE` (``q`` and ``-q`` are one rotation)."""
    if (a.parent, a.child) != (b.parent, b.child):
        return False
    pairs = zip(a.translation_m, b.translation_m, strict=True)
    if any(abs(u - v) > SAME_TOLERANCE for u, v in pairs):
        return False
    quats = list(zip(a.rotation_xyzw, b.rotation_xyzw, strict=True))
    return all(abs(u - v) <= SAME_TOLERANCE for u, v in quats) or all(
        abs(u + v) <= SAME_TOLERANCE for u, v in quats
    )


@dataclass(frozen=True)
class StaticTransformSet:
    """What :func:`select_static_transforms` kept of a log's static transforms, one per child
    frame in the order first seen, and what it dropped (by reason), merged and must say."""

    transforms: tuple[TransformRecord, ...]
    read: int
    dropped: dict[str, int]
    repeats: int
    warnings: tuple[str, ...]

    def to_json(self) -> dict[str, Any]:
        """The manifest's account: ``read = written + repeats + sum(dropped)``."""
        return {
            "read": self.read,
            "written": len(self.transforms),
            "repeats": self.repeats,
            "dropped": {reason: self.dropped.get(reason, 0) for reason in DROP_REASONS},
        }


def select_static_transforms(records: Iterable[TransformRecord], source: str) -> StaticTransformSet:
    """The usable transforms of ``records`` (in the order a log gives them), one per child
    frame, by the module's rule; ``source`` (the topic) names them in the warnings."""
    kept: dict[str, TransformRecord] = {}
    dropped: Counter[str] = Counter()
    unusable: list[str] = []
    warnings: list[str] = []
    read = repeats = 0
    for record in records:
        read += 1
        usable = usable_transform(record)
        if isinstance(usable, str):
            dropped[usable] += 1
            unusable.append(f"{record.parent!r} -> {record.child!r} ({_REASON_WORDS[usable]})")
            continue
        earlier = kept.get(usable.child)
        if earlier is not None and same_transform(earlier, usable):
            repeats += 1
            continue
        if earlier is not None:
            dropped["conflicting"] += 1
            warnings.append(
                f"{source}: child frame {usable.child!r} has conflicting static transforms: "
                f"{earlier.describe()} is replaced by the later {usable.describe()} "
                "(the last one is kept, as tf2 does)"
            )
        kept[usable.child] = usable
    if unusable:
        named = "; ".join(unusable[:_NAMED_AT_MOST])
        more = len(unusable) - _NAMED_AT_MOST
        warnings.insert(
            0,
            f"{source}: {len(unusable)} unusable static transform(s) dropped: {named}"
            + (f"; and {more} more" if more > 0 else ""),
        )
    return StaticTransformSet(tuple(kept.values()), read, dict(dropped), repeats, tuple(warnings))


__all__ = [
    "DROP_REASONS",
    "MIN_QUATERNION_NORM",
    "SAME_TOLERANCE",
    "StaticTransformSet",
    "TransformRecord",
    "same_transform",
    "select_static_transforms",
    "transform_problem",
    "usable_transform",
]
