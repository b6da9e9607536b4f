"""``terrain run``: the same outputs as the verbs one by one, nothing redone, kill -9 safe.

Two small logs: the bundled sample under two names (two logs to the toolkit: a log's id comes
from its name and content), so the per-log stages run them in parallel and tables splits
across them (the first log trains, the second tests). The workspaces take the default
configuration with a shorter search and bootstrap (:func:`quick_config`): what is tested here
is how the stages run, not what they learn, and the eight runs of these tests took 4 minutes
of the slow suite with the default's.
"""

from __future__ import annotations

import hashlib
import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import IO, Any

import pytest

from toolkit.errors import WorkspaceError
from toolkit.pipeline import stage_range
from toolkit.stages import registry

STAGES = registry.names()

SAMPLE_LOG = Path(__file__).resolve().parents[1] / "sample_logs" / "sample.mcap"
#: Manifest fields that differ between two runs of the same stage on the same input.
VOLATILE = {"timings_s", "finished_utc", "x_real_time", "seconds"}
SEED = 20261125
#: The line `terrain run` writes on stdout as each stage ends (with or without a prefix).
STAGE_LINE = re.compile(rf"(?<![\w-])({'|'.join(STAGES)}) +\d+\.\d s  ")
#: Longest wait for a stage's line or a run's end, s.
TIMEOUT_S = 600.0


def quick_config(directory: Path) -> Path:
    """The default configuration with 4 rotations of the search instead of 20 and 50
    bootstrap resamples instead of 1,000, written into ``directory``."""
    text = (Path(__file__).resolve().parents[1] / "toolkit" / "default_config.toml").read_text()
    quick = re.sub(r"^iterations = 20\b", "iterations = 4", text, count=1, flags=re.M)
    quick = re.sub(
        r"^bootstrap_resamples = 1000\b", "bootstrap_resamples = 50", quick, count=1, flags=re.M
    )
    assert quick.count("iterations = 4") == 1 and "bootstrap_resamples = 50" in quick
    path = directory / "quick.toml"
    path.write_text(quick)
    return path


def terrain(*args: str | Path, quiet: bool = True) -> list[str]:
    return [sys.executable, "-m", "toolkit", *(["-q"] if quiet else []), *map(str, args)]


class StageLines:
    """The stages a running `terrain run` (its stdout and stderr in one pipe, not quiet) has
    finished, in order, each with when its line came (s after ``t0``: `run` says a stage's
    line on stdout as it ends), read by a thread; ``text`` keeps the whole output for a
    failure's message."""

    def __init__(self, stream: IO[str], t0: float) -> None:
        self.t0 = t0
        self.ends: dict[str, float] = {}
        self.text: list[str] = []
        self.eof = False
        self._cond = threading.Condition()
        self._thread = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._thread.start()

    def _read(self, stream: IO[str]) -> None:
        for line in stream:
            now = time.perf_counter() - self.t0
            with self._cond:
                self.text.append(line)
                # search, not match: a pool worker's warning may share the line
                for m in STAGE_LINE.finditer(line):
                    self.ends.setdefault(m.group(1), now)
                self._cond.notify_all()
        with self._cond:
            self.eof = True
            self._cond.notify_all()

    def wait_for(self, stage: str) -> bool:
        """Wait until ``stage`` has finished (True) or the output closed without it (False)."""
        with self._cond:
            ok = self._cond.wait_for(lambda: stage in self.ends or self.eof, TIMEOUT_S)
            assert ok, f"no line for {stage} within {TIMEOUT_S} s"
            return stage in self.ends

    def finished(self) -> list[str]:
        """The stages finished so far, once the output is closed."""
        self._thread.join(TIMEOUT_S)
        with self._cond:
            return list(self.ends)


def start_run(logs: list[Path], ws: Path) -> tuple[subprocess.Popen[str], StageLines]:
    """`terrain run` of the logs in ``ws`` (two workers, the quick configuration beside
    them) in a session of its own, its stage lines read as they come."""
    t0 = time.perf_counter()
    config = logs[0].parent / "quick.toml"
    child = subprocess.Popen(
        terrain("run", *logs, "-w", ws, "-c", config, "--workers", "2", quiet=False),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    assert child.stdout is not None
    return child, StageLines(child.stdout, t0)


def _strip(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _strip(v) for k, v in obj.items() if k not in VOLATILE}
    if isinstance(obj, list):
        return [_strip(v) for v in obj]
    return obj


def state(ws: Path) -> dict[str, Any]:
    """Every visible file of the workspace by content (manifests without their timings;
    per-log directories through their public names)."""
    out: dict[str, Any] = {}
    files = []
    # Through the links (WS/logs/<id>, WS/report): os.walk follows them, Path.rglob does not.
    for root, dirs, names in os.walk(ws, followlinks=True):
        dirs[:] = [d for d in dirs if not d.startswith(".")]
        files += [Path(root, n) for n in names if not n.startswith(".")]
    for p in sorted(files):
        rel = p.relative_to(ws)
        if p.name == "manifest.json":
            out[str(rel)] = _strip(json.loads(p.read_text()))
        else:
            out[str(rel)] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def not_as_at_the_end(got: dict[str, Any], want: dict[str, Any]) -> list[str]:
    """What of a workspace's :func:`state` ``got`` is not as in the finished one's ``want``:
    a file not there or with other contents; a manifest's section (its ``stages``: each
    stage's record) the finished manifest does not hold the same."""
    out = []
    for path, have in got.items():
        end = want.get(path)
        if Path(path).name != "manifest.json" or end is None:
            if have != end:
                out.append(path)
            continue
        for key, value in have.items():
            if key == "stages":
                out += [f"{path}: {key}.{k}" for k, v in value.items() if end[key].get(k) != v]
            elif end.get(key) != value:
                out.append(f"{path}: {key}")
    return out


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    d = tmp_path_factory.mktemp("logs")
    out = [d / "run_a.mcap", d / "run_b.mcap"]
    for p in out:
        shutil.copyfile(SAMPLE_LOG, p)
    quick_config(d)  # beside the logs, where start_run finds it
    return out


@pytest.fixture(scope="module")
def first_run(
    logs: list[Path], tmp_path_factory: pytest.TempPathFactory
) -> tuple[Path, dict[str, float]]:
    """One `terrain run` to the end on the two logs: its workspace, and when each stage
    ended (s after the command started, from the line it writes then)."""
    ws = tmp_path_factory.mktemp("run") / "ws"
    child, lines = start_run(logs, ws)
    assert child.wait(TIMEOUT_S) == 0, "".join(lines.text)
    assert lines.finished() == list(STAGES), "".join(lines.text)
    return ws, lines.ends


@pytest.fixture(scope="module")
def uninterrupted(first_run: tuple[Path, dict[str, float]]) -> Path:
    """The workspace of one `terrain run` to the end on the two logs."""
    return first_run[0]


def test_the_stage_list_is_the_pipelines() -> None:
    assert [s.name for s in registry.stages()] == list(STAGES)  # each reads only earlier ones
    assert stage_range("pose", "label") == ("pose", "project", "label")
    with pytest.raises(WorkspaceError):
        stage_range("learn", "pose")


@pytest.mark.slow  # end to end: run by .ci/run, left out of the README's command
def test_run_equals_the_verbs_one_by_one(
    uninterrupted: Path, logs: list[Path], tmp_path: Path
) -> None:
    """The verbs ingest, pose, project, label, tables, learn, online, evaluate run by hand
    give the same files, byte for byte (manifests without their timings)."""
    ws = tmp_path / "ws"
    config = logs[0].parent / "quick.toml"
    subprocess.run(
        terrain("ingest", *logs, "-w", ws, "-c", config), check=True, capture_output=True
    )
    for verb in ("pose", "project", "label", "tables", "learn", "online", "evaluate"):
        subprocess.run(terrain(verb, "-w", ws), check=True, capture_output=True)
    got, want = state(ws), state(uninterrupted)
    assert got.keys() == want.keys()
    assert [k for k in want if got[k] != want[k]] == []
    assert any(k.startswith("report/") for k in want) and "model.json" in want


@pytest.mark.slow  # end to end: run by .ci/run, left out of the README's command
def test_a_second_run_does_nothing(uninterrupted: Path, logs: list[Path], tmp_path: Path) -> None:
    """Every stage reports up to date and no output changes (content or modification time;
    the manifests are rewritten, the lock file touched)."""
    ws = tmp_path / "ws"
    shutil.copytree(uninterrupted, ws, symlinks=True)

    def outputs() -> dict[Path, int]:
        return {
            p: p.stat().st_mtime_ns
            for p in ws.rglob("*")
            if p.is_file() and p.name not in ("manifest.json", ".lock")
        }

    before = outputs()
    out = subprocess.run(
        terrain("run", *logs, "-w", ws), check=True, capture_output=True, text=True
    )
    lines = [ln for ln in out.stdout.splitlines() if ln.split(" ")[0] in STAGES]
    assert len(lines) == len(STAGES)
    assert all(" up to date" in ln and " done" not in ln for ln in lines), lines
    assert outputs() == before
    assert "report: " in out.stdout


@pytest.mark.slow  # end to end: a whole run of two logs first (43 s); run by .ci/run
def test_from_and_to_run_only_their_stages(
    uninterrupted: Path, logs: list[Path], tmp_path: Path
) -> None:
    """--from learn --to learn --overwrite relearns (done) and touches nothing else."""
    ws = tmp_path / "ws"
    shutil.copytree(uninterrupted, ws, symlinks=True)
    before = state(ws)
    out = subprocess.run(
        terrain("run", *logs, "-w", ws, "--from", "learn", "--to", "learn", "--overwrite"),
        check=True,
        capture_output=True,
        text=True,
    )
    stages = [ln.split(" ")[0] for ln in out.stdout.splitlines() if ln.split(" ")[0] in STAGES]
    assert stages == ["learn"]
    assert state(ws) == before  # learning again gives the same model, and nothing else ran


@pytest.mark.slow  # end to end: run by .ci/run, left out of the README's command
def test_killed_in_every_stage_then_rerun_gives_the_same_outputs(
    first_run: tuple[Path, dict[str, float]], logs: list[Path], tmp_path: Path
) -> None:
    """SIGKILL once in each stage, ingest to evaluate, in one workspace: `terrain run` is
    started, killed (its process group, the workers too, as a machine failure) at a random
    moment (seeded) of the stage's span in the uninterrupted run, counted from the line of
    the stage before (from the start for ingest), and started again on what it left, to be
    killed in the next stage, and so on; a last run goes to the end. After each kill every
    file there is as the uninterrupted run made it (an output is there whole or not yet; a
    manifest holds only records the uninterrupted run's holds too); at the end the
    workspace equals the uninterrupted run's, file for file. Every run but the first starts
    on a killed run's workspace, as a rerun does, and one that ends before its kill must
    have succeeded."""
    rng = random.Random(SEED)
    uninterrupted, ends = first_run
    want = state(uninterrupted)
    ws = tmp_path / "ws"
    killed_in: list[str] = []
    for i, stage in enumerate(STAGES):
        begins = ends[STAGES[i - 1]] if i else 0.0
        delay = rng.uniform(0.1, 0.9) * (ends[stage] - begins)
        child, lines = start_run(logs, ws)
        if i and not lines.wait_for(STAGES[i - 1]):
            pytest.fail(f"the run ended before {STAGES[i - 1]}: {''.join(lines.text)}")
        since = time.perf_counter() - lines.t0 - (lines.ends[STAGES[i - 1]] if i else 0.0)
        try:
            rc = child.wait(max(0.0, delay - since))
        except subprocess.TimeoutExpired:
            os.killpg(child.pid, signal.SIGKILL)
            child.wait()
            done = lines.finished()
            killed_in.append(STAGES[len(done)] if len(done) < len(STAGES) else "(its summary)")
        else:
            assert rc == 0, "".join(lines.text)  # ended before the kill: it must have worked
            killed_in.append("(none: the run ended first)")
        assert not_as_at_the_end(state(ws), want) == [], stage
    subprocess.run(
        terrain("run", *logs, "-w", ws, "-c", logs[0].parent / "quick.toml", "--workers", "2"),
        check=True,
        capture_output=True,
    )
    got = state(ws)
    assert got.keys() == want.keys()
    assert [p for p in want if got[p] != want[p]] == []
    print(f"killed in: {', '.join(killed_in)}")


@pytest.mark.slow  # end to end: run by .ci/run, left out of the README's command
def test_a_new_configuration_reaches_every_stage_it_runs(
    uninterrupted: Path, logs: list[Path], tmp_path: Path
) -> None:
    """-c NEW --overwrite --from learn: learning uses NEW (its patch size is recorded in
    model.json), evaluate accepts that model, and NEW becomes the workspace's configuration."""
    ws = tmp_path / "ws"
    shutil.copytree(uninterrupted, ws, symlinks=True)
    new = tmp_path / "new.toml"
    text = (ws / "config.toml").read_text()
    assert "max_points_per_wheel = 40" in text
    new.write_text(text.replace("max_points_per_wheel = 40", "max_points_per_wheel = 30"))
    subprocess.run(
        terrain("run", *logs, "-w", ws, "-c", new, "--from", "learn", "--overwrite"),
        check=True,
        capture_output=True,
    )
    model = json.loads((ws / "model.json").read_text())
    assert model["training"]["max_points_per_wheel"] == 30
    assert "max_points_per_wheel = 30" in (ws / "config.toml").read_text()
    summary = json.loads((ws / "report" / "summary.json").read_text())
    assert summary["train_events"] == model["training"]["events"]


def test_the_ingest_row_counts_are_a_total_not_rows_of_rows() -> None:
    from toolkit.pipeline import StageReport, _record_totals

    rows, _, _ = _record_totals(
        [{"row_counts": {"imu": 5, "gps": 2}}, {"row_counts": {"imu": 1}}], "ingest"
    )
    assert rows == {"total": 8}
    line = StageReport("ingest", 1.0, {"done": 2}, rows, {}, ()).line()
    assert "rows: total 8" in line and "rows: rows" not in line


@pytest.mark.slow  # reads the whole run the slow tests here share (72 s on its own)
def test_run_json_is_the_summary_a_script_reads(
    uninterrupted: Path, logs: list[Path], tmp_path: Path
) -> None:
    ws = tmp_path / "ws"
    shutil.copytree(uninterrupted, ws, symlinks=True)
    proc = subprocess.run(
        terrain("run", *logs, "-w", ws, "--json"), check=True, capture_output=True, text=True
    )
    doc = json.loads(proc.stdout)
    assert doc["ok"] is True and len(doc["log_ids"]) == 2
    assert [s["stage"] for s in doc["stages"]] == list(STAGES)
    assert all(s["statuses"].get("failed", 0) == 0 and not s["failures"] for s in doc["stages"])
    assert doc["report"].endswith("index.html")
