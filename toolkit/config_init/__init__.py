"""``terrain config init``: a starting configuration written from a log itself.

Three pure steps and one that reads the log:

1. :func:`summarize_log` reads what the log says about its sensors: every topic's message
   type, count and rate (through :func:`~toolkit.mcapio.info.scan_log`, as ``terrain info``),
   the ``header.frame_id`` of each sensor topic's first messages, the IMU's mean acceleration
   over them (where gravity points in the IMU's frame), and the static transforms of
   ``/tf_static`` when the log has them.
2. :func:`guess_roles` matches topics to the roles of ``[topics]``: by message type first
   (the types :data:`~toolkit.ingestion.roles.ROLE_SPECS` accepts), then, when several topics
   share a type, by name (``/imu/data`` over ``/imu/data_raw``; a wheel controller's odometry,
   never ``/odometry/filtered``, which is a fusion's output and not a sensor). A topic with
   no messages, or named ``""`` (an absent role in ``[topics]``), plays no role (said on
   the terminal with what was chosen instead), and one with a rate comes before one
   without. Each guess keeps why it was made and the alternatives; a role nothing matches
   says so.
3. :func:`render_config` writes the TOML text: the built-in default's text (every key, every
   comment) with the values the log decides replaced, each replaced value preceded by
   comments saying why, and a head saying which stages the log can feed. The result is
   loaded back with :func:`~toolkit.config.parse_config` before it is returned
   (:func:`init_config`), so what ``config init`` prints always loads.

Nothing here writes TOML through a library: the core depends on none that writes, and
a generated file should read like the hand-written ones (comments where the values are).

The package's modules follow the steps: :mod:`~toolkit.config_init.summary` (1),
:mod:`~toolkit.config_init.roles` (2), and for 3 :mod:`~toolkit.config_init.settings`,
:mod:`~toolkit.config_init.mounts` (``[vehicle]``) and :mod:`~toolkit.config_init.render`
(the text); :func:`render_config` and :func:`init_config` are here.
"""

from __future__ import annotations

import importlib.resources
import logging
from collections.abc import Mapping
from pathlib import Path

from toolkit.config import DEFAULT_CONFIG_RESOURCE, parse_config
from toolkit.config_init.render import Setting, apply_settings, comment_lines
from toolkit.config_init.roles import RoleGuess, guess_role, guess_roles
from toolkit.config_init.settings import StageVerdicts, file_head, log_settings, stage_verdicts
from toolkit.config_init.summary import LogSummary, TopicSummary, summarize_log
from toolkit.errors import ConfigError

_log = logging.getLogger(__name__)


def _default_text() -> str:
    resource = importlib.resources.files("toolkit").joinpath(DEFAULT_CONFIG_RESOURCE)
    return resource.read_text(encoding="utf-8")


def render_config(summary: LogSummary, guesses: Mapping[str, RoleGuess]) -> str:
    """The configuration's TOML text for a log (see the module docstring)."""
    head = file_head(summary, guesses, stage_verdicts(summary, guesses))
    return apply_settings(_default_text(), head, log_settings(summary, guesses))


def init_config(path: str | Path) -> str:
    """``terrain config init``: the starting configuration of a log, as TOML text that
    :func:`~toolkit.config.parse_config` has just loaded without error."""
    summary = summarize_log(path)
    if summary.problems:  # said on the terminal too, not only in the file's comments
        _log.warning(
            "%s: %d problem(s) in this log (damaged or truncated); the configuration is "
            "guessed from what could be read: see `terrain info %s`",
            summary.path,
            summary.problems,
            summary.path,
        )
    guesses = guess_roles(summary)
    notices = (notice for guess in guesses.values() for notice in guess.notices)
    for note in dict.fromkeys((*summary.notes, *summary.tf_warnings, *notices)):
        _log.warning("%s: %s", summary.path, note)
    text = render_config(summary, guesses)
    try:
        parse_config(text, source=f"<configuration written for {summary.path}>")
    except ConfigError as exc:  # a bug here, said as one line rather than a bad file
        raise ConfigError(
            f"the configuration written for this log does not load: {exc}", path
        ) from exc
    return text


__all__ = [
    "LogSummary",
    "RoleGuess",
    "Setting",
    "StageVerdicts",
    "TopicSummary",
    "apply_settings",
    "comment_lines",
    "guess_role",
    "guess_roles",
    "init_config",
    "log_settings",
    "render_config",
    "stage_verdicts",
    "summarize_log",
]
