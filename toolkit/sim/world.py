"""The simulated world: a desert route and the terrain it crosses.

The world is described in *route coordinates* ``(s, d)``: ``s`` is horizontal distance along
the route's centreline in metres and ``d`` the lateral offset from it, left positive. The
height of the ground is the sum of

* a smooth part: the route's hills ``z0(s)`` plus a cross profile ``crossfall(d)`` (a crowned
  road, shoulders and low graded berms beside it);
* fine random roughness on the road with an ISO 8608 displacement spectrum
  ``Gd(n) = Gd(n0) (n / n0)^-2`` with ``n0 = 0.1`` cycles/m (class D on the dirt road, E in
  rough stretches), synthesised on a 5 cm grid;
* coarser, rougher terrain beside the road on a 20 cm grid;
* sparse discrete rough features (washboard, potholes, rocks, ruts, cattle guards), placed
  across the road and its shoulders and sized from the distributions stated with the
  ``FEATURE_*`` constants (:func:`make_features`).

The grids are generated lazily in tiles along ``s`` from seeds derived from the world seed and
the tile index, so a 60-minute route costs no more memory than a one-minute one and any part
of the world can be regenerated on its own, bit for bit. Neighbouring tiles are joined by a
variance-preserving cross-fade, so the field has no seams.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np
import scipy.fft
from numpy.typing import NDArray

FloatArray = NDArray[np.floating[Any]]

ISO8608_N0_CYCLES_PER_M = 0.1
# Geometric mean of each ISO 8608 class's Gd(n0), in m^3.
ISO8608_CLASS_GD_N0_M3 = {
    "A": 16e-6,
    "B": 64e-6,
    "C": 256e-6,
    "D": 1024e-6,
    "E": 4096e-6,
    "F": 16384e-6,
    "G": 65536e-6,
    "H": 262144e-6,
}

FEATURE_KINDS = ("washboard", "pothole", "rock", "rut", "cattle_guard")
# Height (peak-to-peak, or depth) range of each kind, metres: washboard corrugations are
# shallow but periodic (0.5-2 cm: the corrugations of a graded road between gradings;
# judgement), ruts and cattle-guard decks are bounded by what traffic leaves.
# Pothole depths span the three depth classes of the unsurfaced-road pothole rating
# (TM 5-626, 1995, ch. 3, distress "Potholes": 1/2-2 in, 2-4 in, over 4 in; Eaton &
# Beaucham, CRREL SR 92-26, 1992); rock heights are judgement (what a 0.2-0.5 m desert
# stone shows above the ground), capped per rock by its footprint (see make_features).
FEATURE_HEIGHT_RANGE_M = {
    "washboard": (0.005, 0.02),
    "pothole": (0.03, 0.15),
    "rock": (0.03, 0.15),
    "rut": (0.02, 0.08),
    "cattle_guard": (0.03, 0.08),
}
# "ridge" is placed only on purpose (calibration obstacles), never at random.

# Share of the random features of each kind (normalised over ``WorldParams.feature_kinds``).
# Judgement: stones are the common discrete hazard of a desert road (most of them small:
# heights log-uniform), potholes the next; ruts form only where the surface is soft, and
# cattle guards sit only where a fence crosses the road (at 58 features per km in the race
# profile, 1.7 per km). Washboard is the common periodic hazard of any unsurfaced road with
# traffic (Skorseth & Selim, "Gravel Roads Maintenance and Design Manual", FHWA/SD LTAP
# 2000, ch. 1), but a stretch of it is one long, narrow-band excitation: its ripples are
# spaced by the speed of the traffic that made them over its wheels' hop frequency
# (Taberlet, Morris & McElwaine, Phys. Rev. Lett. 99, 068003, 2007), so a vehicle driven at
# a similar speed meets it near its own wheel hop, and near where the shock filter's band
# starts. At 25 % of the features and 6-30 m a stretch (the first model's, 9 % of the road)
# washboard made most positive labels and which of them were positive hung on that band
# edge. At 3 % and 3-12 m a stretch (about 1 % of the road; corrugations gather where
# traffic brakes and accelerates, Skorseth & Selim ch. 1) the positives come mostly from
# discrete impacts, the paper's "small discontinuities" (sect. 8). The shares were set with
# the label rate measured on race seeds 601-606 (benchmarks/sim_seeds.py;
# benchmarks/README.md), not taken from a survey.
FEATURE_KIND_WEIGHTS = {
    "washboard": 0.03,
    "pothole": 0.31,
    "rock": 0.53,
    "rut": 0.10,
    "cattle_guard": 0.03,
}

# -- Where features lie across the road (d, left positive) --------------------------------
# Shoulder width beyond each road edge on which features may lie, metres: the graded
# shoulder and ditch of the cross profile (``Terrain.crossfall``: ditch from the edge to
# 0.8 m beyond, berm foot at 1.3 m). Judgement, to match that profile.
FEATURE_SHOULDER_WIDTH_M = 1.2
# Traffic's wheel paths lie at +-track/2 about the crown: a desert road carries too little
# traffic for lanes, so vehicles drive its crown and move over only to pass (judgement; it
# is also where the simulated vehicle drives). Lateral spread of traffic about them, metres:
# the AASHTO Mechanistic-Empirical Pavement Design Guide's default traffic wander is a
# standard deviation of 10 in (0.254 m) on a marked lane; an unmarked road is wandered a
# little more widely (judgement: 0.3 m).
FEATURE_WHEEL_PATH_SIGMA_M = 0.3
# Share of potholes centred in a wheel path (normal about it, sigma above); the rest are
# uniform over the road's width. Potholes need water and traffic together (TM 5-626 ch. 3;
# Skorseth & Selim ch. 1: water ponding in wheel-path depressions is worked into holes by
# wheels), so they concentrate in the wheel paths but also form wherever the crown is lost
# and water stands; the shoulders carry no traffic and get none. The 60/40 split is
# judgement.
FEATURE_POTHOLE_WHEEL_PATH_SHARE = 0.6
# Rocks come in three kinds of place, with judgement shares:
# * in a wheel path (as potholes there), FEATURE_ROCK_WHEEL_PATH_SHARE: stones of the
#   roadbed laid bare where traffic whips the fines out of the wheel paths (Skorseth & Selim
#   ch. 1, "loss of fines" and loose aggregate in the travelled way);
# * at the edges, FEATURE_ROCK_EDGE_SHARE: uniform in |d| over the band from
#   FEATURE_ROCK_EDGE_INSET_M inside each edge to the shoulder's outer side, where traffic
#   throws loose stone and graders leave it (Skorseth & Selim ch. 1: traffic displaces
#   surface gravel to the shoulder, and windrows form along it);
# * the rest uniform over road and shoulders: stones fallen from banks and loads, or
#   scattered by traffic.
FEATURE_ROCK_WHEEL_PATH_SHARE = 0.3
FEATURE_ROCK_EDGE_SHARE = 0.4
FEATURE_ROCK_EDGE_INSET_M = 0.5

# -- Sizes and shapes ------------------------------------------------------------------------
# Rocks: long horizontal axis log-uniform over 0.2-0.5 m (issue 11: desert rocks 0.2-0.5 m
# across; log-uniform because small stones outnumber large ones); short horizontal axis a
# uniform fraction of it (Zingg's b/a shape ratio, judgement: natural clasts mostly 0.5-1);
# orientation uniform. A rock rests on its largest face, so its shortest axis is vertical
# and its exposed height is at most its short horizontal axis: heights are drawn from the
# kind's range capped at that axis. Shape: the upper half of an ellipsoid, so its flanks
# are vertical at the footprint's edge (a tyre meets a step, then rolls over a dome).
FEATURE_ROCK_MAJOR_AXIS_RANGE_M = (0.2, 0.5)
FEATURE_ROCK_AXIS_RATIO_RANGE = (0.5, 1.0)
# Potholes: long axis log-uniform over 0.3-1.2 m, spanning TM 5-626's diameter classes
# (< 1 ft, 1-2 ft, 2-3 ft, > 3 ft; ASTM D6433 for paved roads: "usually less than 750 mm");
# short axis 0.6-1 of it (near-round, a little longer than wide); orientation uniform; depth
# drawn independently from the kind's range, so potholes are wider and, for their width,
# shallower than rocks. Shape: a vertical wall at the rim down to
# FEATURE_POTHOLE_WALL_FRACTION of the depth ("sharp edges and vertical sides near the top
# of the hole", ASTM D6433's pothole definition), then a rounded (paraboloid) bowl to the
# full depth at the centre. The wall fraction is judgement.
FEATURE_POTHOLE_MAJOR_AXIS_RANGE_M = (0.3, 1.2)
FEATURE_POTHOLE_AXIS_RATIO_RANGE = (0.6, 1.0)
FEATURE_POTHOLE_WALL_FRACTION = 0.5
# Length along the road of the features placed by hand (the calibration profile's ridges), m:
# a 1.2 m hump, like a water bar or a low berm across a dirt road. The paper's Fig. 5 needs
# the shock to grow with speed over 5-15 m/s, and with the shock filter removing 0-10 Hz that
# holds only for an obstacle about this long: over a 0.5 m ridge the shock stops growing
# above about 10 m/s (it lasts 33 ms at 15 m/s, less than half a wheel-hop period, and the
# wheel cannot follow; peaks 0.22 / 0.37 / 0.39 / 0.33 / 0.30 G, r^2 0.08), while over a
# 1.5 m one the slow passes barely reach the filter's band (0.03 G at 5 m/s). The line does
# not pass through the origin (calibration seed 1: 0.068 G per m/s, -0.27 G): below
# v = 10 Hz x the obstacle's length its shock lies mostly under the filter's band.
FIXED_FEATURE_LENGTH_M = 1.2


@dataclass(frozen=True)
class WorldParams:
    """Everything that decides the world, besides the seed.

    Lengths in metres. ``feature_rate_per_km`` is the mean number of discrete rough features
    per kilometre of road; ``rough_stretch_fraction`` the share of the road that is rougher
    (ISO class ``rough_class``) than the base ``road_class``.
    """

    length_m: float
    road_half_width_m: float = 3.5
    road_class: str = "D"
    # Rough stretches are ISO class E ("very poor"), four times class D's spectral density.
    # Class F (the first model's) over 15 % of the road had the wheels off the ground every
    # few metres, a road a racer would not drive at the route's 10-17 m/s; and its Gaussian
    # roughness, not features a laser could single out, made most of the rough labels.
    rough_class: str = "E"
    rough_stretch_fraction: float = 0.15
    offroad_class: str = "F"
    feature_rate_per_km: float = 6.0
    feature_kinds: tuple[str, ...] = FEATURE_KINDS
    feature_height_range_m: tuple[float, float] = (0.02, 0.15)
    max_curvature_per_m: float = 1.0 / 180.0
    max_grade: float = 0.05
    straight: bool = False
    # Fixed features (kind, s_center_m, height_m) placed in addition to random ones; the
    # calibration profile uses this for its obstacles.
    fixed_features: tuple[tuple[str, float, float], ...] = ()


@dataclass(frozen=True)
class RoughFeature:
    """One discrete rough feature; its first seven fields are published on the ground-truth
    topic (``terrain_msgs/RoughFeature``).

    ``s_start_m``..``s_end_m`` and ``d_center_m -+ width_m / 2`` are the feature's bounding
    box in route coordinates (for a rotated ellipse, the box around it), so a point outside
    the box is never on the feature. ``height_m`` is the height (rock, ridge, cattle-guard
    deck), depth (pothole, rut) or peak-to-peak amplitude (washboard). Rocks and potholes
    are ellipses: ``major_axis_m`` and ``minor_axis_m`` their full axes and ``yaw_rad`` the
    long axis's angle from the route's direction (+s) towards +d; zero axes (features made
    by hand) mean the ellipse inscribed in the bounding box.
    """

    kind: str
    s_start_m: float
    s_end_m: float
    d_center_m: float
    width_m: float
    height_m: float
    wavelength_m: float = 0.0
    major_axis_m: float = 0.0
    minor_axis_m: float = 0.0
    yaw_rad: float = 0.0


# --------------------------------------------------------------------------------------------
# Route


@dataclass(frozen=True)
class Route:
    """The route's centreline, sampled every ``ds_m`` metres of horizontal distance.

    Arrays have shape (n,): ``s_m`` distance, ``x_m``/``y_m`` ENU position, ``heading_rad``
    (counter-clockwise from east), ``curvature_per_m`` (left turns positive), ``z0_m`` the
    centreline elevation and ``speed_limit_mps`` the segment's speed limit.
    """

    s_m: FloatArray
    x_m: FloatArray
    y_m: FloatArray
    heading_rad: FloatArray
    curvature_per_m: FloatArray
    z0_m: FloatArray
    speed_limit_mps: FloatArray

    @property
    def ds_m(self) -> float:
        return float(self.s_m[1] - self.s_m[0])

    @property
    def length_m(self) -> float:
        return float(self.s_m[-1])

    def sample(self, s_m: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Centreline (x, y, heading) at distances ``s_m``, any shape; linear between samples
        and clamped at the ends. The samples are uniform, so no search is needed."""
        u = np.asarray(s_m, dtype=np.float64) * (1.0 / self.ds_m)
        np.minimum(np.maximum(u, 0.0, out=u), self.s_m.size - 1.000001, out=u)  # np.clip
        i = u.astype(np.intp)
        f = u - i
        x = self.x_m[i] + f * self._dx[i]
        y = self.y_m[i] + f * self._dy[i]
        heading = self.heading_rad[i] + f * self._dh[i]
        return x, y, heading

    @property
    def _dx(self) -> FloatArray:
        return self._diffs()[0]

    @property
    def _dy(self) -> FloatArray:
        return self._diffs()[1]

    @property
    def _dh(self) -> FloatArray:
        return self._diffs()[2]

    def _diffs(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        cached = self.__dict__.get("_diff_cache")
        if cached is None:
            cached = tuple(
                np.append(np.diff(a), 0.0) for a in (self.x_m, self.y_m, self.heading_rad)
            )
            object.__setattr__(self, "_diff_cache", cached)
        return cached

    def to_world(self, s_m: FloatArray, d_m: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Route coordinates to ENU (x, y)."""
        x, y, heading = self.sample(s_m)
        return x - d_m * np.sin(heading), y + d_m * np.cos(heading)

    def to_route(
        self, x_m: FloatArray, y_m: FloatArray, s_guess_m: FloatArray, iterations: int = 3
    ) -> tuple[FloatArray, FloatArray]:
        """ENU (x, y) to route coordinates, by Newton steps from a nearby ``s_guess_m``.

        Valid within a few tens of metres of the centreline, where the projection onto the
        centreline is unique (curvature radius is at least 180 m). Each step shrinks the
        error by a factor of about ``kappa * d`` (< 0.25), so 3 steps from a guess within
        tens of metres reach millimetres, and 2 suffice from a guess within a metre.
        """
        s = np.asarray(s_guess_m, dtype=np.float64)
        for _ in range(iterations):
            cx, cy, heading = self.sample(s)
            ex, ey = x_m - cx, y_m - cy
            s = s + ex * np.cos(heading) + ey * np.sin(heading)
        cx, cy, heading = self.sample(s)
        d = -(x_m - cx) * np.sin(heading) + (y_m - cy) * np.cos(heading)
        return s, d


def _smooth_noise(
    rng: np.random.Generator, n: int, ds_m: float, wavelengths_m: Sequence[float] | FloatArray
) -> FloatArray:
    """A sum of sinusoids with random phases and the given wavelengths, unit peak amplitude."""
    s = np.arange(n) * ds_m
    out = np.zeros(n)
    for wavelength in wavelengths_m:
        out += np.sin(2 * np.pi * s / wavelength + rng.uniform(0, 2 * np.pi)) * rng.uniform(0.5, 1)
    return out / max(len(wavelengths_m), 1)


def make_route(params: WorldParams, rng: np.random.Generator, ds_m: float = 1.0) -> Route:
    """Lay out a route of gentle curves, hills and speed-limit segments."""
    n = int(np.ceil(params.length_m / ds_m)) + 2
    s = np.arange(n) * ds_m
    curvature: FloatArray
    z0: FloatArray
    if params.straight:
        curvature = np.zeros(n)
        z0 = np.zeros(n)
    else:
        curvature = params.max_curvature_per_m * _smooth_noise(
            rng, n, ds_m, rng.uniform(250.0, 1500.0, size=4)
        )
        # Long straights between the bends, as on desert tracks.
        curvature *= np.clip(np.abs(_smooth_noise(rng, n, ds_m, [2000.0])) * 2.5, 0, 1)
        # Grade g(s) integrates to elevation; bounded by max_grade.
        grade = params.max_grade * _smooth_noise(rng, n, ds_m, rng.uniform(300.0, 2500.0, size=3))
        z0 = np.concatenate([[0.0], np.cumsum(0.5 * (grade[1:] + grade[:-1])) * ds_m])
    heading0 = rng.uniform(-np.pi, np.pi) if not params.straight else 0.0
    heading = heading0 + np.concatenate(
        [[0.0], np.cumsum(0.5 * (curvature[1:] + curvature[:-1])) * ds_m]
    )
    # Midpoint-rule integration keeps the centreline within millimetres of the exact curve.
    mid_heading = 0.5 * (heading[1:] + heading[:-1])
    x = np.concatenate([[0.0], np.cumsum(np.cos(mid_heading)) * ds_m])
    y = np.concatenate([[0.0], np.cumsum(np.sin(mid_heading)) * ds_m])
    # Segment speed limits between 5 and 17 m/s, each segment 200-800 m long.
    limits = np.empty(n)
    i = 0
    while i < n:
        seg = int(rng.uniform(200.0, 800.0) / ds_m)
        limits[i : i + seg] = rng.choice([8.0, 10.0, 12.0, 13.5, 15.0, 17.0])
        i += seg
    return Route(
        s_m=s,
        x_m=x,
        y_m=y,
        heading_rad=heading,
        curvature_per_m=curvature,
        z0_m=z0,
        speed_limit_mps=limits,
    )


# --------------------------------------------------------------------------------------------
# Random fields


def iso8608_field(
    rng: np.random.Generator,
    shape: tuple[int, int],
    spacing_m: tuple[float, float],
    gd_n0_m3: float,
    n_band: tuple[float, float] = (0.02, 10.0),
) -> NDArray[np.float32]:
    """An isotropic Gaussian height field whose profiles follow ISO 8608, shape ``shape``.

    A profile of an isotropic field with 2-D spectrum ``S2(k) = C |k|^-3`` has the one-sided
    1-D spectrum ``Gd(n) = 4 C / n^2`` (integrate ``S2`` across the other axis), so
    ``C = Gd(n0) n0^2 / 4`` gives the ISO 8608 slope ``w = 2``. White noise is shaped by
    ``sqrt(S2 / (ds dd))`` in the Fourier domain; the field is periodic over the grid.
    """
    gain = _iso8608_gain(tuple(shape), tuple(spacing_m), gd_n0_m3, tuple(n_band))
    white = rng.standard_normal(shape)
    spectrum = scipy.fft.rfft2(white) * gain
    field: NDArray[np.float32] = scipy.fft.irfft2(spectrum, s=shape).astype(np.float32)
    return field


@lru_cache(maxsize=8)
def _iso8608_gain(
    shape: tuple[int, int],
    spacing_m: tuple[float, float],
    gd_n0_m3: float,
    n_band: tuple[float, float],
) -> NDArray[np.float64]:
    """The Fourier-domain gain of :func:`iso8608_field` (ns, nd // 2 + 1), read-only: the
    same for every tile of a kind, so computed once (it cost a tenth of a tile's synthesis)."""
    ns, nd = shape
    ds, dd = spacing_m
    ks = np.fft.fftfreq(ns, ds)[:, None]
    kd = np.fft.rfftfreq(nd, dd)[None, :]
    k = np.hypot(ks, kd)
    c = gd_n0_m3 * ISO8608_N0_CYCLES_PER_M**2 / 4.0
    with np.errstate(divide="ignore"):
        gain: NDArray[np.float64] = np.sqrt(c / (ds * dd)) * np.where(k > 0, k, np.inf) ** -1.5
    gain[(k < n_band[0]) | (k > n_band[1])] = 0.0
    gain.flags.writeable = False
    return gain


# --------------------------------------------------------------------------------------------
# Terrain


@dataclass(frozen=True)
class Grid:
    """A height grid over route coordinates: ``heights[i, j]`` at ``s0 + i*ds, d0 + j*dd``."""

    s0_m: float
    d0_m: float
    ds_m: float
    dd_m: float
    heights_m: NDArray[np.floating[Any]]

    def bilinear(self, s_m: FloatArray, d_m: FloatArray) -> FloatArray:
        """Bilinear interpolation; points outside the grid are clamped to its edge."""
        ns, nd = self.heights_m.shape
        # Clamped with the two ufuncs rather than np.clip: the same values, without
        # np.clip's Python-level dispatch (a hot path: hundreds of thousands of calls a log).
        u = (s_m - self.s0_m) * (1.0 / self.ds_m)
        np.minimum(np.maximum(u, 0.0, out=u), ns - 1.000001, out=u)
        v = (d_m - self.d0_m) * (1.0 / self.dd_m)
        np.minimum(np.maximum(v, 0.0, out=v), nd - 1.000001, out=v)
        i = u.astype(np.intp)
        j = v.astype(np.intp)
        u -= i  # now the fractions
        v -= j
        flat = self.heights_m.ravel()
        base = i * nd
        base += j
        h00 = flat[base]
        h01 = flat[base + 1]
        base += nd
        h10 = flat[base]
        h11 = flat[base + 1]
        top = h00 + (h01 - h00) * v
        height: FloatArray = top + ((h10 + (h11 - h10) * v) - top) * u
        return height


@dataclass
class Terrain:
    """Ground height over the whole route, generated tile by tile.

    ``height(s, d)`` comes from the fine grid within ``fine_half_width_m`` of the centreline
    (everything: smooth shape, ISO 8608 road roughness, rough features) and from the coarse
    grid beyond (smooth shape plus the rougher terrain beside the road). Tiles are cached;
    ``window`` assembles a contiguous pair of grids for a stretch of road so hot loops index
    plain arrays.
    """

    params: WorldParams
    seed: int
    route: Route
    features: tuple[RoughFeature, ...]
    tile_length_m: float = 51.2
    fine_spacing_m: float = 0.05
    fine_half_width_m: float = 6.0
    coarse_spacing_m: float = 0.2
    coarse_half_width_m: float = 45.0
    overlap_m: float = 3.2
    _roughness_scale_cache: FloatArray | None = field(default=None, repr=False)

    # -- the smooth part -------------------------------------------------------------------

    def crossfall(self, d_m: FloatArray) -> FloatArray:
        """Cross profile of the road corridor relative to the centreline, metres.

        A 2 % crowned road, a shallow ditch beyond the edge and a graded berm (about 0.3 m
        high, 1.8 m wide) further out; then open desert at ditch level.
        """
        half = self.params.road_half_width_m
        ad = np.abs(d_m)
        crown = -0.02 * np.minimum(ad, half)
        ditch = -0.12 * np.clip((ad - half) / 0.8, 0, 1)
        berm_center = half + 2.2
        berm = 0.3 * np.clip(1 - ((ad - berm_center) / 0.9) ** 2, 0, 1)
        return crown + ditch + berm

    def roughness_scale(self, s_m: FloatArray) -> FloatArray:
        """Amplitude multiplier of the road roughness: 1 on ordinary road, more in rough
        stretches (the ratio of the two ISO classes' amplitudes), smoothly blended."""
        if self._roughness_scale_cache is None:
            rng = np.random.default_rng([self.seed, 7])
            n = self.route.s_m.size
            scale = np.ones(n)
            ratio = np.sqrt(
                ISO8608_CLASS_GD_N0_M3[self.params.rough_class]
                / ISO8608_CLASS_GD_N0_M3[self.params.road_class]
            )
            mean_len = 150.0
            n_stretch = int(self.params.length_m * self.params.rough_stretch_fraction / mean_len)
            s = self.route.s_m
            for _ in range(n_stretch):
                center = rng.uniform(0, self.params.length_m)
                half = rng.uniform(0.25, 0.75) * mean_len
                ramp = np.clip((half - np.abs(s - center)) / 20.0 + 1.0, 0.0, 1.0)
                scale = np.maximum(scale, 1 + (ratio - 1) * np.clip(ramp, 0, 1))
            self._roughness_scale_cache = scale
        return np.interp(s_m, self.route.s_m, self._roughness_scale_cache)

    # -- tiles ------------------------------------------------------------------------------

    def _raw_tile(self, kind: str, index: int) -> NDArray[np.float32]:
        return _raw_field(
            self.seed,
            kind,
            index,
            self._rows(kind, self.tile_length_m + 2 * self.overlap_m),
            self._cols(kind),
            self._spacing(kind),
            self._class_gd(kind),
        )

    def _spacing(self, kind: str) -> float:
        return self.fine_spacing_m if kind == "fine" else self.coarse_spacing_m

    def _half_width(self, kind: str) -> float:
        return self.fine_half_width_m if kind == "fine" else self.coarse_half_width_m

    def _class_gd(self, kind: str) -> float:
        cls = self.params.road_class if kind == "fine" else self.params.offroad_class
        return ISO8608_CLASS_GD_N0_M3[cls]

    def _rows(self, kind: str, length_m: float) -> int:
        return int(round(length_m / self._spacing(kind)))

    def _cols(self, kind: str) -> int:
        return int(round(2 * self._half_width(kind) / self._spacing(kind))) + 1

    def tile(self, kind: str, index: int) -> Grid:
        """Tile ``index`` of the ``"fine"`` or ``"coarse"`` grid, rows ``[s0, s0 + L)``."""
        return _tile_cached(self, kind, index)

    def _build_tile(self, kind: str, index: int) -> Grid:
        sp = self._spacing(kind)
        rows = self._rows(kind, self.tile_length_m)
        s0 = index * self.tile_length_m
        d = -self._half_width(kind) + np.arange(self._cols(kind)) * sp
        if kind == "coarse":
            heights = self._coarse_heights(index)[:rows]
        else:
            s = s0 + np.arange(rows) * sp
            # The fine grid carries the *whole* height within the road corridor (the coarse
            # grid resampled, plus the detail), so a query needs a single lookup.
            coarse_ext = self._coarse_heights(index)
            under = Grid(
                s0,
                -self.coarse_half_width_m,
                self.coarse_spacing_m,
                self.coarse_spacing_m,
                coarse_ext,
            )
            ss, dd = np.meshgrid(s, d, indexing="ij")
            base = under.bilinear(ss.ravel(), dd.ravel()).reshape(ss.shape)
            road = self.roughness_scale(s)[:, None] * self._blended_field("fine", index)
            # Roughness fades out over the shoulder; beyond it the coarse terrain rules.
            taper = np.clip((self.fine_half_width_m - np.abs(d)) / 1.5, 0, 1)[None, :]
            heights = base + road * taper + self._render_features(s, d)
        return Grid(
            s0_m=s0,
            d0_m=-self._half_width(kind),
            ds_m=sp,
            dd_m=sp,
            heights_m=np.ascontiguousarray(heights, dtype=np.float32),
        )

    def _coarse_heights(self, index: int) -> FloatArray:
        """Coarse heights of tile ``index`` with one extra row (the next tile's first), so
        that resampling it near the tile's end needs no neighbour."""
        cache: dict[int, FloatArray] = self.__dict__.setdefault("_coarse_ext", {})
        if index in cache:
            return cache[index]
        sp = self.coarse_spacing_m
        rows = self._rows("coarse", self.tile_length_m)
        s = index * self.tile_length_m + np.arange(rows + 1) * sp
        d = -self.coarse_half_width_m + np.arange(self._cols("coarse")) * sp
        rough = self._blended_field("coarse", index)
        rough = np.concatenate([rough, self._blended_field("coarse", index + 1)[:1]], axis=0)
        offroad_weight = np.clip((np.abs(d) - (self.fine_half_width_m - 1.5)) / 1.5, 0, 1)
        z0 = np.interp(s, self.route.s_m, self.route.z0_m)
        heights: FloatArray = (
            z0[:, None] + self.crossfall(d)[None, :] + rough * offroad_weight[None, :]
        )
        cache[index] = heights
        while len(cache) > 8:
            cache.pop(next(iter(cache)))
        return heights

    def _blended_field(self, kind: str, index: int) -> FloatArray:
        """The seamless random field over tile ``index``, shape (rows, cols).

        Raw tile k spans ``[s0 - o, s0 + L + o)``; across each seam the two raw fields are
        mixed with weights ``(cos t, sin t)``, ``t: 0 -> pi/2``, which keeps the variance.
        """
        rows = self._rows(kind, self.tile_length_m)
        margin = self._rows(kind, self.overlap_m)
        raw = self._raw_tile(kind, index).astype(np.float64)
        out = raw[margin : margin + rows].copy()
        ramp = np.pi / 4 * np.arange(margin) / margin  # 0 .. pi/4 over half the seam
        prev = self._raw_tile(kind, index - 1)[rows + margin : rows + 2 * margin]
        t_in = np.pi / 4 + ramp
        out[:margin] = np.sin(t_in)[:, None] * out[:margin] + np.cos(t_in)[:, None] * prev
        nxt = self._raw_tile(kind, index + 1)[:margin]
        out[rows - margin :] = (
            np.cos(ramp)[:, None] * out[rows - margin :] + np.sin(ramp)[:, None] * nxt
        )
        return out

    def _render_features(self, s: FloatArray, d: FloatArray) -> FloatArray:
        out = np.zeros((s.size, d.size))
        lo, hi = s[0], s[-1]
        for f in self.features:
            if f.s_end_m < lo - 1 or f.s_start_m > hi + 1:
                continue
            i0 = max(int(np.searchsorted(s, f.s_start_m - 0.5)), 0)
            i1 = int(np.searchsorted(s, f.s_end_m + 0.5))
            if i1 <= i0:
                continue
            out[i0:i1] += feature_height(f, s[i0:i1, None], d[None, :])
        return out

    # -- queries ----------------------------------------------------------------------------

    def window(self, s_lo_m: float, s_hi_m: float, *, spare: bool = True) -> TerrainWindow:
        """Contiguous fine and coarse grids covering ``[s_lo, s_hi]``.

        With ``spare`` (the simulator's :class:`WindowCache`) the window always takes the
        tile after ``s_hi``'s as well, so it serves any later request up to the end of
        ``s_hi``'s tile. Without it, only the tiles the interval's interpolation needs: the
        next tile only when ``s_hi`` lies within two coarse grid steps of its tile's end (a
        point within one step interpolates towards the next tile's first row; the second
        step keeps such points clear of :meth:`Grid.bilinear`'s clamp at the grid's last
        row). The heights inside ``[s_lo, s_hi]`` are the same either way; a one-off query
        (the truth lookups of :mod:`toolkit.analysis.truth_terrain`) then synthesises a tile
        less.
        """
        k0 = int(np.floor(s_lo_m / self.tile_length_m))
        if spare:
            k1 = int(np.floor(s_hi_m / self.tile_length_m)) + 1
        else:
            k1 = int(np.floor((s_hi_m + 2 * self.coarse_spacing_m) / self.tile_length_m))
        grids = []
        for kind in ("fine", "coarse"):
            tiles = [self.tile(kind, k) for k in range(k0, k1 + 1)]
            heights = np.concatenate([t.heights_m for t in tiles], axis=0)
            t0 = tiles[0]
            grids.append(Grid(t0.s0_m, t0.d0_m, t0.ds_m, t0.dd_m, heights))
        return TerrainWindow(
            fine=grids[0], coarse=grids[1], fine_half_width_m=self.fine_half_width_m
        )

    def height(self, s_m: FloatArray, d_m: FloatArray) -> FloatArray:
        """Ground height (ENU z, metres) at route coordinates; any shapes that broadcast."""
        s_m, d_m = np.broadcast_arrays(np.asarray(s_m, float), np.asarray(d_m, float))
        flat_s, flat_d = s_m.ravel(), d_m.ravel()
        if flat_s.size == 0:
            return np.zeros(s_m.shape)
        win = self.window(float(flat_s.min()), float(flat_s.max()), spare=False)
        return win.height(flat_s, flat_d).reshape(s_m.shape)


@dataclass(frozen=True)
class TerrainWindow:
    """A contiguous stretch of terrain, for fast repeated queries."""

    fine: Grid
    coarse: Grid
    fine_half_width_m: float

    def height(self, s_m: FloatArray, d_m: FloatArray) -> FloatArray:
        """Ground height at route coordinates (1-D arrays of equal length)."""
        on_road = np.abs(d_m) < self.fine_half_width_m
        n_on = int(np.count_nonzero(on_road))
        if n_on == on_road.size:
            return self.fine.bilinear(s_m, d_m)
        if n_on == 0:
            return self.coarse.bilinear(s_m, d_m)
        # Each grid only where it rules (a ray's samples are often partly on the road).
        h = np.empty(on_road.size)
        h[on_road] = self.fine.bilinear(s_m[on_road], d_m[on_road])
        off = ~on_road
        h[off] = self.coarse.bilinear(s_m[off], d_m[off])
        return h


@dataclass
class WindowCache:
    """Hands out a :class:`TerrainWindow` covering a requested stretch, rebuilding it only
    when the request runs past the current one (the vehicle moves forward, so rarely)."""

    terrain: Terrain
    _window: TerrainWindow | None = None
    _range: tuple[float, float] = (0.0, -1.0)

    def covering(self, s_lo_m: float, s_hi_m: float) -> TerrainWindow:
        lo, hi = self._range
        if self._window is None or s_lo_m < lo or s_hi_m > hi:
            lo = max(0.0, s_lo_m - 10.0)
            hi = s_hi_m + self.terrain.tile_length_m
            self._window = self.terrain.window(lo, hi)
            tile = self.terrain.tile_length_m
            self._range = (np.floor(lo / tile) * tile, (np.floor(hi / tile) + 1) * tile)
        return self._window


@lru_cache(maxsize=64)
def _raw_field(
    seed: int,
    kind: str,
    index: int,
    rows: int,
    cols: int,
    spacing_m: float,
    gd_n0_m3: float,
) -> NDArray[np.float32]:
    rng = np.random.default_rng([seed, 1 if kind == "fine" else 2, index + (1 << 20)])
    return iso8608_field(rng, (rows, cols), (spacing_m, spacing_m), gd_n0_m3)


def _tile_cached(terrain: Terrain, kind: str, index: int) -> Grid:
    cache: dict[tuple[str, int], Grid] = terrain.__dict__.setdefault("_tiles", {})
    key = (kind, index)
    grid = cache.get(key)
    if grid is None:
        grid = terrain._build_tile(kind, index)
        cache[key] = grid
        # Bounded memory: the vehicle and its lasers only ever need a few tiles around
        # the current position, so drop the oldest beyond a small budget.
        while len(cache) > 16:
            cache.pop(next(iter(cache)))
    return grid


# --------------------------------------------------------------------------------------------
# Rough features


def _ellipse_frame(f: RoughFeature) -> tuple[float, float, float, float, float]:
    """(s of the centre, semi-major and semi-minor axis, cos and sin of the yaw) of a rock's
    or pothole's elliptical footprint."""
    sc = 0.5 * (f.s_start_m + f.s_end_m)
    if f.major_axis_m > 0.0 and f.minor_axis_m > 0.0:
        return sc, f.major_axis_m / 2, f.minor_axis_m / 2, np.cos(f.yaw_rad), np.sin(f.yaw_rad)
    return sc, (f.s_end_m - f.s_start_m) / 2, f.width_m / 2, 1.0, 0.0


def _ellipse_half_extents(a_m: float, b_m: float, yaw_rad: float) -> tuple[float, float]:
    """Half extents along s and d of an ellipse with semi-axes ``a_m``, ``b_m`` whose
    ``a`` axis is turned by ``yaw_rad`` from +s towards +d."""
    c, sn = np.cos(yaw_rad), np.sin(yaw_rad)
    return float(np.hypot(a_m * c, b_m * sn)), float(np.hypot(a_m * sn, b_m * c))


def feature_height(f: RoughFeature, s: FloatArray, d: FloatArray) -> FloatArray:
    """Height added by feature ``f`` at route coordinates ``s``, ``d`` (arrays that
    broadcast; the result has their broadcast shape), metres."""
    half_w = f.width_m / 2
    lateral = np.clip(1 - ((d - f.d_center_m) / half_w) ** 2, 0, 1) ** 0.25
    length = f.s_end_m - f.s_start_m
    u = (s - f.s_start_m) / length  # 0..1 along the feature
    inside = (u >= 0) & (u <= 1)
    if f.kind == "washboard":
        # Corrugations across the road, faded in and out over two wavelengths.
        ramp = np.clip(np.minimum(u, 1 - u) * length / (2 * f.wavelength_m), 0, 1)
        wave = 0.5 * f.height_m * np.sin(2 * np.pi * (s - f.s_start_m) / f.wavelength_m)
        return np.where(inside, wave * ramp * lateral, 0.0)
    if f.kind in ("pothole", "rock"):
        # r2: squared elliptical radius in the footprint's own axes, 1 on its edge.
        sc, a, b, c, sn = _ellipse_frame(f)
        ds = s - sc
        dd = d - f.d_center_m
        r2 = ((ds * c + dd * sn) / a) ** 2 + ((dd * c - ds * sn) / b) ** 2
        if f.kind == "rock":
            # The upper half of an ellipsoid: vertical flanks at the edge, a dome on top.
            return f.height_m * np.sqrt(np.maximum(1.0 - r2, 0.0))
        # A vertical wall at the rim, then a paraboloid bowl down to the full depth.
        wall = FEATURE_POTHOLE_WALL_FRACTION
        return np.where(r2 < 1.0, -f.height_m * (wall + (1.0 - wall) * (1.0 - r2)), 0.0)
    if f.kind == "ridge":
        # A smooth ridge across the road (a calibration obstacle, like a log or kerb).
        bump = np.where(inside, np.sin(np.pi * np.clip(u, 0, 1)) ** 2, 0.0)
        ridge: FloatArray = f.height_m * bump * lateral
        return ridge
    if f.kind == "rut":
        ramp = np.clip(np.minimum(u, 1 - u) * length / 2.0, 0, 1)
        groove = np.clip(1 - ((d - f.d_center_m) / half_w) ** 2, 0, 1)
        return np.where(inside, -f.height_m * groove * ramp, 0.0)
    if f.kind == "cattle_guard":
        # A raised deck of steel rails with gaps between them, across the whole road.
        ramp = np.clip(np.minimum(u, 1 - u) * length / 0.25, 0, 1)
        rails = 0.3 * (0.5 + 0.5 * np.cos(2 * np.pi * (s - f.s_start_m) / f.wavelength_m))
        return np.where(inside, f.height_m * ramp * (0.7 + rails) * lateral, 0.0)
    raise ValueError(f"unknown rough feature kind {f.kind!r}")


def footprint_lateral_span(f: RoughFeature, s_m: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The lateral extent ``(d_lo_m, d_hi_m)`` of feature ``f``'s footprint (where it
    changes the ground) at each of the distances ``s_m`` (any shape; both results have its
    shape), NaN where the footprint does not reach that ``s``.

    Rocks and potholes are their ellipses; every other kind its bounding box.
    """
    s = np.asarray(s_m, dtype=np.float64)
    if f.kind in ("pothole", "rock"):
        sc, a, b, c, sn = _ellipse_frame(f)
        x = s - sc
        # The ellipse's points (x, y = d - d_center) satisfy q2 y^2 + q1 y + q0 <= 0.
        q2 = (sn / a) ** 2 + (c / b) ** 2
        q1 = 2.0 * x * c * sn * (1.0 / a**2 - 1.0 / b**2)
        q0 = x * x * ((c / a) ** 2 + (sn / b) ** 2) - 1.0
        disc = q1 * q1 - 4.0 * q2 * q0
        root = np.sqrt(np.where(disc >= 0.0, disc, np.nan))
        return f.d_center_m + (-q1 - root) / (2 * q2), f.d_center_m + (-q1 + root) / (2 * q2)
    inside = (s >= f.s_start_m) & (s <= f.s_end_m)
    half_w = f.width_m / 2
    lo = np.where(inside, f.d_center_m - half_w, np.nan)
    return lo, np.where(inside, f.d_center_m + half_w, np.nan)


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _side(rng: np.random.Generator) -> float:
    return 1.0 if rng.random() < 0.5 else -1.0


def _ellipse_feature(
    kind: str,
    s0_m: float,
    rng: np.random.Generator,
    height_range_m: tuple[float, float],
    half_road_m: float,
    track_m: float,
) -> RoughFeature:
    """A rock or pothole starting at ``s0_m``: footprint, orientation, height or depth and
    lateral place drawn from the distributions stated with the ``FEATURE_*`` constants."""
    rock = kind == "rock"
    major_range = FEATURE_ROCK_MAJOR_AXIS_RANGE_M if rock else FEATURE_POTHOLE_MAJOR_AXIS_RANGE_M
    ratio_range = FEATURE_ROCK_AXIS_RATIO_RANGE if rock else FEATURE_POTHOLE_AXIS_RATIO_RANGE
    major = _log_uniform(rng, *major_range)
    minor = major * float(rng.uniform(*ratio_range))
    yaw = float(rng.uniform(0.0, np.pi))
    h_lo, h_hi = height_range_m
    if rock:
        # Exposed height at most the short horizontal axis (the rock lies on its largest
        # face); a profile's lower bound wins over that cap if the two conflict.
        h_hi = max(min(h_hi, minor), h_lo)
    height = _log_uniform(rng, h_lo, h_hi)
    half_s, half_d = _ellipse_half_extents(major / 2, minor / 2, yaw)
    outer = half_road_m + FEATURE_SHOULDER_WIDTH_M
    u = rng.random()
    if u < (FEATURE_ROCK_WHEEL_PATH_SHARE if rock else FEATURE_POTHOLE_WHEEL_PATH_SHARE):
        d = _side(rng) * track_m / 2 + rng.normal(0.0, FEATURE_WHEEL_PATH_SIGMA_M)
    elif not rock:
        d = rng.uniform(-(half_road_m - half_d), half_road_m - half_d)
    elif u < FEATURE_ROCK_WHEEL_PATH_SHARE + FEATURE_ROCK_EDGE_SHARE:
        d = _side(rng) * rng.uniform(half_road_m - FEATURE_ROCK_EDGE_INSET_M, outer - half_d)
    else:
        d = rng.uniform(-(outer - half_d), outer - half_d)
    return RoughFeature(
        kind,
        s0_m,
        s0_m + 2 * half_s,
        float(d),
        2 * half_d,
        height,
        major_axis_m=major,
        minor_axis_m=minor,
        yaw_rad=yaw,
    )


def make_features(
    params: WorldParams, route: Route, rng: np.random.Generator, track_m: float = 1.65
) -> tuple[RoughFeature, ...]:
    """Scatter discrete rough features along the road: Poisson in ``s`` at
    ``params.feature_rate_per_km``, kinds in the proportions of :data:`FEATURE_KIND_WEIGHTS`
    (among ``params.feature_kinds``), heights log-uniform in each kind's range clipped to
    ``params.feature_height_range_m`` (small features are much more common than large
    ones), then the profile's fixed features. Sorted by ``s_start_m``.

    Across the road (``track_m``: the track of the traffic that wears the road, 1.65 m like
    the simulated vehicle's):

    * potholes: in a traffic wheel path (``+-track_m / 2``, normal spread
      :data:`FEATURE_WHEEL_PATH_SIGMA_M`) with probability
      :data:`FEATURE_POTHOLE_WHEEL_PATH_SHARE`, else uniform over the road;
    * rocks: in a wheel path with probability :data:`FEATURE_ROCK_WHEEL_PATH_SHARE`, in
      the edge bands (:data:`FEATURE_ROCK_EDGE_INSET_M` inside each edge out to the
      shoulder's outer side) with probability :data:`FEATURE_ROCK_EDGE_SHARE`, else
      uniform over road and shoulders (:data:`FEATURE_SHOULDER_WIDTH_M` each side);
    * ruts: in a wheel path, as potholes there (wheels make them);
    * washboard and cattle guards: across the whole road.

    Rock and pothole footprints are ellipses (sizes and shapes with the ``FEATURE_*``
    constants); every footprint stays on the road and its shoulders.
    """
    count = rng.poisson(params.feature_rate_per_km * params.length_m / 1000.0)
    starts = np.sort(rng.uniform(30.0, max(params.length_m - 30.0, 31.0), size=count))
    lo, hi = params.feature_height_range_m
    kinds = params.feature_kinds
    unknown = [k for k in kinds if k not in FEATURE_KIND_WEIGHTS]
    if unknown:
        raise ValueError(f"no random placement for rough feature kinds {unknown}")
    weights = np.array([FEATURE_KIND_WEIGHTS[k] for k in kinds])
    weights = weights / weights.sum()
    out: list[RoughFeature] = []
    half_road = params.road_half_width_m
    for s0 in starts:
        kind = kinds[int(rng.choice(len(kinds), p=weights))]
        k_lo, k_hi = FEATURE_HEIGHT_RANGE_M[kind]
        h_lo, h_hi = max(lo, k_lo), max(min(hi, k_hi), max(lo, k_lo))
        if kind in ("pothole", "rock"):
            out.append(_ellipse_feature(kind, s0, rng, (h_lo, h_hi), half_road, track_m))
            continue
        height = _log_uniform(rng, h_lo, h_hi)
        if kind == "washboard":
            wavelength = float(rng.uniform(0.4, 1.0))
            length = float(rng.uniform(3.0, 12.0))
            out.append(RoughFeature(kind, s0, s0 + length, 0.0, 2 * half_road, height, wavelength))
        elif kind == "rut":
            length = float(rng.uniform(8.0, 40.0))
            width = float(rng.uniform(0.25, 0.5))
            d = _side(rng) * track_m / 2 + rng.normal(0.0, FEATURE_WHEEL_PATH_SIGMA_M)
            out.append(RoughFeature(kind, s0, s0 + length, float(d), width, height))
        else:  # cattle guard
            length = float(rng.uniform(2.0, 3.0))
            out.append(RoughFeature(kind, s0, s0 + length, 0.0, 2 * half_road, height, 0.2))
    for kind, s_center, height in params.fixed_features:
        size = FIXED_FEATURE_LENGTH_M
        out.append(
            RoughFeature(kind, s_center - size / 2, s_center + size / 2, 0.0, 2 * half_road, height)
        )
    out.sort(key=lambda f: f.s_start_m)
    return tuple(out)


@dataclass(frozen=True)
class World:
    """Route, terrain and features, all decided by ``(params, seed)``."""

    params: WorldParams
    seed: int
    route: Route
    terrain: Terrain

    @property
    def features(self) -> tuple[RoughFeature, ...]:
        return self.terrain.features


def make_world(params: WorldParams, seed: int) -> World:
    """Build the world for ``params`` and ``seed``; same inputs, same world, bit for bit."""
    route = make_route(params, np.random.default_rng([seed, 0]))
    features = make_features(params, route, np.random.default_rng([seed, 3]))
    terrain = Terrain(params=params, seed=seed, route=route, features=features)
    return World(params=params, seed=seed, route=route, terrain=terrain)
