"""What each rotation of sect. 6's coordinate ascent does on the training and the test split.

Builds both splits' pair tables from a workspace's training tables (as ``terrain learn``
does), runs the search with the workspace's ``[learn]`` configuration, then replays its
accepted steps rotation by rotation and prints, after each, on train and test: the AUC, the
objective of eq. (6) at its best threshold (``TPR - lambda FPR``, lambda from the config)
and on test the TPR at FPR 1, 5, 10 and 20 %. Rotation 0 is the initial guess.

So one can tell whether the search overfits (test objective falling while train rises) or
trades the rest of the ROC for its low-FPR corner (test objective rising, AUC and TPR at the
larger FPRs falling).

Usage: python benchmarks/learn_rotations.py WORKSPACE [--rotations 10]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from sklearn.metrics import roc_auc_score, roc_curve

from toolkit.config import load_config
from toolkit.model.ascent import B_NAMES, coordinate_ascent
from toolkit.model.roughness import PairTable, RoughnessParams, score_events
from toolkit.model.search import ascent_config
from toolkit.stages import training_data
from toolkit.workspace import Workspace

FPRS = (0.01, 0.05, 0.10, 0.20)


def tpr_at(rough: NDArray[np.bool_], score: NDArray[np.float64], fpr_max: float) -> float:
    """The ROC's TPR at the largest FPR not above ``fpr_max`` (ties count as one step)."""
    fpr, tpr, _ = roc_curve(rough, score)
    return float(tpr[np.searchsorted(fpr, fpr_max, side="right") - 1])


def best_objective(rough: NDArray[np.bool_], score: NDArray[np.float64], lam: float) -> float:
    """Eq. (6) at its best threshold: max over the ROC of TPR - lambda FPR."""
    fpr, tpr, _ = roc_curve(rough, score)
    return float((tpr - lam * fpr).max())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("workspace", type=Path)
    ap.add_argument("--rotations", type=int, default=10, help="rotations to print")
    args = ap.parse_args()
    ws = Workspace(args.workspace)
    config = load_config(ws.config_path)
    lam = config.learn.lambda_fp
    t0 = time.perf_counter()
    splits: dict[str, tuple[PairTable, NDArray[np.bool_]]] = {}
    for split in ("train", "test"):
        events = training_data.split_events(ws, split)
        pairs = training_data.pair_table(
            training_data.patches_of(ws, events, config.model), config.model, ws.root
        )
        rough = np.asarray(events.column("rough").to_numpy(zero_copy_only=False), bool)
        splits[split] = (pairs, rough)
        print(f"{split}: {int(rough.sum())} rough of {rough.size} events")
    search = ascent_config(config.learn)
    result = coordinate_ascent(*splits["train"], search)
    print(f"pairs and search: {time.perf_counter() - t0:.1f} s")

    def report(label: str, b: list[float]) -> None:
        params = RoughnessParams.from_vector(b, 0.0)
        cells = []
        for split, (pairs, rough) in splits.items():
            score = score_events(pairs, params).r_combined
            cells.append(
                f"{split} AUC {roc_auc_score(rough, score):.3f} "
                f"J {best_objective(rough, score, lam):.3f}"
            )
        pairs, rough = splits["test"]
        score = score_events(pairs, params).r_combined
        tprs = " ".join(f"{tpr_at(rough, score, f):.2f}" for f in FPRS)
        print(f"{label}: {'; '.join(cells)}; test TPR at FPR 1/5/10/20 %: {tprs}")

    b = list(search.initial)
    report("rotation 0 (initial guess)", b)
    for rotation in range(min(args.rotations, search.iterations)):
        taken = [s for s in result.steps if s[0] == rotation]
        for _, name, value, _ in taken:
            b[B_NAMES.index(name)] = value
        report(f"rotation {rotation + 1} ({len(taken)} steps)", b)


if __name__ == "__main__":
    main()
