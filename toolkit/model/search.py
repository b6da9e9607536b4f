"""The search of sect. 6 as the configuration's ``[learn]`` sets it: the initial guess of
B, the increments, lambda of eq. (6), the rotations, which elements move and how steps are
accepted (:class:`toolkit.model.ascent.AscentConfig`).

Learn searches from it; evaluate's trained rows (the baselines, the ablations, the oracle)
search from it as well, some with elements held fixed.
"""

from __future__ import annotations

from toolkit.config import LearnConfig, OnlineLearnConfig
from toolkit.model.ascent import AscentConfig
from toolkit.model.online import OnlineConfig


def ascent_config(
    lc: LearnConfig,
    free: tuple[bool, ...] | None = None,
    fixed: dict[int, float] | None = None,
) -> AscentConfig:
    """The search of sect. 6 from ``[learn]``: B is the 13-vector (alpha_1..alpha_10,
    upsilon, omega, zeta), or with ``lead_term`` the 15-vector whose alpha_11, alpha_12 weigh
    the look-ahead (:mod:`toolkit.model.roughness`); ``free`` (one flag per element, for the
    13 or 15 elements) says which elements move, ``fixed`` overrides initial values by index
    (an ablation's zeroed terms)."""
    alpha = [*lc.initial_alpha, *(lc.initial_lead if lc.lead_term else ())]
    steps = [*lc.increment_alpha, *(lc.increment_lead if lc.lead_term else ())]
    initial = [*alpha, lc.initial_upsilon, float(lc.initial_omega), lc.initial_zeta]
    for j, v in (fixed or {}).items():
        initial[j] = v
    increments = (*steps, lc.increment_upsilon, lc.increment_omega, lc.increment_zeta)
    return AscentConfig(
        initial=tuple(float(v) for v in initial),
        increments=tuple(float(v) for v in increments),
        lambda_fp=lc.lambda_fp,
        iterations=lc.iterations,
        free=free if free is not None else (),
        accept=lc.accept,
        validation_share=lc.validation_share,
        step_rule=lc.step_rule,
    )


def online_config(oc: OnlineLearnConfig, lc: LearnConfig) -> OnlineConfig:
    """The online learner of ``[online]``, with ``[learn]``'s lambda for eq. (6)'s mu."""
    return OnlineConfig(
        update_every_m=oc.update_every_m,
        buffer_rough=oc.buffer_rough,
        buffer_smooth=oc.buffer_smooth,
        coordinates_per_update=oc.coordinates_per_update,
        min_rough=oc.min_rough,
        step_rule=oc.step_rule,
        average=oc.average,
        validation_share=oc.validation_share,
        lambda_fp=lc.lambda_fp,
        refit_every_m=oc.refit_every_m,
        refit_iterations=oc.refit_iterations,
        refit_budget_s=oc.refit_budget_s,
        refit_smooth=oc.refit_smooth,
        accept_margin=oc.accept_margin,
        reference_smooth=oc.reference_smooth,
    )


__all__ = ["ascent_config", "online_config"]
