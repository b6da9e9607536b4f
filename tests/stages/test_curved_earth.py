"""A log's points are as right far from its world origin as near it (issue "Truth far from
home", point 1): the cloud posed and projected with the origin 30 or 100 km away, taken
into the cloud of its own origin, agrees at 20-30 m range within 2 cm (p95). On the tangent
plane of before it was 9 and 30 cm."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from toolkit.analysis.cloud_frames import frame_agreement, read_cloud
from toolkit.config import default_config
from toolkit.geometry.geodesy import GeodeticOrigin
from toolkit.stages import pose_inputs
from toolkit.stages.pose import SPEC as POSE
from toolkit.stages.project import SPEC as PROJECT
from toolkit.stages.runner import run_stage
from toolkit.workspace import Workspace

EARTH_RADIUS_M = 6_371_000.0


def _west(origin: GeodeticOrigin, km: float) -> GeodeticOrigin:
    import numpy as np

    dlon = np.degrees(km * 1e3 / (EARTH_RADIUS_M * np.cos(np.radians(origin.latitude_deg))))
    return GeodeticOrigin(
        origin.latitude_deg, origin.longitude_deg - float(dlon), origin.altitude_m
    )


@pytest.mark.slow  # poses and projects the sample twice more: run by .ci/run
@pytest.mark.parametrize("km", [30.0, 100.0])
def test_the_cloud_far_from_its_origin_is_the_cloud_near_it(
    sample_projected: tuple[Path, str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, km: float
) -> None:
    root, log_id = sample_projected
    near = read_cloud(Workspace(root).log_dir(log_id) / "points.parquet")
    ws = Workspace(shutil.copytree(root, tmp_path / "far", symlinks=True))
    real = pose_inputs.choose_enu_origin

    def far(*args: object, **kwargs: object) -> object:
        chosen = real(*args, **kwargs)  # type: ignore[arg-type]
        return None if chosen is None else (_west(chosen[0], km), chosen[1])

    monkeypatch.setattr(pose_inputs, "choose_enu_origin", far)
    run_stage(POSE, ws, default_config(), log_id=log_id, overwrite=True)
    run_stage(PROJECT, ws, default_config(), log_id=log_id, overwrite=True)
    moved = read_cloud(ws.log_dir(log_id) / "points.parquet")
    assert moved.origin != near.origin
    agreement = frame_agreement(near, moved, 20.0, 30.0)
    assert agreement.returns > 100_000
    assert agreement.dz_p95_m <= 0.02, agreement
    assert agreement.dxy_p95_m <= 0.02, agreement
