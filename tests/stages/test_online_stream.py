"""A workspace's tables as the drive online learning replays."""

from __future__ import annotations

import numpy as np
import pyarrow.compute as pc

from tests.stages.test_learn import Pipeline
from toolkit.config import default_config
from toolkit.stages.online_stream import drive_stream, label_delay_s, one_clock
from toolkit.tableio import read_table


def test_the_sample_drive_is_its_events_in_driven_order(pipeline: Pipeline) -> None:
    """Every event of both splits, by start time; each seen no later than its last point and
    no earlier than its first, and known the filter's delay after its end."""
    cfg = default_config()
    drive = drive_stream(pipeline.ws, cfg.model, cfg.label)
    s = drive.stream
    events = read_table(pipeline.ws.events_table, "tables_events")
    assert s.events == events.num_rows == s.patches.events
    assert set(drive.split.tolist()) == {"train", "test"}
    assert np.all(np.diff(s.t_start_ns) > 0) and np.all(np.diff(s.s_start_m) > 0)
    assert label_delay_s(cfg.label) == 0.195  # 40 taps at 100 Hz: 19.5 samples
    ends = events.column("t_end_ns").to_numpy()
    by_id = dict(zip(events.column("event_id").to_pylist(), ends.tolist(), strict=True))
    clock = s.t_start_ns[0] - events.column("t_start_ns").to_numpy().min()
    want = np.array([by_id[e] for e in drive.event_id.tolist()]) + clock + 195_000_000
    np.testing.assert_array_equal(s.t_known_ns, want)
    points = read_table(pipeline.ws.event_points_table, "event_points")
    for k in (0, s.events // 2, s.events - 1):
        mine = points.filter(pc.equal(points.column("event_id"), int(drive.event_id[k])))
        t = mine.column("t_ns").to_numpy() + clock
        assert t.min() <= s.t_seen_ns[k] <= t.max()


def test_logs_follow_one_another_on_one_clock_and_odometer() -> None:
    """Two logs whose own clocks overlap: the second starts 1 s after the first's last
    label, and its metres continue the first's."""
    log_id = np.array(["a", "a", "b", "b"], dtype=object)
    t_seen = np.array([100, 200, 50, 150], np.int64)
    t_known = np.array([300, 400, 250, 350], np.int64)
    s_start = np.array([0.0, 1.4, 0.0, 1.4])
    s_end = s_start + 1.4
    clock, metres = one_clock(log_id, t_seen, t_known, s_start, s_end)
    assert (t_seen + clock).tolist() == [0, 100, 1_000_000_300, 1_000_000_400]
    np.testing.assert_allclose(s_start + metres, [0.0, 1.4, 2.8, 4.2])
