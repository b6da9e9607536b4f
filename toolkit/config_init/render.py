"""Step 3 of ``config init``, the text: the default's TOML with the decided values and
the comments saying why put in (:class:`Setting`, :func:`apply_settings`).

Part of :mod:`toolkit.config_init`, whose docstring tells the steps.
"""

from __future__ import annotations

import re
import textwrap
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from toolkit.config import escape_controls

# --------------------------------------------------------------------------------------
# 3. The TOML text
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Setting:
    """What to write for one key of the default: ``value`` as TOML text (None keeps the
    default's line) and the comment lines to put above it (without ``#``)."""

    value: str | None
    comments: tuple[str, ...] = ()


Settings = dict[tuple[str, str], Setting]


COMMENT_WIDTH = 96


def comment_lines(texts: Iterable[str]) -> list[str]:
    """TOML comment lines of ``texts``, each wrapped to :data:`COMMENT_WIDTH` (a text's
    leading spaces indent its continuation lines too); an empty text is a bare ``#``. Control
    characters and line separators are escaped (:func:`~toolkit.config.escape_controls`): a
    name from the log can neither break a comment nor end it."""
    out: list[str] = []
    for text in map(escape_controls, texts):
        indent = " " * (len(text) - len(text.lstrip(" ")))
        wrapped = textwrap.wrap(
            text,
            width=COMMENT_WIDTH - 2,
            subsequent_indent=indent + "  ",
            break_long_words=False,
            break_on_hyphens=False,
        )
        out.extend(f"# {w}".rstrip() for w in wrapped or [""])
    return out


_SECTION = re.compile(r"^\[([A-Za-z0-9_.]+)\]")
_KEY = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)\s*=")
_CONTINUATION = re.compile(r"^\s+#")


def apply_settings(default_text: str, head: Sequence[str], settings: Settings) -> str:
    """The default's text with ``head`` replacing its opening comments and each key of
    ``settings`` preceded by its comments and, where it gives a value, rewritten (the
    default's comments on a rewritten key, which describe Stanley, are dropped). A setting
    whose key the default's section lacks (a role declared since, with no line in the
    default) is written at the end of its section.

    Raises ValueError for a setting of a section the default does not have, or a new key
    without a value (a programming error)."""
    lines = default_text.splitlines()
    start = next(i for i, line in enumerate(lines) if _KEY.match(line))
    out = [*comment_lines(head), ""]
    section = ""
    sections = {m.group(1) for m in map(_SECTION.match, lines) if m}
    used: set[tuple[str, str]] = set()
    skipping = False

    def close(section: str) -> None:
        """Write the section's settings the default has no line for."""
        extra = [k for k in settings if k[0] == section and k not in used]
        if not extra:
            return
        while out and not out[-1].strip():
            out.pop()
        for key in extra:
            setting = settings[key]
            if setting.value is None:
                raise ValueError(f"a setting for a new key without a value: {key}")
            out.extend(comment_lines(setting.comments))
            out.append(f"{key[1]} = {setting.value}")
            used.add(key)
        out.append("")

    for line in lines[start:]:
        if skipping and _CONTINUATION.match(line):
            continue
        skipping = False
        header = _SECTION.match(line)
        if header:
            close(section)
            section = header.group(1)
        key = _KEY.match(line)
        setting = settings.get((section, key.group(1))) if key else None
        if key is None or setting is None:
            out.append(line)
            continue
        used.add((section, key.group(1)))
        out.extend(comment_lines(setting.comments))
        if setting.value is None:
            out.append(line)
        else:
            out.append(f"{key.group(1)} = {setting.value}")
            skipping = True
    close(section)
    unknown = {k for k in set(settings) - used if k[0] not in sections}
    if unknown:
        raise ValueError(f"settings for sections the default does not have: {sorted(unknown)}")
    return "\n".join(out).rstrip("\n") + "\n"
