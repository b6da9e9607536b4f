"""Where the simulated lasers' height errors come from, per laser (issue 26).

Usage::

    python benchmarks/laser_errors.py WS [--log LOG_ID] [--out DIR]

``WS`` is a workspace run ``--to tables`` on one simulated log. For the event points
(``tables/event_points.parquet``: the points within 30 cm of a rear tyre's track under each
event) the script re-projects every point from its scan's range and beam with the error
sources taken away one at a time, and reports per laser:

1. the z error against the true terrain under the point (std, 99 / 99.9 % of |error|, max,
   excess kurtosis) for each variant:

   * ``as_logged``: the estimated pose and the published mounts (``points.parquet``'s z);
   * ``true_pose``: the true pose (``truth_pose.parquet``) at the stamped beam time;
   * ``true_time``: ... at the true beam time (stamp less the laser clock's offset);
   * ``true_mount``: ... and the lasers' true (miscalibrated) mounts;
   * ``no_bias``: ... and the range less the laser's constant bias;
   * ``no_flex``: ... and the mount's flex under the body's specific force taken out, with
     the specific force differentiated from the 100 Hz truth (the simulator uses its 1 kHz
     truth, so a little flex remains).

   What is left after ``no_flex`` is range noise, quantisation, stamp jitter and the beam's
   footprint (mixed pixels); the first two give at most ``10 mm x sin(grazing)``.
2. on smooth (not rough) events, the largest |dz| between one laser's points in one 25 cm
   cell of one tyre patch (the race test's cell), per patch: with the true heights alone,
   as logged, and with the true heights plus one error source alone (the difference of two
   consecutive variants above, applied at the logged point), and how far apart in range
   and time the points sharing a cell were taken;
3. for events with a feature under a tyre (truth), how many of the closest laser's points of
   that tyre land on the feature's footprint and the largest true height among them.

Only the simulator's truth is read (``mcap_metadata.json``'s ``terrain_sim`` record: true
mounts, range biases, clock offsets, laser parameters); nothing is written but ``--out``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
from scipy.spatial.transform import Rotation, Slerp
from scipy.stats import kurtosis

from toolkit.analysis.truth_terrain import true_ground
from toolkit.geometry.mounts import frame_mounts
from toolkit.geometry.rotations import euler_to_rot

GRAVITY_MPS2 = 9.80665
CELL_M = 0.25
VARIANTS = ("as_logged", "true_pose", "true_time", "true_mount", "no_bias", "no_flex")


def frame_of(topic: str) -> str:
    """``/laser/front_3`` -> ``laser_3`` (the simulator's frame names)."""
    return "laser_" + topic.rsplit("_", 1)[-1]


class Poses:
    """A pose table interpolated at any time: positions linearly, attitudes by Slerp, and
    (truth only) the body's specific force from the differentiated velocity."""

    def __init__(self, path: Path) -> None:
        t = pq.read_table(path).to_pandas()
        self.t = t["t_ns"].to_numpy(np.int64)
        self.t0 = int(self.t[0])
        self.ts = (self.t - self.t0) * 1e-9
        self.pos = t[["x", "y", "z"]].to_numpy(np.float64)
        rpy = t[["roll", "pitch", "yaw"]].to_numpy(np.float64)
        self.rot = Rotation.from_matrix(euler_to_rot(rpy))
        self.slerp = Slerp(self.ts, self.rot)
        v = t[["vx", "vy", "vz"]].to_numpy(np.float64)
        a = np.gradient(v, self.ts, axis=0)
        a[:, 2] += GRAVITY_MPS2
        # Specific force in the body frame (world velocities: the pose's ENU frame).
        self.f_body = self.rot.inv().apply(a)

    def at(self, t_ns: np.ndarray) -> tuple[np.ndarray, Rotation]:
        s = np.clip((t_ns - self.t0) * 1e-9, self.ts[0], self.ts[-1])
        pos = np.stack([np.interp(s, self.ts, self.pos[:, j]) for j in range(3)], axis=1)
        return pos, self.slerp(s)

    def specific_force(self, t_ns: np.ndarray) -> np.ndarray:
        s = (t_ns - self.t0) * 1e-9
        return np.stack([np.interp(s, self.ts, self.f_body[:, j]) for j in range(3)], axis=1)


def project(
    pos: np.ndarray,
    rot: Rotation,
    mount_rot: np.ndarray,
    mount_xyz: np.ndarray,
    rng: np.ndarray,
    theta: np.ndarray,
    flex_pitch: np.ndarray | None = None,
) -> np.ndarray:
    """World points (N, 3): ``pos + R (F R_mount r (cos, sin, 0) + t_mount)``, with ``F`` the
    flex rotation about base_link's y (positive nose-down), none when ``flex_pitch`` is None.
    ``mount_rot`` (N, 3, 3), ``mount_xyz`` (N, 3)."""
    p_laser = np.stack([rng * np.cos(theta), rng * np.sin(theta), np.zeros_like(rng)], axis=1)
    d = np.einsum("nij,nj->ni", mount_rot, p_laser)
    if flex_pitch is not None:
        c, s = np.cos(flex_pitch), np.sin(flex_pitch)
        d = np.stack([c * d[:, 0] + s * d[:, 2], d[:, 1], -s * d[:, 0] + c * d[:, 2]], axis=1)
    return pos + rot.apply(d + mount_xyz)


def load(ws: Path, log_id: str | None) -> tuple[pd.DataFrame, pd.DataFrame, Path, str]:
    events = pq.read_table(ws / "tables" / "events.parquet").to_pandas()
    log_id = log_id or str(events["log_id"].iloc[0])
    events = events[events["log_id"] == log_id]
    pts = pq.read_table(ws / "tables" / "event_points.parquet").to_pandas()
    pts = pts[pts["log_id"] == log_id].reset_index(drop=True)
    log_dir = ws / "logs" / log_id
    labelled = pq.read_table(
        log_dir / "events.parquet",
        columns=["event_id", "truth_feature_height_m", "truth_feature_kind"],
    ).to_pandas()
    events = events.merge(labelled, on="event_id", how="left")
    # Each event point's beam and range, from the cloud (by laser and beam time).
    cloud = pq.read_table(
        log_dir / "points.parquet",
        columns=["t_ns", "laser", "beam", "range"],
        filters=[("t_ns", "in", pa.array(np.unique(pts["t_ns"].to_numpy())))],
    )
    cloud = cloud.set_column(1, "laser", pc.cast(cloud.column("laser"), pa.string()))
    cloud_df = cloud.to_pandas().drop_duplicates(["laser", "t_ns"])
    pts = pts.merge(cloud_df, on=["laser", "t_ns"], how="left", validate="many_to_one")
    if pts["range"].isna().any():
        raise SystemExit(f"{int(pts['range'].isna().sum())} event points not in the cloud")
    return events, pts, log_dir, log_id


def errors(pts: pd.DataFrame, log_dir: Path) -> dict[str, np.ndarray]:
    """z error (N,) of every event point for each variant, and the true height under the
    logged point (``h``) and the truth's route coordinates."""
    sim = json.loads((log_dir / "mcap_metadata.json").read_text())["terrain_sim"]
    sensors = json.loads(sim["sensors"])["laser"]
    true_mounts = json.loads(sim["laser_true_mounts"])
    bias = json.loads(sim["laser_range_bias_m"])
    offsets = json.loads(sim["clock_offsets_ns"])
    frames = sorted({frame_of(t) for t in pts["laser"].unique()})
    published, _ = frame_mounts(log_dir / "tf_static.json", "base_link", frames)

    frame = pts["laser"].map(frame_of).to_numpy()
    t_ns = pts["t_ns"].to_numpy(np.int64)
    t_true = t_ns - pts["laser"].map(lambda s: offsets[s]).to_numpy(np.int64)
    rng = pts["range"].to_numpy(np.float64)
    theta = sensors["angle_min_rad"] + pts["beam"].to_numpy() * sensors["angle_increment_rad"]
    n = len(pts)
    pub_rot, pub_xyz = np.empty((n, 3, 3)), np.empty((n, 3))
    tru_rot, tru_xyz = np.empty((n, 3, 3)), np.empty((n, 3))
    rng_bias = np.empty(n)
    for f in frames:
        m = frame == f
        pub_rot[m] = published[f].rotation
        pub_xyz[m] = np.asarray(published[f].translation_m)
        r, p, y = true_mounts[f]["rpy_rad"]
        tru_rot[m] = Rotation.from_euler("ZYX", [y, p, r]).as_matrix()
        tru_xyz[m] = np.asarray(true_mounts[f]["xyz_m"])
        rng_bias[m] = bias[f]

    est = Poses(log_dir / "pose.parquet")
    tru = Poses(log_dir / "truth_pose.parquet")
    fs = tru.specific_force(t_true)
    flex = sensors["flex_pitch_rad_per_mps2"] * ((fs[:, 2] - GRAVITY_MPS2) - fs[:, 0])

    xyz = {}
    pos, rot = est.at(t_ns)
    xyz["as_logged"] = project(pos, rot, pub_rot, pub_xyz, rng, theta)
    pos, rot = tru.at(t_ns)
    xyz["true_pose"] = project(pos, rot, pub_rot, pub_xyz, rng, theta)
    pos, rot = tru.at(t_true)
    xyz["true_time"] = project(pos, rot, pub_rot, pub_xyz, rng, theta)
    xyz["true_mount"] = project(pos, rot, tru_rot, tru_xyz, rng, theta)
    xyz["no_bias"] = project(pos, rot, tru_rot, tru_xyz, rng - rng_bias, theta)
    xyz["no_flex"] = project(pos, rot, tru_rot, tru_xyz, rng - rng_bias, theta, flex)

    logged = pts[["x", "y", "z"]].to_numpy(np.float64)
    gap = np.abs(xyz["as_logged"] - logged).max()
    if gap > 1e-3:
        raise SystemExit(f"re-projection does not reproduce the cloud: {gap:.4f} m")
    ground = true_ground(log_dir)
    if ground is None:
        raise SystemExit("not a simulated log")
    out: dict[str, np.ndarray] = {}
    for name, p in xyz.items():
        h, z = ground.height_m(p)
        out[name] = z - h
    s, d, _ = ground.route_coordinates(logged)
    out["h"] = ground.terrain_height_m(s, d)
    out["s"], out["d"] = s, d
    # Grazing angle of each beam (for the range-to-height factor) and the flex angle.
    horiz = np.hypot(*(xyz["no_flex"][:, :2] - (pos + rot.apply(tru_xyz))[:, :2]).T)
    out["grazing"] = np.arctan2(pos[:, 2] + rot.apply(tru_xyz)[:, 2] - xyz["no_flex"][:, 2], horiz)
    out["flex_rad"] = flex
    out["horiz_m"] = horiz
    return out


def tail_row(e: np.ndarray, local: np.ndarray) -> dict[str, float]:
    """Global std of ``e``; spread, tail quantiles of |.|, max and excess kurtosis of the
    ``local`` error (the patch's median removed: what comparisons within a patch see)."""
    ok = np.isfinite(local)
    x = local[ok]
    a = np.abs(x)
    return {
        "n": int(ok.sum()),
        "std_global_cm": 100 * float(np.nanstd(e)),
        "std_cm": 100 * x.std(),
        "q99_cm": 100 * np.quantile(a, 0.99),
        "q999_cm": 100 * np.quantile(a, 0.999),
        "max_cm": 100 * a.max(),
        "kurt": float(kurtosis(x)),
    }


def cell_groups(pts: pd.DataFrame) -> pd.DataFrame:
    return pd.DataFrame(
        {
            "event_id": pts["event_id"].to_numpy(),
            "wheel": pts["wheel"].to_numpy(),
            "laser": pts["laser"].to_numpy(),
            "cx": np.floor(pts["x"].to_numpy() / CELL_M).astype(np.int64),
            "cy": np.floor(pts["y"].to_numpy() / CELL_M).astype(np.int64),
        }
    )


def cell_dz(pts: pd.DataFrame, z: np.ndarray) -> pd.Series:
    """Largest within-cell |dz| per (event, wheel, laser) over the 25 cm cells."""
    df = cell_groups(pts).assign(z=z).dropna()
    g = df.groupby(["event_id", "wheel", "laser", "cx", "cy"])["z"]
    spread = (g.max() - g.min()).rename("dz")
    return spread.groupby(level=["event_id", "wheel", "laser"]).max()


def dz_row(name: str, laser: str, dz: pd.Series) -> dict[str, object]:
    x = 100 * dz.xs(laser, level="laser").to_numpy()
    return {
        "z": name,
        "laser": laser,
        "patches": x.size,
        "median_cm": np.median(x),
        "q90_cm": np.quantile(x, 0.9),
        "q99_cm": np.quantile(x, 0.99),
        "max_cm": x.max(),
        "over_5cm_pct": 100 * np.mean(x > 5.0),
        "over_10cm_pct": 100 * np.mean(x > 10.0),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("ws", type=Path)
    ap.add_argument("--log", default=None)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    events, pts, log_dir, log_id = load(args.ws, args.log)
    err = errors(pts, log_dir)
    lasers = sorted(pts["laser"].unique())
    pd.set_option("display.width", 200)
    pd.set_option("display.max_columns", 20)
    pd.set_option("display.precision", 2)
    n_rough = int(events["rough"].sum())
    print(f"log {log_id}: {len(events)} events ({n_rough} rough), {len(pts)} event points, "
          f"{len(pts) / max(len(events), 1) / 2:.0f} a tyre")  # fmt: skip

    by_laser = {laser: (pts["laser"] == laser).to_numpy() for laser in lasers}
    geo = pd.DataFrame(
        {
            laser: {
                "points_a_tyre": m.sum() / max(len(events), 1) / 2,
                "horiz_m": np.median(err["horiz_m"][m]),
                "range_m": np.median(pts["range"].to_numpy()[m]),
                "grazing_deg": np.degrees(np.median(err["grazing"][m])),
                "flex_std_mrad": 1e3 * np.std(err["flex_rad"][m]),
            }
            for laser, m in by_laser.items()
        }
    ).T
    print("\nGeometry of the event points (medians) and the mounts' flex\n", geo)

    patch = (pts["event_id"].astype(str) + pts["wheel"] + pts["laser"]).to_numpy()
    rows = []
    for name in VARIANTS:
        local = err[name] - pd.Series(err[name]).groupby(patch).transform("median").to_numpy()
        for laser, m in by_laser.items():
            rows.append({"variant": name, "laser": laser, **tail_row(err[name][m], local[m])})
    table = pd.DataFrame(rows).set_index(["variant", "laser"])
    print("\n1. z error against the true terrain; std_global about the log's mean, the rest "
          "with each patch's median removed\n", table.to_string())  # fmt: skip

    smooth = set(events.loc[~events["rough"].astype(bool), "event_id"])
    keep = pts["event_id"].isin(smooth).to_numpy()
    sub = pts[keep]
    h = err["h"][keep]
    components = {
        "pose": err["as_logged"] - err["true_pose"],
        "timing": err["true_pose"] - err["true_time"],
        "mount": err["true_time"] - err["true_mount"],
        "bias": err["true_mount"] - err["no_bias"],
        "flex": err["no_bias"] - err["no_flex"],
        "residual": err["no_flex"],
    }
    dz_rows = []
    for name, z in [("truth", h), ("as_logged", h + err["as_logged"][keep])] + [
        (f"truth+{c}", h + v[keep]) for c, v in components.items()
    ]:
        dz = cell_dz(sub, z)
        dz_rows.extend(dz_row(name, laser, dz) for laser in lasers)
    dz_table = pd.DataFrame(dz_rows).set_index(["z", "laser"])
    print("\n2. largest within-cell |dz| per tyre patch and laser, smooth events: the true "
          "heights, as logged, and the true heights plus one error source alone "
          "(residual: noise, quantisation, stamp jitter, footprint)\n",
          dz_table.to_string())  # fmt: skip

    cells = cell_groups(sub).assign(r=sub["range"].to_numpy(), t=sub["t_ns"].to_numpy() * 1e-9)
    g = cells.groupby(["event_id", "wheel", "laser", "cx", "cy"])
    spread = pd.DataFrame({"dr": g["r"].max() - g["r"].min(), "dt": g["t"].max() - g["t"].min(),
                           "n": g["r"].size()})  # fmt: skip
    spread = spread[spread["n"] >= 2]
    sp = spread.groupby(level="laser").agg(
        cells=("n", "size"),
        points_median=("n", "median"),
        dr_median_m=("dr", "median"),
        dr_q90_m=("dr", lambda x: x.quantile(0.9)),
        dt_median_s=("dt", "median"),
        dt_q90_s=("dt", lambda x: x.quantile(0.9)),
    )
    print("\n   cells with two or more points: spread of range and time within a cell\n",
          sp.to_string())  # fmt: skip

    # 3. Features under a tyre: do each laser's points land on them?
    feats = pq.read_table(log_dir / "truth_features.parquet").to_pandas()
    under = events[events["truth_feature_height_m"].fillna(0) > 0.03]
    rows3 = []
    for ev in under.itertuples():
        p = (pts["event_id"] == ev.event_id).to_numpy()
        for laser, m in by_laser.items():
            q = p & m
            if not q.any():
                continue
            s, d = err["s"][q], err["d"][q]
            on = np.zeros(q.sum(), bool)
            for f in feats.itertuples():
                on |= (
                    (s >= f.s_start_m)
                    & (s <= f.s_end_m)
                    & (np.abs(d - f.d_center_m) <= f.width_m / 2)
                )
            h_rel = err["h"][q] - np.median(err["h"][q])
            dz = cell_dz(pts[q], pts["z"].to_numpy()[q])
            rows3.append(
                {
                    "event": int(ev.event_id),
                    "rough": bool(ev.rough),
                    "kind": ev.truth_feature_kind,
                    "feature_cm": 100 * ev.truth_feature_height_m,
                    "laser": laser,
                    "points": int(q.sum()),
                    "on_feature": int(on.sum()),
                    "top_true_cm": 100 * float(h_rel[on].max()) if on.any() else np.nan,
                    "cell_dz_cm": 100 * float(dz.max()) if len(dz) else np.nan,
                }
            )
    t3 = pd.DataFrame(rows3)
    if len(t3):
        print(f"\n3. events with a feature over 3 cm under a tyre ({len(under)}): rough ones, "
              "each laser\n", t3[t3["rough"]].to_string(index=False))  # fmt: skip
        print("\n   all of them, by laser and kind: points, points on the feature's box, "
              "events with a point on it\n",
              t3.assign(hit=t3["on_feature"] > 0).groupby(["kind", "laser"])[
                  ["points", "on_feature", "hit"]].sum().to_string())  # fmt: skip
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        table.to_csv(args.out / "z_error.csv")
        dz_table.to_csv(args.out / "cell_dz_smooth.csv")
        sp.to_csv(args.out / "cell_spread.csv")
        t3.to_csv(args.out / "features.csv", index=False)


if __name__ == "__main__":
    main()
