"""Pools stop when the command stops: Ctrl-C and SIGTERM leave no worker running.

Each case runs a real process (the command line, or a small script) in a session of its
own, waits for its pool worker to be busy, signals it as a terminal or ``kill`` would, and
checks that the process ends within seconds and that no process it started lives on."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

#: Waiting for an end after a signal at most (a failing case is then stopped by SIGKILL).
STOP_WITHIN_S = 15.0
ROOT = Path(__file__).resolve().parents[1]


def _children(pid: int) -> list[int]:
    """Live processes whose parent is ``pid`` (from /proc; zombies are not alive)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        # pid (comm) state ppid ...: comm may hold spaces, so split after its ')'.
        state, ppid = stat.rsplit(")", 1)[1].split()[:2]
        if int(ppid) == pid and state != "Z":
            found.append(int(entry.name))
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _wait_for_workers(proc: subprocess.Popen[bytes], at_least: int = 1) -> list[int]:
    deadline = time.monotonic() + 60.0
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            pytest.fail(f"the process ended before its workers started ({proc.returncode})")
        workers = _children(proc.pid)
        if len(workers) >= at_least:
            time.sleep(1.0)  # let them get busy
            return _children(proc.pid)
        time.sleep(0.1)
    pytest.fail("no pool worker started within 60 s")


def _ends_and_leaves_nothing(proc: subprocess.Popen[bytes], workers: list[int]) -> int:
    start = time.monotonic()
    try:
        code = proc.wait(timeout=STOP_WITHIN_S)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        pytest.fail(f"still running {STOP_WITHIN_S} s after the signal")
    took = time.monotonic() - start
    time.sleep(0.5)  # an orphan would still be running now
    left = [pid for pid in workers if _alive(pid)]
    if left:
        for pid in left:
            os.kill(pid, signal.SIGKILL)
    assert not left, f"workers {left} outlived their parent"
    assert took < STOP_WITHIN_S
    return code


@pytest.fixture
def sim_command(tmp_path: Path) -> list[str]:
    """A long simulation whose laser casting runs in a pool worker (CPU-bound numpy)."""
    return [
        sys.executable,
        "-m",
        "toolkit",
        "sim",
        str(tmp_path / "long.mcap"),
        "--profile",
        "race",
        "--distance-m",
        "50000",
        "--workers",
        "1",
    ]


@pytest.mark.parametrize(
    ("how", "code"),
    [
        ("sigint_to_the_group", 128 + signal.SIGINT),
        ("sigterm_to_the_command", 128 + signal.SIGTERM),
    ],
    ids=["ctrl_c", "sigterm"],
)
def test_a_signal_ends_the_command_and_its_busy_worker(
    sim_command: list[str], tmp_path: Path, how: str, code: int | None
) -> None:
    proc = subprocess.Popen(
        sim_command,
        cwd=ROOT,
        start_new_session=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    workers = _wait_for_workers(proc)
    if how == "sigint_to_the_group":  # what Ctrl-C in a terminal does
        os.killpg(proc.pid, signal.SIGINT)
    else:
        os.kill(proc.pid, signal.SIGTERM)
    got = _ends_and_leaves_nothing(proc, workers)
    assert proc.stderr is not None
    err = proc.stderr.read().decode()
    assert "Traceback" not in err
    assert got == code
    # One line, the stop's, and nothing after it: no "leaked semaphore objects" from
    # multiprocessing's resource tracker (the pool's queues, tqdm's lock in a worker).
    (line,) = err.splitlines()
    assert line == f"terrain: error: stopped ({'Ctrl-C' if code == 130 else 'SIGTERM'})"
    # Nothing half-written is left where the log was to go.
    assert not (tmp_path / "long.mcap").exists()
    assert [p.name for p in tmp_path.iterdir()] == []


BUSY_SCRIPT = """
import multiprocessing, sys, numpy as np
from toolkit.pools import process_pool
from toolkit.stopping import stop_on_signals

def busy(n):
    x = np.random.default_rng(0).random(4_000_000)
    while True:  # CPU-bound numpy, as a stage's worker is
        x = np.sort(x)[::-1].copy()

if __name__ == "__main__":
    workers = []
    try:
        with stop_on_signals(), process_pool(2) as pool:
            futures = [pool.submit(busy, i) for i in range(4)]
            workers = multiprocessing.active_children()
            for f in futures:
                f.result()
    finally:  # how each worker ended: -15 its SIGTERM, -9 the SIGKILL after the grace
        for p in workers:
            p.join(10)
        print(sorted(str(p.exitcode) for p in workers), flush=True)
"""


@pytest.mark.parametrize("ctrl_c", [False, True], ids=["sigterm", "ctrl_c"])
def test_a_signal_to_a_pool_of_busy_workers_stops_them_all(tmp_path: Path, ctrl_c: bool) -> None:
    """Workers in an endless numpy loop (each call minutes long in a stage with an absurd
    size): ``ProcessPoolExecutor.shutdown`` alone would wait for them for ever."""
    script = tmp_path / "busy.py"
    script.write_text(BUSY_SCRIPT)
    proc = subprocess.Popen(
        [sys.executable, str(script)],
        cwd=ROOT,
        start_new_session=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
    )
    workers = _wait_for_workers(proc, at_least=2)
    if ctrl_c:
        os.killpg(proc.pid, signal.SIGINT)
        assert _ends_and_leaves_nothing(proc, workers) != 0
    else:
        os.kill(proc.pid, signal.SIGTERM)
        assert _ends_and_leaves_nothing(proc, workers) == 128 + signal.SIGTERM
    if not ctrl_c:
        # Forked workers (this pool's default) ended on their SIGTERM, where they were: none
        # kept the parent's handler and had to be killed after the grace (-9). (A status
        # may be None: a wait interrupted by the parent's own SIGTERM loses it, the worker
        # reaped all the same, as the check for orphans above shows.)
        assert proc.stdout is not None
        codes = proc.stdout.read().decode().split("\n")[-2]
        assert "-15" in codes and "-9" not in codes, codes


#: A command whose pool was stopped mid-task, with a thread that never ends standing in for
#: the pool's manager thread stuck on a result its killed worker half-wrote.
STUCK_AFTER_A_STOP = """
import sys, threading, time
from toolkit.pools import exit_without_waiting, process_pool

threading.Thread(target=threading.Event().wait, name="stuck").start()
try:
    with process_pool(1) as pool:
        pool.submit(time.sleep, 60)
        time.sleep(1.0)
        raise SystemExit(7)
except SystemExit as exc:
    print("unwound")  # not flushed by the script: exit_without_waiting must do it
    exit_without_waiting(exc.code)
    raise
"""


def test_a_command_that_stopped_a_pool_ends_without_waiting_on_its_threads() -> None:
    """The exit after an interrupt that ended a pool's workers mid-task must not wait on
    the pool's threads (it hung 1 run in 3 under load before ``exit_without_waiting``)."""
    proc = subprocess.run(
        [sys.executable, "-c", STUCK_AFTER_A_STOP],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=STOP_WITHIN_S + 15,
    )
    assert proc.returncode == 7, proc.stderr
    assert proc.stdout == "unwound\n"
    assert "Traceback" not in proc.stderr


def _ctrl_c_in_run(tmp_path: Path, after: str, wait_s: float) -> subprocess.Popen[str]:
    """``terrain run`` on the sample, Ctrl-C to its session ``wait_s`` after stage ``after``
    said its line: checked to end with exit 130, the stop's line last, no traceback and no
    "leaked semaphore objects" warning; the ended process, for more checks."""
    from tests.conftest import SAMPLE_LOG

    proc = subprocess.Popen(
        [sys.executable, "-m", "toolkit", "run", str(SAMPLE_LOG), "-w", str(tmp_path / "ws")],
        cwd=ROOT,
        start_new_session=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None and proc.stderr is not None
    for line in proc.stdout:  # each stage's line as it ends
        if line.startswith(f"{after} "):
            break
    time.sleep(wait_s)
    os.killpg(proc.pid, signal.SIGINT)
    code = proc.wait(timeout=STOP_WITHIN_S)
    err = proc.stderr.read()
    assert code == 128 + signal.SIGINT, err
    assert "leaked" not in err and "Traceback" not in err and "Warning" not in err, err
    assert err.splitlines()[-1] == "terrain: error: stopped (Ctrl-C)"
    return proc


def test_ctrl_c_while_a_runs_workers_are_busy_says_one_line_and_leaks_nothing(
    tmp_path: Path,
) -> None:
    """``terrain run`` stopped by Ctrl-C while project's spawned workers work: exit 130,
    the stop's line last, no traceback and no "leaked semaphore objects" warning from
    multiprocessing's resource tracker (its queues' semaphores, and tqdm's lock, which a
    worker's first bar makes and a terminated worker never unlinks)."""
    _ctrl_c_in_run(tmp_path, after="ingest", wait_s=3.0)  # project's workers at work


@pytest.mark.slow  # a run to learn first (~20 s); run by .ci/run
def test_ctrl_c_while_evaluate_trains_its_rows_stops_every_forked_worker(
    tmp_path: Path,
) -> None:
    """``terrain run`` stopped by Ctrl-C while evaluate trains its rows in forked workers:
    exit 130, the stop's line last, no traceback or leak warning, and no process of the
    command left behind."""
    # Past scoring the learned model: the rows' workers at work.
    proc = _ctrl_c_in_run(tmp_path, after="learn", wait_s=4.0)
    # Nothing of the command's session is left (multiprocessing's resource tracker ends
    # once the command has; init reaps it).
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline:
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.1)
    with pytest.raises(ProcessLookupError):
        os.killpg(proc.pid, 0)
    assert not (tmp_path / "ws" / "report").exists()
