"""The methods evaluate compares (:mod:`toolkit.analysis.methods`), on crafted patches; the
rows of a whole run are checked on the sample log in ``tests/stages/test_evaluate.py``."""

from __future__ import annotations

import dataclasses

import numpy as np

from tests.model.helpers import make_patches, random_patches
from toolkit.analysis.methods import Trainer, baseline, paper_exact
from toolkit.config import default_config
from toolkit.model.baseline import BaselineParams
from toolkit.model.roughness import PairTable


def test_the_paper_exact_row_and_the_race_test_ignore_the_extensions() -> None:
    """The paper's method as written has no look-ahead term, no early stopping and halved
    increments whatever the configuration; the race test trains its 13-vector with the
    look-ahead term on."""
    cfg = default_config()
    extended = dataclasses.replace(
        cfg, learn=dataclasses.replace(cfg.learn, lead_term=True, validation_share=0.3)
    )
    model, learn = paper_exact(extended.model, extended.learn)
    assert model.point_sample == "hash" and learn.accept == "objective"
    assert not learn.lead_term and learn.validation_share == 0.0
    assert extended.learn.step_rule == "adapt" and learn.step_rule == "halve"
    rng = np.random.default_rng(0)
    patches = make_patches(random_patches(rng, 40, 8))
    rough = np.arange(40) % 4 == 0
    train = np.arange(40) < 20
    trainer = Trainer(train, rough, extended.learn, PairTable)
    got = baseline(trainer, patches, BaselineParams())
    assert got.trained is not None and len(got.params.alpha) == 10
