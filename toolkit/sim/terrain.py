"""The ground's height over the route: ISO 8608 random fields in tiles, plus the smooth shape
and the rough features, and the grids that answer height queries.

A profile of an isotropic field with 2-D spectrum ``S2(k) = C |k|^-3`` follows ISO 8608's
``Gd(n) = Gd(n0) (n / n0)^-2`` (:func:`iso8608_field`). Tiles along ``s`` are synthesised
from seeds derived from the world seed and the tile index, so any stretch can be rebuilt on
its own, bit for bit; neighbouring tiles are cross-faded with weights ``(cos t, sin t)``,
which keeps the variance, so the field has no seams.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.fft
from numpy.typing import NDArray

from toolkit.arrays import AnyFloatArray as FloatArray
from toolkit.sim.features import RoughFeature, feature_height
from toolkit.sim.route import Route

if TYPE_CHECKING:
    from toolkit.sim.world_params import WorldParams


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
