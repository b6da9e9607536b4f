"""The report's section on learning while driving: what it says of a replay's summary."""

from __future__ import annotations

from typing import Any

from toolkit.analysis.online_page import online_section


def _entry(online_auc: float, start_auc: float) -> dict[str, Any]:
    rates = {"tpr_at_fpr": {"5%": 0.5, "10%": 0.66, "20%": 0.82}}
    return {
        "test": {
            "online": {"auc": online_auc, **rates},
            "offline": {"auc": 0.899, **rates},
            "start": {"auc": start_auc, **rates},
        },
        "update_every_m": 150.0,
        "frozen_after_m": 3000.0,
        "stretch_m": 2000.0,
        "drives": 4,
        "within_0_02_from_m": 30000.0,
        "label_latency_s": {"p50": 0.86, "p95": 1.19},
        "gaps": [],
        "first_update_m": {"0": 4650.0, "1": None},
        "speed_control": {"online": 0.56, "offline": 0.47},
    }


def test_the_section_says_whether_learning_while_driving_helped() -> None:
    helped = "\n".join(online_section({"online_learning": _entry(0.895, 0.750)}, None))
    assert "Learning while driving helped: the online scores&#x27; test AUC, 0.895" in helped
    assert "From 30.0 km driven on" in helped and "119 % of the offline model" in helped
    worse = "\n".join(online_section({"online_learning": _entry(0.887, 0.895)}, "f.png"))
    assert "Learning while driving did not help here" in worse and "-0.008" in worse
    assert "helped:" not in worse and "<img src='f.png'" in worse
    assert online_section({}, None) == []
    never = _entry(0.822, 0.831) | {"first_update_m": {"0": None}}
    said = "\n".join(online_section({"online_learning": never}, None))
    assert "The model never changed on any drive" in said and "did not help" not in said
