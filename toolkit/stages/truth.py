"""The simulator's truth, moved into the frame the pose is written in.

The simulator writes its true pose (``/truth/odom``) in its own world frame: local ENU at the
origin in its ``terrain_sim`` metadata record. The contract wants ``truth_pose.parquet`` in
the pose's frame, local ENU at the log's agreeing GPS fix (:mod:`toolkit.geometry.frames`), so the
two tables compare row for row. Both are world frames of :mod:`toolkit.geometry.map_frame`
(level at every point), so positions move exactly through geodetic coordinates and the yaw
by the two maps' difference in convergence there
(:func:`~toolkit.geometry.map_frame.move_between_frames`); roll and pitch are the same in
both. Velocities are kept: they turn by that same angle, 5e-6 rad for origins 30 m apart.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from toolkit.geometry.frames import ENU_FRAME_ID, choose_enu_origin
from toolkit.geometry.geodesy import GeodeticOrigin
from toolkit.geometry.map_frame import move_between_frames
from toolkit.tableio import TableWriter


def origin_json(origin: GeodeticOrigin) -> str:
    """The ``enu_origin`` metadata value of tables in a local ENU frame."""
    return json.dumps(
        {
            "latitude_deg": origin.latitude_deg,
            "longitude_deg": origin.longitude_deg,
            "altitude_m": origin.altitude_m,
        }
    )


def truth_to_pose_frame(
    truth: TableWriter, gps_file: Path, sim: GeodeticOrigin
) -> TableWriter | str:
    """The finished truth table (sim frame) rewritten in the pose's frame, a row group at a
    time; or a warning (``truth`` left as it is) when the log has no GPS fix to define the
    frame. ``gps_file`` is the log's GPS table."""
    chosen = choose_enu_origin(pq.read_table(gps_file))
    if chosen is None:
        return "truth_pose left in the simulator's frame: the log has no GPS fix"
    origin = chosen[0]

    def move(piece: pa.Table, first_row: int) -> pa.Table:
        xyz_sim = np.stack([piece.column(c).to_numpy(zero_copy_only=False) for c in "xyz"], 1)
        yaw_sim = piece.column("yaw").to_numpy(zero_copy_only=False)
        xyz, yaw = move_between_frames(xyz_sim, yaw_sim, sim, origin)
        assert yaw is not None
        moved = {**{c: xyz[:, k] for k, c in enumerate("xyz")}, "yaw": yaw}
        for c, values in moved.items():
            piece = piece.set_column(
                piece.schema.get_field_index(c), c, pa.array(values, pa.float64())
            )
        return piece

    return truth.rewrite(move, {"enu_origin": origin_json(origin), "frame_id": ENU_FRAME_ID})


__all__ = ["origin_json", "truth_to_pose_frame"]
