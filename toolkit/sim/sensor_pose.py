"""A sensor's pose at arbitrary times within a block of true state: the vehicle's pose
interpolated between dynamics samples, and a mount's flex under the body's specific force.
Shared by the 2-D lasers (:mod:`toolkit.sim.suite`) and the lidar (:mod:`toolkit.sim.lidar_scan`).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from toolkit.arrays import AnyFloatArray as FloatArray
from toolkit.sim.drive import GRAVITY_MPS2, TrueBlock


def pose_at(ext: TrueBlock, t_ext: FloatArray, t: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``world_from_base`` rotations (k, 3, 3) and positions (k, 3) at times ``t`` (k,), on
    the same axis (ns, float) as ``t_ext``, the block's sample times."""
    pos = np.stack([np.interp(t, t_ext, ext.position_m[:, j]) for j in range(3)], axis=1)
    ypr = np.stack(
        [np.interp(t, t_ext, a) for a in (ext.yaw_rad, ext.pitch_rad, ext.roll_rad)], axis=1
    )
    rot: FloatArray = Rotation.from_euler("ZYX", ypr).as_matrix()
    return rot, pos


def flex_pitch(ext: TrueBlock, t_ext: FloatArray, t: FloatArray, rad_per_mps2: float) -> FloatArray:
    """A mount's flex at times ``t`` (k,): rotations (k, 3, 3) about base_link's y by
    ``rad_per_mps2 * ((f_z - g) - f_x)`` (positive pitch is nose-down;
    :class:`~toolkit.sim.sensors.LaserParams` gives the model)."""
    f = ext.specific_force_body_mps2
    fx = np.interp(t, t_ext, f[:, 0])
    fz = np.interp(t, t_ext, f[:, 2])
    pitch = rad_per_mps2 * ((fz - GRAVITY_MPS2) - fx)
    c, s = np.cos(pitch), np.sin(pitch)
    out = np.zeros((t.size, 3, 3))
    out[:, 0, 0] = c
    out[:, 0, 2] = s
    out[:, 1, 1] = 1.0
    out[:, 2, 0] = -s
    out[:, 2, 2] = c
    return out
