"""How realistic is a simulated log? A report to judge a simulator change by looking.

Runs the toolkit's own stages on one simulated log in a scratch workspace (ingest, pose,
project, label) and writes into ``--out``:

- ``imu_spectrum.png`` / ``.csv``: the power spectral density of the IMU's vertical specific
  force while driving (Welch, 4 s segments), with the shock filter's band edges marked: a
  wheel-hop peak near 10-15 Hz should show, and the label rate should not hang on a cliff there.
- ``band_edge.csv`` / ``.png``: the share of rough events as the filter's lower band edge moves
  from 8 to 12 Hz (the pass edge 5 Hz above it, 40 taps): label once per edge.
- ``fig4_truth.csv`` / ``.png``: the paper's Fig. 4 from the points projected with the *true*
  pose (what the lasers alone contribute) next to the one from the estimated pose the project
  stage wrote.
- ``positives.csv``: every rough event with what the truth says lies under a rear tyre (kind,
  height), and the counts by kind (background roughness when none).
- ``fig5_shock_speed.png`` / ``.csv``: the paper's Fig. 5 (peak shock against speed over the
  obstacles of a ``calibration`` log, with its line and r^2: the label stage's figure), from
  ``--calibration CAL.mcap`` (or from LOG itself when it is a calibration log).

Usage: python benchmarks/sim_report.py LOG.mcap --out DIR [--calibration CAL.mcap]
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import shutil
import tempfile
from collections import Counter
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy import signal  # noqa: E402

from toolkit.analysis.fig4 import write_fig4  # noqa: E402
from toolkit.analysis.scan_agreement import ScanAgreement  # noqa: E402
from toolkit.config import default_config  # noqa: E402
from toolkit.geometry.mounts import frame_mounts, sensor_mounts  # noqa: E402
from toolkit.model.projection import Counts  # noqa: E402
from toolkit.stages.ingest import ingest_log  # noqa: E402
from toolkit.stages.label import SPEC as LABEL  # noqa: E402
from toolkit.stages.pose import SPEC as POSE  # noqa: E402
from toolkit.stages.project import SPEC as PROJECT  # noqa: E402
from toolkit.stages.project_scans import (  # noqa: E402
    LASER_COLUMNS,
    PoseStream,
    ScanBatch,
    project_batch,
)
from toolkit.stages.runner import run_stage  # noqa: E402
from toolkit.tableio import iter_table_batches, read_table  # noqa: E402
from toolkit.workspace import Workspace  # noqa: E402

BAND_EDGES_HZ = (8.0, 9.0, 10.0, 11.0, 12.0)


def imu_spectrum(log_dir: Path, out: Path, stop_hz: float, pass_hz: float) -> None:
    """Welch PSD of base_link's vertical specific force while moving faster than 2 m/s."""
    imu = read_table(log_dir / "imu.parquet", "imu")
    pose = read_table(log_dir / "pose.parquet", "pose", columns=["t_ns", "speed"])
    mount = sensor_mounts(log_dir / "tf_static.json", default_config().vehicle).imu
    accel = np.stack([imu.column(f"accel_{a}").to_numpy() for a in "xyz"], axis=1)
    az = accel @ mount.rotation[2]
    t = imu.column("t_ns").to_numpy()
    speed = np.interp(t, pose.column("t_ns").to_numpy(), pose.column("speed").to_numpy())
    rate = 1e9 / float(np.median(np.diff(t)))
    moving = az[speed > 2.0]
    freq, psd = signal.welch(moving - moving.mean(), fs=rate, nperseg=int(4 * rate))
    with (out / "imu_spectrum.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["freq_hz", "psd_m2_s4_per_hz"])
        w.writerows(zip(freq.tolist(), psd.tolist(), strict=True))
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.semilogy(freq, psd)
    for x, label in ((stop_hz, "stop edge"), (pass_hz, "pass edge")):
        ax.axvline(x, color="grey", ls="--", lw=0.8)
        ax.text(x, psd.max(), label, rotation=90, va="top", fontsize=8)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("PSD of vertical specific force ((m/s^2)^2/Hz)")
    ax.set_title("IMU vertical spectrum while driving")
    fig.tight_layout()
    fig.savefig(out / "imu_spectrum.png", dpi=110)
    plt.close(fig)


def band_edge_rates(ws: Workspace, log_id: str, out: Path) -> list[tuple[float, int, int]]:
    """(stop edge Hz, events, rough) per edge; the label stage run once per edge."""
    base = default_config()
    rows = []
    for stop in BAND_EDGES_HZ:
        label = dataclasses.replace(base.label, fir_stop_hz=stop, fir_pass_hz=stop + 5.0)
        result = run_stage(
            LABEL, ws, dataclasses.replace(base, label=label), log_id=log_id, overwrite=True
        )
        rows.append((stop, result.events, result.rough))
    with (out / "band_edge.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["stop_edge_hz", "events", "rough", "rough_percent"])
        for stop, n, rough in rows:
            w.writerow([stop, n, rough, round(100.0 * rough / max(n, 1), 4)])
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot([r[0] for r in rows], [100.0 * r[2] / max(r[1], 1) for r in rows], "o-")
    ax.axhspan(0.3, 0.6, color="green", alpha=0.15, label="target 0.3-0.6 %")
    ax.set_xlabel("filter stop edge (Hz; pass edge 5 Hz above)")
    ax.set_ylabel("rough events (%)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "band_edge.png", dpi=110)
    plt.close(fig)
    # Leave the log labelled with the configured filter.
    run_stage(LABEL, ws, base, log_id=log_id, overwrite=True)
    return rows


def fig4_truth(log_dir: Path, out: Path) -> str:
    """Fig. 4 from the scans projected with the true pose (the lasers' own error)."""
    frames = sorted(
        {str(f) for f in read_table(log_dir / "laser.parquet", "laser", columns=["frame_id"])
         .column("frame_id").to_pylist()}
    )  # fmt: skip
    mounts, _ = frame_mounts(log_dir / "tf_static.json", "base_link", frames)
    poses = PoseStream(log_dir / "truth_pose.parquet", "truth_pose")
    agreement = ScanAgreement()
    counts, previous = Counts(), {}
    first_ns: int | None = None
    for batch in iter_table_batches(
        log_dir / "laser.parquet", "laser", columns=LASER_COLUMNS, batch_rows=2000
    ):
        table = project_batch(ScanBatch.from_record_batch(batch), mounts, poses, previous, counts)
        if table.num_rows == 0:
            continue
        t0 = int(table.column("scan_t_ns")[0].as_py())
        first_ns = t0 if first_ns is None else first_ns
        if t0 - first_ns > 120e9:
            break
        agreement.feed(table)
    result = agreement.result()
    scratch = out / "truth_fig4"
    scratch.mkdir(exist_ok=True)
    for path in write_fig4(result, scratch, "truth pose"):
        shutil.move(str(path), out / path.name.replace("fig4_", "fig4_truth_"))
    scratch.rmdir()
    return result.fit.describe()


def positives(log_dir: Path, out: Path) -> Counter[str]:
    events = read_table(log_dir / "events.parquet", "events")
    rough = events.filter(events.column("rough"))
    kinds: Counter[str] = Counter()
    with (out / "positives.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["event_id", "speed_mph", "shock_g", "ruggedness", "feature", "height_m"])
        for row in rough.to_pylist():
            kind = row.get("truth_feature_kind") or "background"
            kinds[kind] += 1
            w.writerow(
                [row["event_id"], row["speed_mph"], row["shock_g"], row["ruggedness"], kind,
                 row.get("truth_feature_height_m")]
            )  # fmt: skip
    return kinds


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("log", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--calibration", type=Path, default=None, help="a calibration log for Fig. 5")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="sim_report_") as tmp:
        ws = Workspace(Path(tmp) / "ws")
        cfg = default_config()
        log_id = ingest_log(args.log, ws, cfg).log_id
        run_stage(POSE, ws, cfg, log_id=log_id)
        estimated = run_stage(PROJECT, ws, cfg, log_id=log_id)
        labelled = run_stage(LABEL, ws, cfg, log_id=log_id)
        log_dir = ws.log_dir(log_id)
        imu_spectrum(log_dir, args.out, cfg.label.fir_stop_hz, cfg.label.fir_pass_hz)
        rows = band_edge_rates(ws, log_id, args.out)
        truth_fit = fig4_truth(log_dir, args.out)
        for name in ("fig4_z_difference_vs_dt.png", "fig4_z_difference_vs_dt.csv",
                     "fig5_shock_speed.png", "fig5_shock_speed.csv"):  # fmt: skip
            if (log_dir / name).is_file():
                shutil.copy(log_dir / name, args.out / name)
        kinds = positives(log_dir, args.out)
        fig5 = labelled.fig5
        if args.calibration is not None:
            cal_id = ingest_log(args.calibration, ws, cfg).log_id
            run_stage(POSE, ws, cfg, log_id=cal_id)
            fig5 = run_stage(LABEL, ws, cfg, log_id=cal_id).fig5
            for name in ("fig5_shock_speed.png", "fig5_shock_speed.csv"):
                shutil.copy(ws.log_dir(cal_id) / name, args.out / name)
    summary = {
        "log": str(args.log),
        "events": labelled.events,
        "rough": labelled.rough,
        "rough_percent": round(100 * labelled.rough_rate, 4),
        "rough_percent_by_stop_edge_hz": {
            str(s): round(100.0 * r / max(n, 1), 4) for s, n, r in rows
        },
        "positives_by_feature": dict(kinds),
        "fig4_estimated_pose": estimated.fig4,
        "fig4_true_pose": truth_fit,
        "fig5": fig5,
        "calibration_log": str(args.calibration) if args.calibration else None,
    }
    (args.out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
