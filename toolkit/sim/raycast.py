"""Laser ray casting: where each beam meets the terrain, and the range its footprint's echo
gives (the search and the footprint's maths are in :class:`RayCaster`'s docstring)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from toolkit.arrays import AnyFloatArray as FloatArray
from toolkit.sim.route import Route
from toolkit.sim.terrain import TerrainWindow


@dataclass(frozen=True)
class _RayPaths:
    """The rays being cast and where they run over the route.

    ``o``, ``u`` (n, 3): origins and unit directions in ENU. Along ray ``i`` at parameter
    ``t`` (its range, m), with ``tau = t - t_expansion_m[i]``, the route coordinates are
    ``s = s_m + tau (s1 + tau s2)`` and ``d = d_m + tau (b1 + tau d2)``: the second-order
    expansion about ``t_expansion_m`` of :meth:`RayCaster._expand`."""

    window: TerrainWindow
    o: FloatArray
    u: FloatArray
    t_expansion_m: FloatArray
    s_m: FloatArray
    d_m: FloatArray
    s1: FloatArray
    s2: FloatArray
    b1: FloatArray
    d2: FloatArray

    def route_coords(self, rows: NDArray[np.intp], tt: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Route coordinates ``(s, d)`` (m) of the rays ``rows`` (n,) at ray parameters
        ``tt``, (n,) or (n, k); the results have ``tt``'s shape."""
        col: tuple[slice | None, ...] = (slice(None), None) if tt.ndim == 2 else (slice(None),)
        tau = tt - self.t_expansion_m[rows][col]
        s = self.s_m[rows][col] + tau * (self.s1[rows][col] + tau * self.s2[rows][col])
        d = self.d_m[rows][col] + tau * (self.b1[rows][col] + tau * self.d2[rows][col])
        return s, d

    def gap(self, rows: NDArray[np.intp], tt: FloatArray) -> FloatArray:
        """``g(t) = o_z + t u_z - h(s(t), d(t))`` (m, > 0 above the ground) of the rays
        ``rows`` (n,) at ray parameters ``tt`` (n,)."""
        s, d = self.route_coords(rows, tt)
        gap: FloatArray = self.o[rows, 2] + tt * self.u[rows, 2] - self.window.height(s, d)
        return gap

    def ground_along(self, rows: NDArray[np.intp], tt: FloatArray) -> FloatArray:
        """Ground height (m) under the rays ``rows`` (n,) at ray parameters ``tt`` (n, k)."""
        s, d = self.route_coords(rows, tt)
        heights: FloatArray = self.window.height(s.ravel(), d.ravel()).reshape(tt.shape)
        return heights


@dataclass(frozen=True)
class _CentralHits:
    """The central rays' first crossings, which the footprint steps start from: ``rows``
    (n,) the rays' indices in ``paths``, ``t_c`` (n,) their ray parameters (m), ``o``, ``u``
    (n, 3) their origins and unit directions, ``slope`` (n,) the smooth ground's rise per
    metre of horizontal distance along them."""

    paths: _RayPaths
    rows: NDArray[np.intp]
    t_c: FloatArray
    o: FloatArray
    u: FloatArray
    slope: FloatArray

    def take(self, sel: NDArray[np.intp]) -> _CentralHits:
        """The hits ``sel`` of these."""
        return _CentralHits(
            self.paths, self.rows[sel], self.t_c[sel], self.o[sel], self.u[sel], self.slope[sel]
        )


@dataclass(frozen=True)
class RayCaster:
    """Finds where laser rays meet the terrain.

    For each ray ``p(t) = o + t u`` (``u`` unit, ``t`` the range), the ground is met where
    ``g(t) = o_z + t u_z - h(s(t), d(t))`` first turns negative. The search:

    1. estimate ``t_s`` against the smooth ground: the route elevation ``z0(s)`` and the
       cross profile;
    2. march from ``up_margin_m`` above that estimate in steps of ``step_dz_m`` of ray descent
       until ``g < 0`` (the first crossing, so rocks occlude what is behind them, up to the
       step's resolution);
    3. refine the bracket by the Illinois variant of regula falsi to well below a mm.

    Route coordinates along a ray come from a second-order expansion around ``t_s``, exact
    to millimetres within the few metres a bracket spans (curve radii are >= 180 m).

    With ``divergence_rad`` > 0 the beam is a cone of that full angle, and the range is what
    a time-of-flight receiver makes of the echo of its whole footprint:

    4. in the vertical plane of the central ray (where the footprint is long: at Stanley's
       grazing angles of 5-20 degrees it is 3-12 times longer along the ground than across),
       the ground is sampled where sub-rays spread evenly over the cone meet the local
       plane of the smooth ground (grade and cross profile), at most ``footprint_samples``
       of them and ``footprint_spacing_m`` apart, plus at most ``occluder_samples`` points
       ``occluder_spacing_m`` apart before the footprint, far enough back to catch an
       occluder ``occluder_height_m`` tall that the lowest sub-ray would graze;
    5. a ground point is seen if no nearer point subtends a higher elevation (a running
       maximum of the elevation tangent from the sensor), so each gap between samples
       reflects the slice of the cone between the horizon before it and its own elevation;
    6. the range is the mean of those slices' ranges weighted by the cone's light in them
       (uniform across the cone). Where the footprint straddles a depth edge (the top of a
       rock and the ground behind it, a pothole's rim and its floor) the return falls
       between the surfaces: a mixed pixel. Light beyond the last sample would come back
       later as a separate echo and is left out.

    The cone's spread across the scan plane is neglected: there the spot is at most
    ``25 m x 4.4 mrad = 11 cm`` wide, half the beam spacing.
    """

    route: Route
    crossfall: Callable[[FloatArray], FloatArray]
    step_dz_m: float = 0.1
    up_margin_m: float = 0.35
    down_margin_m: float = 0.35
    refine_iterations: int = 16
    tolerance_m: float = 0.0005
    max_range_m: float = 80.0
    min_range_m: float = 0.5
    divergence_rad: float = 0.0
    footprint_tolerance_m: float = 0.005
    footprint_samples: int = 12
    footprint_spacing_m: float = 0.12
    occluder_samples: int = 8
    occluder_spacing_m: float = 0.3
    occluder_height_m: float = 0.2
    # A footprint reaches at most this far from the central hit (grazing rays on a falling
    # road would otherwise meet the ground plane arbitrarily far away).
    footprint_reach_m: float = 4.0

    def cast(
        self, window: TerrainWindow, origin: FloatArray, direction: FloatArray, s_hint_m: float
    ) -> FloatArray:
        """Ranges (n,) for rays ``origin`` (n, 3) + t ``direction`` (n, 3); inf: no return."""
        ranges = np.full(origin.shape[0], np.inf)
        idx = np.flatnonzero(direction[:, 2] < -1e-3)
        if idx.size == 0:
            return ranges
        paths, t = self._expand(window, origin[idx], direction[idx], s_hint_m)
        t_lo, g_lo, t_hi, g_hi = self._march(paths, t)
        found, best = self._refine(paths, t_lo, g_lo, t_hi, g_hi)
        if self.divergence_rad > 0 and found.size:
            slope = self._ground_slope(paths, found, best)
            o, u = paths.o[found], paths.u[found]
            best = self._footprint(_CentralHits(paths, found, best, o, u, slope))
        ranges[idx[found]] = best
        return ranges

    def _expand(
        self, window: TerrainWindow, o: FloatArray, u: FloatArray, s_hint_m: float
    ) -> tuple[_RayPaths, FloatArray]:
        """Step 1: the rays' route coordinates about an estimate of where each meets the
        smooth ground, and that estimate ``t`` (n,), refined once with the cross profile."""
        uz = u[:, 2]
        # A smooth estimate against z0(s), s linearised along the route tangent ...
        x0, y0, h0 = self.route.sample(np.array([s_hint_m]))
        along = u[:, 0] * np.cos(h0[0]) + u[:, 1] * np.sin(h0[0])
        along_o = (o[:, 0] - x0[0]) * np.cos(h0[0]) + (o[:, 1] - y0[0]) * np.sin(h0[0])
        t = np.full(o.shape[0], 10.0)
        for _ in range(3):
            z0 = np.interp(s_hint_m + along_o + t * along, self.route.s_m, self.route.z0_m)
            t = np.clip((o[:, 2] - z0) / -uz, self.min_range_m, self.max_range_m)
        # Route coordinates along each ray: a second-order expansion about this point.
        p = o + t[:, None] * u
        s_s, d_s = self.route.to_route(p[:, 0], p[:, 1], s_hint_m + along_o + t * along)
        _, _, heading = self.route.sample(s_s)
        kappa = np.interp(s_s, self.route.s_m, self.route.curvature_per_m)
        a1 = u[:, 0] * np.cos(heading) + u[:, 1] * np.sin(heading)
        b1 = -u[:, 0] * np.sin(heading) + u[:, 1] * np.cos(heading)
        scale = 1.0 / (1.0 - kappa * d_s)
        # ds/dt = a1 / (1 - kappa d); dd/dt = b1; second order from the frame's rotation.
        s1 = a1 * scale
        s2 = kappa * a1 * b1 * scale**2
        d2 = -0.5 * kappa * a1**2 * scale
        paths = _RayPaths(window, o, u, t, s_s, d_s, s1, s2, b1, d2)
        # ... then refine the estimate once with the cross profile at the ray's offset.
        _, d_est = paths.route_coords(np.arange(o.shape[0]), t)
        z_smooth = np.interp(s_s, self.route.s_m, self.route.z0_m) + self.crossfall(d_est)
        t = np.clip((o[:, 2] - z_smooth) / -uz, self.min_range_m, self.max_range_m)
        return paths, t

    def _march(
        self, paths: _RayPaths, t: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Step 2: march down each ray from above the ground estimate ``t`` to its first
        crossing. Returns the brackets ``t_lo``, ``g_lo`` (g > 0) and ``t_hi``, ``g_hi``
        (g <= 0), (n,) each; ``t_hi`` NaN where the ray met nothing by its end."""
        uz = paths.u[:, 2]
        n = t.size
        # A ray already below ground where the march starts meets something higher than
        # expected (a berm, a hill's shoulder): start further back, up to twice.
        t_lo = np.maximum(t - self.up_margin_m / -uz, self.min_range_m)
        g_lo = paths.gap(np.arange(n), t_lo)
        for _ in range(2):
            under = np.flatnonzero(g_lo <= 0)
            if under.size == 0:
                break
            t_lo[under] = np.maximum(
                t_lo[under] - 3 * self.up_margin_m / -uz[under], self.min_range_m
            )
            g_lo[under] = paths.gap(under, t_lo[under])
        step = self.step_dz_m / -uz
        t_end = np.minimum(t + self.down_margin_m / -uz, self.max_range_m)
        t_hi = np.full(n, np.nan)
        g_hi = np.full(n, np.nan)
        active = np.flatnonzero(g_lo > 0)
        cur_t = t_lo[active]
        cur_g = g_lo[active]
        while active.size:
            nxt_t = np.minimum(cur_t + step[active], t_end[active])
            nxt_g = paths.gap(active, nxt_t)
            hit = nxt_g <= 0
            done = hit | (nxt_t >= t_end[active])
            hit_rows = active[hit]
            t_lo[hit_rows] = cur_t[hit]
            g_lo[hit_rows] = cur_g[hit]
            t_hi[hit_rows] = nxt_t[hit]
            g_hi[hit_rows] = nxt_g[hit]
            keep = ~done
            active, cur_t, cur_g = active[keep], nxt_t[keep], nxt_g[keep]
        return t_lo, g_lo, t_hi, g_hi

    def _refine(
        self,
        paths: _RayPaths,
        t_lo: FloatArray,
        g_lo: FloatArray,
        t_hi: FloatArray,
        g_hi: FloatArray,
    ) -> tuple[NDArray[np.intp], FloatArray]:
        """Step 3: Illinois refinement of each bracket [t_lo (g>0), t_hi (g<=0)], until the
        vertical miss is below ``tolerance_m`` times the ray's slope (a range error under
        ``tolerance_m``), for at most ``refine_iterations`` steps. Returns the rays that
        met the ground and their crossings' ray parameters."""
        uz = paths.u[:, 2]
        found = np.flatnonzero(np.isfinite(t_hi))
        a, fa = t_lo[found], g_lo[found]
        b, fb = t_hi[found], g_hi[found]
        side = np.zeros(found.size)
        best = np.where(np.abs(fa) < np.abs(fb), a, b)
        live = np.arange(found.size)
        # With a footprint the central crossing only places the footprint's samples: a few mm
        # of range is plenty (the echo's range comes from the samples).
        tolerance = self.tolerance_m if self.divergence_rad <= 0 else self.footprint_tolerance_m
        tol = tolerance * -uz[found]
        for _ in range(self.refine_iterations):
            fa_l, fb_l, a_l, b_l = fa[live], fb[live], a[live], b[live]
            c = b_l - fb_l * (b_l - a_l) / (fb_l - fa_l)
            fc = paths.gap(found[live], c)
            best[live] = c
            left = fc > 0
            # The end that stays twice in a row has its value halved (Illinois).
            side_l = side[live]
            fb_l = np.where(left & (side_l == 1), fb_l * 0.5, fb_l)
            fa_l = np.where(~left & (side_l == -1), fa_l * 0.5, fa_l)
            a[live] = np.where(left, c, a_l)
            fa[live] = np.where(left, fc, fa_l)
            b[live] = np.where(left, b_l, c)
            fb[live] = np.where(left, fb_l, fc)
            side[live] = np.where(left, 1, -1)
            live = live[np.abs(fc) > tol[live]]
            if live.size == 0:
                break
        return found, best

    def _ground_slope(
        self, paths: _RayPaths, found: NDArray[np.intp], best: FloatArray
    ) -> FloatArray:
        """The smooth ground's slope along each ray ``found`` at its hit ``best`` (grade and
        cross profile), per metre of horizontal distance: where the footprint's samples go."""
        u = paths.u
        tau = best - paths.t_expansion_m[found]
        s_c, d_c = paths.route_coords(found, best)
        grade = np.interp(s_c, self.route.s_m, np.gradient(self.route.z0_m, self.route.s_m))
        cross = (self.crossfall(d_c + 0.05) - self.crossfall(d_c - 0.05)) / 0.1
        ds_dt = paths.s1[found] + 2 * tau * paths.s2[found]
        dd_dt = paths.b1[found] + 2 * tau * paths.d2[found]
        slope: FloatArray = (grade * ds_dt + cross * dd_dt) / np.hypot(u[found, 0], u[found, 1])
        return slope

    def _footprint(self, hits: _CentralHits) -> FloatArray:
        """Ranges (n,) of the echo of each beam's footprint (steps 4-6 of the class doc),
        from the central rays' first crossings ``hits``.

        The march (step 2) can step over ground the central ray dips under for less than one
        step (the last few decimetres of a plateau or rock before its far edge, at grazing
        angles); the footprint's samples before the hit then stand above the central ray.
        Those rays are done again around the first such crossing of the sampled profile."""
        out, redo = self._footprint_once(hits)
        again = np.flatnonzero(np.isfinite(redo))
        if again.size:  # few: all at the most samples, in one go
            retry = replace(hits.take(again), t_c=redo[again])
            out[again], _ = self._profile(retry, self.footprint_samples, self.occluder_samples)
        return out

    def _footprint_once(self, hits: _CentralHits) -> tuple[FloatArray, FloatArray]:
        """One pass of :meth:`_footprint`: the ranges (n,), and (n,) where the sampled
        ground first rises above the central ray before ``t_c`` (its ray parameter; NaN
        where it does not).

        The samples are as many as their spacing needs, up to ``footprint_samples`` over the
        footprint (spacing ``footprint_spacing_m``) and ``occluder_samples`` before it
        (``occluder_spacing_m``), in three classes (a third, two thirds or all of both; a
        ray takes the class the larger need asks for): a near laser's 0.1 m footprint needs
        4, a far one's 1.4 m 12. Few classes, because each costs a pass of Python."""
        u, t_c, slope = hits.u, hits.t_c, hits.slope
        half = 0.5 * self.divergence_rad
        uh = np.hypot(u[:, 0], u[:, 1])
        tan_c = u[:, 2] / uh
        t_half = np.tan(half)
        rho_c = t_c * uh
        plane = -tan_c * rho_c + slope * rho_c  # as ``num`` in _sample_distances
        den_lo = slope - (tan_c - t_half) / (1.0 + tan_c * t_half)
        den_hi = slope - (tan_c + t_half) / (1.0 - tan_c * t_half)
        reach = self.footprint_reach_m
        near = plane / np.maximum(den_lo, 1e-6)
        far = np.where(den_hi > 1e-6, plane / np.maximum(den_hi, 1e-6), rho_c + reach)
        length = np.clip(far - near, 0.0, 2 * reach)
        back = np.clip(self.occluder_height_m / np.maximum(den_lo, 1e-6), 0.0, reach)
        levels_fp = np.ceil(self.footprint_samples * np.array([1, 2, 3]) / 3).astype(int)
        levels_occ = np.ceil(self.occluder_samples * np.array([1, 2, 3]) / 3).astype(int)
        need_fp = np.searchsorted(levels_fp, length / self.footprint_spacing_m + 1.0)
        need_occ = np.searchsorted(levels_occ, back / self.occluder_spacing_m)
        group = np.minimum(np.maximum(need_fp, need_occ), 2)
        out = np.empty(t_c.size)
        redo = np.empty(t_c.size)
        for g in np.unique(group):
            sel = np.flatnonzero(group == g)
            out[sel], redo[sel] = self._profile(
                hits.take(sel), int(levels_fp[g]), int(levels_occ[g])
            )
        return out, redo

    def _profile(self, hits: _CentralHits, k: int, m: int) -> tuple[FloatArray, FloatArray]:
        """:meth:`_footprint_once` for rays sampled ``k`` times over the footprint and ``m``
        times before it."""
        u = hits.u
        uh = np.hypot(u[:, 0], u[:, 1])  # horizontal length of the unit direction
        tan_c = u[:, 2] / uh
        tan_k, rho = self._sample_distances(hits, uh, tan_c, k, m)
        h = hits.paths.ground_along(hits.rows, rho / uh[:, None])
        tan_g = (h - hits.o[:, 2:3]) / rho  # elevation tangent of each ground sample
        horizon = np.maximum.accumulate(tan_g, axis=1)
        lo_b = np.maximum(horizon[:, :-1], tan_k[:, 0][:, None])  # slice of the cone per gap
        hi_b = np.minimum(horizon[:, 1:], tan_k[:, -1][:, None])
        light = np.maximum(hi_b - lo_b, 0.0)
        # The slice's middle sub-ray meets the ground between the gap's two samples, where
        # the (linear) profile's tangent reaches the middle tangent.
        # (A lit slice has t1 > t0; an unlit one any finite value.)
        mid = 0.5 * (lo_b + hi_b)
        t0 = tan_g[:, :-1]
        f = np.clip((mid - t0) / np.maximum(tan_g[:, 1:] - t0, 1e-12), 0.0, 1.0)
        rho_mid = rho[:, :-1] + f * (rho[:, 1:] - rho[:, :-1])
        total = light.sum(axis=1)
        lit = total > 0
        out = hits.t_c.copy()
        # Range from horizontal distance with the central ray's secant: the cone's 2.2 mrad
        # change it by at most 2e-4 of the range.
        out[lit] = (light * rho_mid).sum(axis=1)[lit] / total[lit] / uh[lit]
        # Ground sampled before the hit (the samples before the cone's centre) that stands
        # above the central ray: it met the ground first there.
        redo = _first_rise(tan_g[:, : m + k // 2], rho, tan_c, uh)
        return out, redo

    def _sample_distances(
        self, hits: _CentralHits, uh: FloatArray, tan_c: FloatArray, k: int, m: int
    ) -> tuple[FloatArray, FloatArray]:
        """Where :meth:`_profile` samples the ground: the ``k`` sub-rays' elevation tangents
        (n, k) and the horizontal distances (m) of the ``m`` samples before the footprint
        and the ``k`` over it, (n, m + k), nearest first. ``uh`` (n,) is the horizontal
        length of each unit direction and ``tan_c`` (n,) its central elevation tangent."""
        half = 0.5 * self.divergence_rad
        slope = hits.slope
        rho_c = hits.t_c * uh  # horizontal distance of the central hit
        above = -tan_c * rho_c  # sensor height above the central hit
        reach = self.footprint_reach_m
        # Sub-ray tangents, evenly spread over the cone; where each meets the local plane
        # z = z_c + slope (rho - rho_c), seen from the sensor: rho = (above + slope rho_c) /
        # (slope - tan). A sub-ray that never comes down to the plane is capped at the reach.
        # tan(el_c + offset) to first order: the offsets are at most 2.2 mrad, so the second
        # order (tan_c offset^2, below 1e-6) is far below the cone's width.
        offset = half * np.linspace(-1.0, 1.0, k)[None, :]
        tc = tan_c[:, None]
        tan_k = tc + offset * (1.0 + tc * tc)
        num = (above + slope * rho_c)[:, None]  # > 0: the sensor is above the plane
        den = slope[:, None] - tan_k  # falls with k, so rho_fp rises with k
        rho_fp = np.clip(
            num / np.maximum(den, 1e-6), (rho_c - reach)[:, None], (rho_c + reach)[:, None]
        )
        # Before the footprint: the lowest sub-ray is within occluder_height_m of the plane
        # for occluder_height_m / (slope - tan_lo) metres of horizontal distance.
        back = np.clip(self.occluder_height_m / np.maximum(den[:, 0], 1e-6), 0.0, reach)
        steps = np.arange(m, 0, -1) / m  # 1 .. 1/m of the way back
        rho_occ = np.maximum(
            rho_fp[:, :1] - back[:, None] * steps[None, :], self.min_range_m * uh[:, None]
        )
        return tan_k, np.concatenate([rho_occ, rho_fp], axis=1)


def _first_rise(
    tan_before: FloatArray, rho: FloatArray, tan_c: FloatArray, uh: FloatArray
) -> FloatArray:
    """Where the ground sampled before a hit first stands above the central ray, as a ray
    parameter (n,), NaN where it never does: between that sample and the one before,
    linear in between. ``tan_before`` (n, j) are the first ``j`` samples' elevation
    tangents, ``rho`` (n, >= j) their horizontal distances (m), ``tan_c`` (n,) the central
    ray's tangent and ``uh`` (n,) its direction's horizontal length."""
    above_ray = tan_before > tan_c[:, None] + 1e-9
    redo = np.full(tan_c.size, np.nan)
    hit_rows = np.flatnonzero(above_ray.any(axis=1))
    if hit_rows.size:
        j = np.argmax(above_ray[hit_rows], axis=1)
        i = np.maximum(j - 1, 0)
        ta, tb = tan_before[hit_rows, i], tan_before[hit_rows, j]
        ra, rb = rho[hit_rows, i], rho[hit_rows, j]
        w = np.where(tb > ta, (tan_c[hit_rows] - ta) / np.maximum(tb - ta, 1e-12), 1.0)
        w = np.where(j > 0, np.clip(w, 0.0, 1.0), 0.0)
        redo[hit_rows] = (ra + w * (rb - ra)) / uh[hit_rows]
    return redo
