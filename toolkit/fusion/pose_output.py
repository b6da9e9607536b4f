"""The estimator's output: the posterior mean carried to every segment end as a base_link
pose, and the rows of the output grid interpolated from them.

Between epochs the mean of the last epoch's posterior ``x_k`` is carried forward by the IMU
increments integrated since (:class:`~toolkit.fusion.epoch_filter.Segments`; ``tau`` the time
since the epoch, ``R_k = R(rpy_k)``), the process model's mean without bias corrections::

    p = p_k + v_k tau + 1/2 g tau^2 + R_k dp        v = v_k + g tau + R_k dv
    R = R_k dR                                      rpy = euler(R)

so the output between filter steps uses nothing measured later; at an epoch the posterior
replaces the carried prior. base_link, from the IMU's state (``l_axle`` base_link's origin
from the IMU, ``w`` the bias-corrected gyro rate)::

    p_base = p + R l_axle        v_base = v + R (w x l_axle)

Rows are linear interpolations of these segment ends (yaw unwrapped, then wrapped again) at
the output times ``t_start + m / output_rate_hz`` not strictly inside an IMU gap
(:func:`~toolkit.fusion.epochs.grid_outside_gaps`).
"""

from __future__ import annotations

import numpy as np

from toolkit.arrays import FloatArray
from toolkit.fusion.epoch_filter import Segments
from toolkit.fusion.epochs import grid_outside_gaps
from toolkit.fusion.estimator_io import OutputChunk
from toolkit.fusion.state import ATT, GRAVITY, POS, VEL
from toolkit.geometry.rotations import euler_rates, euler_to_rot, rot_to_euler, wrap_angle

#: The pose columns of a segment end, in output order (``speed`` follows them in a row):
#: base_link position (m, world), roll-pitch-yaw (rad), velocity (m/s, world), Euler rates
#: (rad/s).
POSE_COLUMNS = (
    "x",
    "y",
    "z",
    "roll",
    "pitch",
    "yaw",
    "vx",
    "vy",
    "vz",
    "roll_rate",
    "pitch_rate",
    "yaw_rate",
)


def carried_pose(seg: Segments, lever_axle: FloatArray) -> dict[str, FloatArray]:
    """The base_link pose at every segment end (module docstring), columns
    :data:`POSE_COLUMNS` (n,) each."""
    # The mean carried from each epoch's posterior to every segment end (vectorised).
    ep_seg = np.flatnonzero(seg.is_epoch)
    base = seg.base
    rot_a = euler_to_rot(base[:, ATT])
    tau = seg.tau[:, None]
    pos = (
        base[:, POS]
        + base[:, VEL] * tau
        + 0.5 * GRAVITY * tau**2
        + np.einsum("nij,nj->ni", rot_a, seg.dp)
    )
    vel = base[:, VEL] + GRAVITY * tau + np.einsum("nij,nj->ni", rot_a, seg.dv)
    rot = rot_a @ seg.rot_inc
    att = rot_to_euler(rot)
    # At an epoch the posterior replaces the carried prior.
    pos[ep_seg] = seg.post[ep_seg][:, POS]
    vel[ep_seg] = seg.post[ep_seg][:, VEL]
    att[ep_seg] = seg.post[ep_seg][:, ATT]
    rot[ep_seg] = euler_to_rot(att[ep_seg])
    # base_link: the IMU position less the lever arm; velocity less w x lever.
    pos_b = pos + np.einsum("nij,j->ni", rot, lever_axle)
    vel_b = vel + np.einsum("nij,nj->ni", rot, np.cross(seg.w, lever_axle))
    rates = euler_rates(att, seg.w)
    return dict(zip(POSE_COLUMNS, (*pos_b.T, *att.T, *vel_b.T, *rates.T), strict=True))


class OutputGrid:
    """The output rows, window by window: :meth:`rows` of each window's segment ends, in
    time order. ``rows_in_gaps``: output times left out inside IMU gaps so far."""

    def __init__(
        self, t0_ns: int, t_start: float, step: float, n_out_total: int, gaps: FloatArray
    ) -> None:
        """Output times ``t_start + step m``, ``1 <= m <= n_out_total`` (s after ``t0_ns``),
        none strictly inside one of the ``gaps`` (K, 2) s."""
        self._t0_ns, self._t_start, self._step = t0_ns, t_start, step
        self._n_out_total, self._gaps = n_out_total, gaps
        self._prev_row: dict[str, float] | None = None  # last segment's values, to interpolate
        self._first_seg_t: float | None = None
        self._m_next = 1  # next output index (t_out = t_start + step * m)
        self.rows_in_gaps = 0

    def rows(self, t_seg: FloatArray, seg_cols: dict[str, FloatArray]) -> OutputChunk | None:
        """The rows at the output times up to the last of the segment ends ``t_seg`` (n,) s,
        interpolated from their pose ``seg_cols`` (:func:`carried_pose`) and the previous
        window's last; None when there is none."""
        prev_row = self._prev_row
        if prev_row is not None:
            t_seg = np.concatenate([[prev_row["t"]], t_seg])
            seg_cols = {k: np.concatenate([[prev_row[k]], v]) for k, v in seg_cols.items()}
        seg_cols["yaw"] = np.unwrap(seg_cols["yaw"])
        prev_row = {k: float(v[-1]) for k, v in seg_cols.items()}
        prev_row["t"] = float(t_seg[-1])
        self._prev_row = prev_row
        if self._first_seg_t is None:
            self._first_seg_t = float(t_seg[0])
        # Output times up to this window's last segment end.
        t_start, step = self._t_start, self._step
        m_hi = min(int(np.floor((t_seg[-1] - t_start) / step)), self._n_out_total)
        if m_hi < self._m_next:
            return None
        t_out, n_left_out = grid_outside_gaps(t_start, step, self._m_next, m_hi, self._gaps)
        self.rows_in_gaps += n_left_out
        self._m_next = m_hi + 1
        t_out = t_out[t_out >= self._first_seg_t]
        if t_out.size == 0:
            return None
        columns = {
            k: np.asarray(np.interp(t_out, t_seg, v), dtype=np.float64) for k, v in seg_cols.items()
        }
        columns["yaw"] = wrap_angle(columns["yaw"])
        columns["speed"] = np.hypot(columns["vx"], columns["vy"])
        return self._t0_ns + np.round(t_out * 1e9).astype(np.int64), columns


__all__ = ["POSE_COLUMNS", "OutputGrid", "carried_pose"]
