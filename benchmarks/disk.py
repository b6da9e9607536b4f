"""Benchmark: what a workspace costs on disk (``benchmarks/README.md``, "Disk").

    python benchmarks/disk.py WS LOG.mcap [LOG.mcap ...]

Prints the workspace's size against its logs' (the ratio the README states), the largest
files, the point cloud's bytes a point (each column's share, from the Parquet footer) and the
size per hour of log (the pose's time span).
"""

from __future__ import annotations

import sys
from collections import Counter
from pathlib import Path

import pyarrow.parquet as pq

from toolkit.tableio import read_table
from toolkit.workspace import Workspace


def _size(root: Path) -> int:
    """Bytes of every file under ``root`` (hard links counted once)."""
    seen: set[int] = set()
    total = 0
    for path in root.rglob("*"):
        if path.is_file() and not path.is_symlink():
            st = path.stat()
            if st.st_ino not in seen:
                seen.add(st.st_ino)
                total += st.st_size
    return total


def main(ws_root: str, logs: list[str]) -> None:
    ws = Workspace(Path(ws_root))
    log_bytes = sum(Path(p).stat().st_size for p in logs)
    ws_bytes = _size(ws.root)
    print(
        f"logs {log_bytes / 1e9:.3f} GB; workspace {ws_bytes / 1e9:.3f} GB "
        f"({ws_bytes / log_bytes:.2f}x the logs)"
    )
    hours = 0.0
    points = 0
    by_column: Counter[str] = Counter()
    for log_id in ws.log_ids():
        t = read_table(ws.log_table(log_id, "pose"), "pose", columns=["t_ns"])["t_ns"].to_numpy()
        hours += (int(t[-1]) - int(t[0])) * 1e-9 / 3600.0
        meta = pq.ParquetFile(ws.log_table(log_id, "points")).metadata
        points += meta.num_rows
        for i in range(meta.num_row_groups):
            group = meta.row_group(i)
            for j in range(group.num_columns):
                column = group.column(j)
                by_column[column.path_in_schema] += column.total_compressed_size
    cloud = sum(by_column.values())
    print(
        f"{hours * 60:.1f} minutes of log: {ws_bytes / 1e9 / hours:.2f} GB an hour "
        f"({log_bytes / 1e9 / hours:.2f} GB an hour of log)"
    )
    print(
        f"points.parquet: {points} points, {cloud / 1e9:.3f} GB, "
        f"{cloud / max(points, 1):.2f} bytes a point (data pages)"
    )
    for name, size in by_column.most_common():
        print(f"  {name:12s} {size / max(points, 1):6.2f} bytes a point")
    files = sorted((p.stat().st_size, p) for p in ws.root.rglob("*.parquet") if p.is_file())[-6:]
    for size, path in files:
        print(f"  {size / 1e9:7.3f} GB  {path.relative_to(ws.root)}")


if __name__ == "__main__":
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2:])
