"""The evaluation's rows, each method declared once (as the stages are in
:mod:`toolkit.stages.registry`).

A method's declaration is its key (its entry in ``summary.json`` and, but for the headline,
its column of ``scores.parquet``), its name in the report, its line in the ROC figure, and
its kind: the headline model the report is about, a method it is compared with, or an
ablation of the headline (``summary.json`` lists those under ``ablations``). The report, the
summary, the scores table, the stage's terminal lines and the export all read
:data:`METHODS`; how each row is trained is :mod:`toolkit.analysis.methods` and
:mod:`toolkit.stages.evaluate`, whose :meth:`~toolkit.analysis.methods.Rows.add` refuses a
key not declared here. Adding a method is one line here, its computation, and its column
in ``schemas/tables/scores.json`` (``tests/analysis/test_method_registry.py`` holds the
schema to this list).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

Kind = Literal["headline", "compared", "ablation"]


@dataclass(frozen=True)
class Method:
    """One row of the evaluation.

    ``color`` and ``linestyle`` are matplotlib's (tab10 colours; solid: methods on laser
    points, dotted: beyond the paper, dash-dot: the oracle, dashed: ablations), fixed per
    method so that it looks the same in every report whatever rows a run has.
    """

    key: str
    title: str
    kind: Kind
    color: str
    linestyle: str


#: Every method, in the report's order (its table, its ROC legend, the summary's keys, the
#: scores table's columns). A row a run cannot train (no oracle off the simulator, no
#: closest laser) is left out of that run, and the report says why.
METHODS: tuple[Method, ...] = (
    Method("self_supervised", "self-supervised (this model)", "headline", "black", "-"),
    Method(
        "paper_exact",
        "self-supervised, the paper's method as written",
        "compared",
        "tab:blue",
        "-",
    ),
    Method("baseline_all_lasers", "race obstacle test, all lasers", "compared", "tab:red", "-"),
    Method(
        "baseline_closest_laser",
        "race obstacle test, closest laser",
        "compared",
        "tab:orange",
        "-",
    ),
    Method(
        "baseline_model_points",
        "race obstacle test, on this model's points",
        "compared",
        "tab:brown",
        "-",
    ),
    Method(
        "model_closest_laser",
        "self-supervised, on the closest laser's points",
        "compared",
        "tab:green",
        "-",
    ),
    Method(
        "boosted",
        "beyond the paper: gradient-boosted trees on patch features",
        "compared",
        "tab:purple",
        ":",
    ),
    Method(
        "online",
        "learning while driving: each event scored as it was seen (sect. 8)",
        "compared",
        "gold",
        "-",
    ),
    Method("oracle", "oracle: model on true terrain heights", "compared", "tab:gray", "-."),
    Method("no_time_term", "ablation: no time term (alpha_3 = 0)", "ablation", "tab:cyan", "--"),
    Method(
        "no_rate_terms",
        "ablation: no roll/pitch-rate terms (alpha_7 = alpha_9 = 0)",
        "ablation",
        "tab:olive",
        "--",
    ),
    Method("no_learning", "ablation: the initial guess, not learned", "ablation", "tab:pink", "--"),
)

_BY_KEY = {m.key: m for m in METHODS}
#: The method the report is about: drawn last (on top), thick and black; its scores are
#: scores.parquet's ``r_combined`` and ``predicted``, which ``terrain export`` carries.
(HEADLINE,) = [m.key for m in METHODS if m.kind == "headline"]
#: The method the headline is judged against, as the paper's Fig. 6 does: the race's
#: obstacle test on the closest laser.
RACE_TEST = "baseline_closest_laser"
#: The headline's own starting point, unlearned: what learning buys is the difference.
UNLEARNED_START = "no_learning"
#: Every method's key, in the report's order.
METHOD_KEYS = tuple(_BY_KEY)
#: The methods the summary lists at its top level (the headline and those compared).
MAIN_METHODS = tuple(m.key for m in METHODS if m.kind != "ablation")
#: The ablations, listed under the summary's ``ablations``.
ABLATION_NAMES = tuple(m.key for m in METHODS if m.kind == "ablation")
#: scores.parquet's columns of the methods besides the headline, in the report's order.
SCORE_COLUMNS = tuple(m.key for m in METHODS if m.kind != "headline")


if not {RACE_TEST, UNLEARNED_START} <= set(_BY_KEY):
    raise ImportError("method_registry: RACE_TEST and UNLEARNED_START must be declared methods")


class UnknownMethodError(KeyError):
    """A row named by a key no method declares."""

    def __init__(self, key: str) -> None:
        super().__init__(key)
        self.key = key

    def __str__(self) -> str:
        return f"no method {self.key!r} is declared (toolkit/analysis/method_registry.py)"


def method(key: str) -> Method:
    """The method declared under ``key``; :class:`UnknownMethodError` for any other."""
    try:
        return _BY_KEY[key]
    except KeyError:
        raise UnknownMethodError(key) from None


def title(key: str) -> str:
    """The report's name of ``key``'s method, or the key itself for an undeclared one (an
    old summary's row, shown rather than lost)."""
    found = _BY_KEY.get(key)
    return found.title if found is not None else key


__all__ = [
    "ABLATION_NAMES",
    "HEADLINE",
    "MAIN_METHODS",
    "METHODS",
    "METHOD_KEYS",
    "RACE_TEST",
    "SCORE_COLUMNS",
    "UNLEARNED_START",
    "Kind",
    "Method",
    "UnknownMethodError",
    "method",
    "title",
]
