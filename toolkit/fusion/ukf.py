"""An IMU-driven unscented Kalman filter for the vehicle pose (paper sect. 3), on filterpy.

The state vector and its angle-aware means are :mod:`toolkit.fusion.state`'s, the process
model (IMU pre-integration, process noise) :mod:`toolkit.fusion.process`'s and the
measurement models :mod:`toolkit.fusion.measurements`'.

Every measurement is gated: the squared Mahalanobis distance of its innovation,
``y^T S^-1 y``, above the sensor's threshold rejects it; rejections are counted per sensor.
A measurement marked ``robust`` is instead down-weighted beyond its gate: its noise is
inflated until the distance equals the gate, and it is used (counted as accepted and as
down-weighted; :meth:`PoseUKF.update_joint` gives the maths and the reason).

An update may be conditioned on some states (``PoseUKF.update_joint(..., given=c)``): they
are held at their mean for the update, which then moves neither them nor their marginal
covariance and keeps the regression of the other states on them. Dead reckoning uses it for
the directions its body-frame measurements cannot see
(:data:`~toolkit.fusion.state.DEAD_RECKONING_GIVEN`; the reasons are in
``PoseUKF._conditioned``).

The filter (:class:`PoseUKF`, whose docstring states the sigma points, the predict and the
update) holds filterpy's :class:`~filterpy.kalman.MerweScaledSigmaPoints` (with
:func:`~toolkit.fusion.state.state_residual`, so sigma points wrap their angles) and uses
only its public ``sigma_points``, ``Wm`` and ``Wc``; the process model, the unscented
transform and the gated update run on all sigma points at once, where filterpy would loop
over them.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping
from types import MappingProxyType

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints

from toolkit.arrays import FloatArray
from toolkit.errors import StageError
from toolkit.fusion.measurements import MeasFn, Measurement
from toolkit.fusion.process import ImuIncrement, NoiseModel, propagate
from toolkit.fusion.state import (
    ATT,
    DIM_X,
    MOTION,
    POS,
    VEL,
    plain_mean,
    plain_residual,
    state_mean,
    state_residual,
    unscented_transform,
)
from toolkit.geometry.rotations import wrap_angle


class PoseUKF:
    """The pose filter: an unscented Kalman filter over the 16-state model
    (:mod:`toolkit.fusion.state`).

    It holds filterpy's scaled sigma points and the state privately; every public method is
    ours. ``n = 16`` is the state dimension, ``x`` (n,) the mean, ``P`` (n, n) the covariance.

    Sigma points (Van der Merwe's scaled set, filterpy's ``MerweScaledSigmaPoints``), 2n + 1
    of them, with ``lambda = alpha^2 (n + kappa) - n`` and ``U`` the upper Cholesky factor of
    ``(n + lambda) P`` (``U^T U = (n + lambda) P``, ``U_i`` its row i)::

        X_0 = x,    X_i = x + U_i,    X_(n+i) = x - U_i          (i = 1..n, angles wrapped)
        Wm_0 = lambda / (n + lambda),    Wc_0 = Wm_0 + 1 - alpha^2 + beta
        Wm_i = Wc_i = 1 / (2 (n + lambda))                        (i = 1..2n)

    Predict over one IMU increment (:meth:`predict`; ``f`` is :func:`propagate`, ``Q`` is
    :meth:`NoiseModel.q` for the increment's duration ``T``)::

        Y_i = f(X_i)
        x- = sum_i Wm_i Y_i                                       (angles: wrapped mean)
        P- = sum_i Wc_i (Y_i - x-)(Y_i - x-)^T + Q

    Gated update with a measurement function ``h`` and noise covariance ``R`` (k, k)
    (:meth:`update`; the sigma points are drawn afresh from the current ``x, P``)::

        Z_i = h(X_i),    z^ = sum_i Wm_i Z_i
        S = sum_i Wc_i (Z_i - z^)(Z_i - z^)^T + R                 (k, k)
        y = z - z^,      d2 = y^T S^-1 y                          (rejected if d2 > gate)
        Pxz = sum_i Wc_i (X_i - x)(Z_i - z^)^T                    (n, k)
        K = Pxz S^-1,    x+ = x + K y,    P+ = P - K S K^T        (P+ symmetrised)

    For a measurement linear in the state, ``h(x) = H x``, this is exactly the Kalman update
    (``S = H P H^T + R``, ``K = P H^T S^-1``): the sigma points carry ``x`` and ``P`` exactly.

    After an interval nobody observed (a long IMU gap), :meth:`restart` raises the
    position, velocity and attitude block of ``P`` to at least its initial value.

    Read-only: :attr:`x`, :attr:`P`, :attr:`gated` (rejected measurements per sensor name),
    :attr:`accepted` (used ones), :attr:`down_weighted` (used ones beyond their gate, robust
    blocks of :meth:`update_joint`), :attr:`last_d2` (``d2`` of the last measurement tried).
    """

    def __init__(
        self,
        x0: FloatArray,
        P0: FloatArray,
        noise: NoiseModel,
        *,
        alpha: float,
        beta: float,
        kappa: float,
    ) -> None:
        """Start from the mean ``x0`` (16,) and covariance ``P0`` (16, 16).

        ``alpha``, ``beta``, ``kappa``: the sigma-point parameters (see the class docstring).
        """
        self._x = _checked(x0, (DIM_X,), "x0")
        self._P = _checked(P0, (DIM_X, DIM_X), "P0")
        self._noise = noise
        # filterpy forms X_i = x +- U_i with its default subtract (one call per sigma point);
        # _sigma_points wraps the angles of all of them at once afterwards, the same numbers
        # as passing state_residual as `subtract`, without 2n Python calls per draw.
        self._points = MerweScaledSigmaPoints(DIM_X, alpha=alpha, beta=beta, kappa=kappa)
        self._wm: FloatArray = np.asarray(self._points.Wm, dtype=np.float64)
        self._wc: FloatArray = np.asarray(self._points.Wc, dtype=np.float64)
        self._gated: Counter[str] = Counter()
        self._accepted: Counter[str] = Counter()
        self._down_weighted: Counter[str] = Counter()
        self._last_d2 = 0.0

    # -- read-only views ----------------------------------------------------------------

    @property
    def x(self) -> FloatArray:
        """The state mean (16,), a read-only view."""
        return _read_only(self._x)

    @property
    def P(self) -> FloatArray:  # noqa: N802 (P, the covariance's textbook name)
        """The state covariance (16, 16), a read-only view."""
        return _read_only(self._P)

    @property
    def noise(self) -> NoiseModel:
        """The process noise model."""
        return self._noise

    @property
    def gated(self) -> Mapping[str, int]:
        """Measurements rejected by their gate, per sensor name (0 for a name never seen)."""
        return MappingProxyType(self._gated)

    @property
    def accepted(self) -> Mapping[str, int]:
        """Measurements used, per sensor name (0 for a name never seen)."""
        return MappingProxyType(self._accepted)

    @property
    def down_weighted(self) -> Mapping[str, int]:
        """Robust measurements used beyond their gate with inflated noise, per sensor name
        (also counted in :attr:`accepted`; 0 for a name never seen)."""
        return MappingProxyType(self._down_weighted)

    @property
    def last_d2(self) -> float:
        """Squared Mahalanobis distance ``y^T S^-1 y`` of the last measurement tried."""
        return self._last_d2

    # -- the filter -----------------------------------------------------------------------

    def predict(self, inc: ImuIncrement, q_extra: FloatArray | None = None) -> None:
        """Predict over one pre-integrated IMU increment (see the class docstring).

        ``q_extra`` (16, 16), symmetric positive semidefinite: process noise added to
        :meth:`NoiseModel.q` for this step (the estimator's measured accelerometer noise in
        odometry dead reckoning, :func:`toolkit.fusion.accel_noise.vibration_q`).
        """
        moved = propagate(self._sigma_points(), inc)
        q = self._noise.q(inc.T)
        if q_extra is not None:
            q = q + _checked(q_extra, (DIM_X, DIM_X), "q_extra")
        self._x, self._P = unscented_transform(
            moved, self._wm, self._wc, q, state_mean, state_residual
        )

    def update(
        self,
        name: str,
        z: FloatArray,
        R: FloatArray,
        hx: MeasFn,
        gate_chi2: float,
        *,
        mean_fn: Callable[[FloatArray, FloatArray], FloatArray] = plain_mean,
        residual_fn: Callable[[FloatArray, FloatArray], FloatArray] = plain_residual,
    ) -> bool:
        """Update with the measurement ``z`` (k,) of noise covariance ``R`` (k, k).

        ``hx`` maps sigma points (M, 16) to predicted measurements (M, k); ``mean_fn`` and
        ``residual_fn`` average and subtract measurements (the angle versions for angles).
        Returns False, leaving the state alone and counting the rejection under ``name``,
        when the squared Mahalanobis distance of the innovation exceeds ``gate_chi2``.
        """
        sigmas = self._sigma_points()
        zs = hx(sigmas)
        zp, S = unscented_transform(zs, self._wm, self._wc, R, mean_fn, residual_fn)
        y = residual_fn(np.asarray(z, dtype=np.float64), zp)
        S_inv = np.linalg.inv(S)
        d2 = float(y @ S_inv @ y)
        self._last_d2 = d2
        if not np.isfinite(d2) or d2 > gate_chi2:
            self._gated[name] += 1
            return False
        dx = state_residual(sigmas, self._x)
        dz = residual_fn(zs, zp)
        Pxz = (dx.T * self._wc) @ dz
        K = Pxz @ S_inv
        x = self._x + K @ y
        x[ATT] = wrap_angle(x[ATT])
        P = self._P - K @ S @ K.T
        self._x = x
        # K S K^T is symmetric only up to round-off; keep P exactly symmetric.
        self._P = 0.5 * (P + P.T)
        self._accepted[name] += 1
        return True

    def update_joint(self, blocks: list[Measurement], *, given: tuple[int, ...] = ()) -> list[bool]:
        """Update with several measurements taken at the same time, from one sigma-point draw.

        Each block ``b`` (a :class:`Measurement`) has ``z_b`` (k_b,), ``R_b``, ``h_b`` and a
        gate. The blocks are stacked into one measurement, ``Z_i = (h_1(X_i), ..., h_B(X_i))``
        with ``R = blockdiag(R_b)``, and its unscented transform is taken once (``z^``,
        ``S``, ``Pxz`` as in :meth:`update`; angle blocks averaged and subtracted wrapped).
        Each block is gated on its own marginal innovation, ``d2_b = y_b^T S_bb^-1 y_b``
        (``S_bb`` the block's diagonal block of ``S``), exactly what :meth:`update` would
        compute for it alone. The accepted blocks ``a`` then update together::

            K = Pxz[:, a] S[a, a]^-1,    x+ = x + K y_a,    P+ = P - K S[a, a] K^T

        For measurements linear in the state this equals the sequential updates; it draws
        sigma points once instead of once per sensor. Returns the accepted flag per block.

        A ``robust`` block beyond its gate (``d2_b > g``, finite) is not rejected but
        down-weighted: its noise is inflated so that its innovation's squared Mahalanobis
        distance equals the gate, and it is then used like an accepted block::

            lam = d2_b / g,    R_b' = R_b + (lam - 1) S_bb,    so S_bb' = lam S_bb
            and y_b^T S_bb'^-1 y_b = d2_b / lam = g

        (the cross-blocks of ``S`` do not contain ``R`` and are unchanged; ``S`` stays
        positive definite, a PSD matrix having been added). It is counted as accepted and as
        down-weighted. This is the Mahalanobis-distance covariance inflation of Chang (2014,
        J. Geodesy 88(4), doi:10.1007/s00190-013-0690-8, its analytical scaling of the
        innovation covariance): inside the gate the ordinary update, beyond it a correction
        that shrinks as the reading goes further out (its gain scales by ``1 / lam``, so the
        correction, in standard deviations, by ``g / sqrt(d2_b)``: a redescending weight,
        bounded by the correction at the gate; Huber's (1964, Ann. Math. Stat. 35(1))
        weight would keep it constant beyond the gate, ``lam = sqrt(d2_b / g)``). Why: for a
        sensor that is the only reference of what it measures (the wheels in odometry dead
        reckoning), dropping its outlying readings leaves that state to the process model
        alone, which is worse than a reading with a heavier tail.

        ``given``: state indices ``c`` the update is conditioned on (none by default); see
        :meth:`_conditioned`, which says how and why.
        """
        if not blocks:
            return []
        if given:
            return self._conditioned(blocks, np.asarray(given, dtype=np.intp))
        sigmas = self._sigma_points()
        dz, y, starts = _stacked_innovations(blocks, sigmas, self._wm)
        S = (dz.T * self._wc) @ dz
        keep, flags = self._gate_blocks(blocks, S, y, starts)
        if not keep:
            return flags
        idx = np.asarray(keep)
        S_a = S[np.ix_(idx, idx)]
        dx = state_residual(sigmas, self._x)
        Pxz = (dx.T * self._wc) @ dz[:, idx]
        K = np.linalg.solve(S_a, Pxz.T).T  # Pxz S^-1, S symmetric
        x = self._x + K @ y[idx]
        x[ATT] = wrap_angle(x[ATT])
        P = self._P - K @ S_a @ K.T
        self._x = x
        self._P = 0.5 * (P + P.T)
        return flags

    def _gate_blocks(
        self, blocks: list[Measurement], S: FloatArray, y: FloatArray, starts: np.ndarray
    ) -> tuple[list[int], list[bool]]:
        """Gate each block of :meth:`update_joint` on its marginal innovation, ``d2_b = y_b^T
        S_bb^-1 y_b``, after adding its ``R_b`` to ``S`` (in place; a robust block beyond its
        gate also inflates ``S_bb`` in place, see :meth:`update_joint`), and count it. Returns
        the rows of ``y`` kept and the accepted flag per block."""
        keep: list[int] = []
        flags: list[bool] = []
        for i, b in enumerate(blocks):
            sl = slice(int(starts[i]), int(starts[i + 1]))
            S[sl, sl] += b.R
            yb = y[sl]
            d2 = float(yb @ np.linalg.solve(S[sl, sl], yb))
            self._last_d2 = d2
            ok = bool(np.isfinite(d2) and d2 <= b.gate_chi2)
            if not ok and b.robust and np.isfinite(d2):
                # Beyond the gate but robust: R_b' = R_b + (lam - 1) S_bb (docstring).
                S[sl, sl] *= d2 / b.gate_chi2
                self._down_weighted[b.name] += 1
                ok = True
            flags.append(ok)
            if ok:
                keep.extend(range(sl.start, sl.stop))
                self._accepted[b.name] += 1
            else:
                self._gated[b.name] += 1
        return keep, flags

    def _conditioned(self, blocks: list[Measurement], c: np.ndarray) -> list[bool]:
        """:meth:`update_joint` conditioned on the states ``c``; ``r`` are the others.

        The prior is split into the marginal of ``x_c`` and the regression of ``x_r`` on it::

            A = P_rc P_cc^-1,        P_r|c = P_rr - A P_cr      (x_r = x^_r + A (x_c - x^_c) + e)

        The measurements update ``e`` alone, from sigma points drawn with ``x_c`` held at its
        mean (the update's ``x^_r -> x^_r+``, ``P_r|c -> P_r|c+``); then the joint is put back
        with the marginal of ``x_c`` and the regression ``A`` unchanged::

            x^_c+ = x^_c,   P_cc+ = P_cc,   P_rc+ = A P_cc,   P_rr+ = P_r|c+ + A P_cc A^T

        ``P+`` is positive definite when ``P`` is (its Schur complement in ``P_cc`` is
        ``P_r|c+``). No measurement moves ``x_c`` or shrinks its variance, and unlike a
        Schmidt ("consider") update, whose innovation covariance includes ``H_c P_cc H_c^T``,
        the spread of ``x_c`` does not loosen the measurements' hold on ``x_r``.

        Why: this is gauge fixing for the directions the measurements cannot see. Used in
        dead reckoning (:mod:`toolkit.fusion.estimator`, ``c`` = position, yaw, z gyro bias,
        wheel scale): wheel speed, the non-holonomic constraint and the IMU's roll and pitch
        are all body-frame quantities, invariant when the whole solution is translated or
        turned about gravity (``p -> Rz p + t``, ``v -> Rz v``, ``yaw -> yaw + a``; gravity
        is vertical, so the process model is invariant too). Those four directions are
        unobservable (the odometer/NHC-aided INS; e.g. Dissanayake et al. 2001, IEEE T-RA
        17(5); Shin 2001, UCGE 20156), and a filter that updates them anyway gains spurious
        information about them (Huang, Mourikis, Roumeliotis 2010, IJRR 29(5); Hesch et al.
        2014, IEEE T-RO 30(1)): here, through the position-velocity and yaw-velocity
        cross-covariances every wheel/NHC innovation moved the position and turned the yaw.
        Conditioning on them makes a velocity innovation correct the velocity in the frame of
        the current heading, and the position stay the integral of the velocity. The z gyro
        bias and the wheel scale are observable in dead reckoning only through the
        accelerometer (centripetal ``v w_z`` against the gyro; integrated specific force
        against the odometer), where a lateral accelerometer bias ``b`` is a yaw-rate error
        ``b / v`` (0.05 m/s^2 is 3 deg/s at 1 m/s) and vibration, slip and tilt errors are
        as large as the signal, so the filter would fit them to those errors instead; they
        keep their prior (or what GPS taught them) with an honest, growing covariance.
        """
        r = np.setdiff1d(np.arange(DIM_X), c)
        P = self._P
        P_cc = P[np.ix_(c, c)]
        A = np.linalg.solve(P_cc, P[np.ix_(c, r)]).T  # P_rc P_cc^-1, (|r|, |c|)
        P_cond = np.zeros_like(P)
        P_cond[np.ix_(r, r)] = P[np.ix_(r, r)] - A @ P[np.ix_(c, r)]
        # x_c held at its mean: a negligible spread keeps the sigma points' Cholesky defined.
        P_cond[np.ix_(c, c)] = np.eye(c.size) * 1e-14
        x_c = self._x[c].copy()
        self._P = 0.5 * (P_cond + P_cond.T)
        try:
            flags = self.update_joint(blocks)
        finally:
            x = self._x.copy()
            x[c] = x_c
            self._x = x
            out = self._P.copy()
            out[np.ix_(r, r)] += A @ P_cc @ A.T
            out[np.ix_(r, c)] = A @ P_cc
            out[np.ix_(c, r)] = (A @ P_cc).T
            out[np.ix_(c, c)] = P_cc
            self._P = 0.5 * (out + out.T)
        return flags

    def reset_motion(self, x_motion: FloatArray, P0: FloatArray) -> None:
        """Re-initialise position and velocity: ``x[POS, VEL] = x_motion`` (6,), and their
        rows and columns of ``P`` replaced by ``P0``'s (cross-covariances with everything
        else zeroed, so ``P`` stays positive definite). Attitude, biases and wheel scale
        keep their estimate and covariance: a filter locked out by its GPS gate has lost its
        position, not the IMU's calibration."""
        pv = slice(POS.start, VEL.stop)
        x = self._x.copy()
        x[pv] = _checked(x_motion, (6,), "x_motion")
        P0c = _checked(P0, (DIM_X, DIM_X), "P0")
        P = self._P.copy()
        P[pv, :] = 0.0
        P[:, pv] = 0.0
        P[pv, pv] = P0c[pv, pv]
        self._x = x
        self._P = 0.5 * (P + P.T)

    def restart(self, P0: FloatArray) -> None:
        """Forget the motion after an interval nobody observed (a long IMU gap).

        ``P0`` (16, 16) is the initial covariance; only its motion block ``F = P0[MOTION,
        MOTION]`` (9, 9: position, velocity, attitude; positive definite) is used. With
        ``A = P[MOTION, MOTION]`` and ``F = L L^T`` (Cholesky), the motion block is raised to
        at least ``F`` in the matrix order by flooring the eigenvalues of ``A`` measured in
        units of ``F``::

            M = L^-1 A L^-T = V diag(lam) V^T            (eigen-decomposition, M symmetric)
            A' = L V diag(max(lam, 1)) V^T L^T

        and ``P[MOTION, MOTION] = A'``; the bias block and the motion-bias cross-covariances
        are kept. The mean is left as it is.

        Why this rule: the gap is crossed at constant velocity and attitude, so afterwards
        position, velocity and attitude are at least as uncertain as at the start (``A' - F``
        is positive semidefinite), while the biases, which a gap of a second or two does not
        change, keep what was learnt about them (their walk over the gap is already in the
        predict's ``Q``). ``A' - A`` is positive semidefinite, so ``P' = P + [[A' - A, 0],
        [0, 0]]`` stays symmetric positive definite, and directions already more uncertain
        than ``F`` keep their covariance, cross-correlations included. The rule is
        idempotent (a second restart changes nothing), which matters because the estimator
        restarts at every epoch inside a gap. The element-wise ``max(P, P0)`` this replaces
        is not a covariance operation: it zeroes negative cross-covariances one entry at a
        time, which can leave ``P`` indefinite and make the next Cholesky fail.
        """
        F = _checked(P0, (DIM_X, DIM_X), "P0")[MOTION, MOTION]
        try:
            L = np.linalg.cholesky(F)
        except np.linalg.LinAlgError as exc:
            raise ValueError("the motion block of P0 must be positive definite") from exc
        L_inv = np.linalg.inv(L)
        A = self._P[MOTION, MOTION]
        M = L_inv @ A @ L_inv.T
        lam, V = np.linalg.eigh(0.5 * (M + M.T))
        A_floored = L @ ((V * np.maximum(lam, 1.0)) @ V.T) @ L.T
        P = self._P.copy()
        P[MOTION, MOTION] = A_floored
        self._P = 0.5 * (P + P.T)

    def _sigma_points(self) -> FloatArray:
        """The 2n + 1 sigma points (33, 16) of the current ``x, P``."""
        try:
            sigmas = np.asarray(self._points.sigma_points(self._x, self._P), dtype=np.float64)
            sigmas[:, ATT] = wrap_angle(sigmas[:, ATT])
            return sigmas
        except np.linalg.LinAlgError as exc:
            raise StageError(
                f"pose filter diverged: its state covariance is no longer positive definite ({exc})"
            ) from exc


def _stacked_innovations(
    blocks: list[Measurement], sigmas: FloatArray, wm: FloatArray
) -> tuple[FloatArray, FloatArray, np.ndarray]:
    """The blocks' predicted measurements stacked, ``Z_i = (h_1(X_i), ..., h_B(X_i))``:
    their residuals from their means ``dz`` (M, k), the innovation ``y = z - z^`` (k,) and
    the row where each block starts (B + 1,), each block averaged and subtracted by its own
    ``mean_fn`` and ``residual_fn`` (wrapped for angles)."""
    y_parts: list[FloatArray] = []
    dz_parts: list[FloatArray] = []
    for b in blocks:
        zs = b.hx(sigmas)
        zp = b.mean_fn(zs, wm)
        y_parts.append(b.residual_fn(np.asarray(b.z, dtype=np.float64), zp))
        dz_parts.append(b.residual_fn(zs, zp))
    sizes = [p.shape[1] for p in dz_parts]
    starts = np.concatenate([[0], np.cumsum(sizes)])
    return np.concatenate(dz_parts, axis=1), np.concatenate(y_parts), starts


def _checked(a: FloatArray, shape: tuple[int, ...], name: str) -> FloatArray:
    """A float64 copy of ``a``; a wrong shape or a non-finite value is a programming error."""
    out = np.array(a, dtype=np.float64)
    if out.shape != shape or not np.all(np.isfinite(out)):
        raise ValueError(f"{name} must be a finite array of shape {shape}, got {out.shape}")
    return out


def _read_only(a: FloatArray) -> FloatArray:
    view = a.view()
    view.flags.writeable = False
    return view


__all__ = ["PoseUKF"]
