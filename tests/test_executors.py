"""Tests of the executors: what make_executor refuses, a missing or unreachable Dask, and
pool workers that never outlive the process that started them."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import pytest

from toolkit.errors import ConfigError
from toolkit.executors import make_executor


def test_make_executor_rejects_bad_settings() -> None:
    with pytest.raises(ConfigError, match="'local', 'dask'"), make_executor("slurm"):
        pass
    with pytest.raises(ConfigError, match="--scheduler"), make_executor("dask"):
        pass
    with pytest.raises(ConfigError, match="-1"), make_executor("local", workers=-1):
        pass
    with (
        pytest.raises(ConfigError, match="dask executor only"),
        make_executor("local", scheduler="tcp://x:1"),
    ):
        pass


def test_missing_distributed_package_says_how_to_install(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "distributed", None)  # makes 'import distributed' fail
    with pytest.raises(ConfigError) as err, make_executor("dask", scheduler="tcp://127.0.0.1:1"):
        pass
    message = str(err.value)
    assert "\n" not in message
    assert "pip install 'terrain[distributed]'" in message


def test_unreachable_scheduler_is_a_config_error() -> None:
    import dask
    import distributed  # noqa: F401 - the [distributed] extra, installed for the tests

    with (
        dask.config.set({"distributed.comm.timeouts.connect": "2s"}),
        pytest.raises(ConfigError, match="cannot connect to the Dask scheduler at tcp://127"),
        make_executor("dask", scheduler="tcp://127.0.0.1:9"),
    ):
        pass


def _alive(pid: int) -> bool:
    """Whether a process runs (a zombie waiting for its reaper has exited)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:
        return False
    return "\nState:\tZ" not in status


def test_pool_workers_exit_when_their_parent_is_killed(tmp_path: Path) -> None:
    """kill -9 of the ingest parent must not leave its pool workers running."""
    import signal
    import subprocess

    script = (
        "import multiprocessing, time\n"
        "from toolkit.executors import make_executor\n"
        "with make_executor('local', workers=1) as pool:\n"
        "    future = pool.submit(time.sleep, 120)\n"
        "    time.sleep(2)\n"
        "    print(*[p.pid for p in multiprocessing.active_children()], flush=True)\n"
        "    future.result()\n"
    )
    parent = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE)
    try:
        assert parent.stdout is not None
        children = [int(pid) for pid in parent.stdout.readline().split()]
        assert children and all(_alive(pid) for pid in children)
        parent.send_signal(signal.SIGKILL)
        parent.wait(timeout=30)
        deadline = time.monotonic() + 15
        while any(_alive(pid) for pid in children) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not any(_alive(pid) for pid in children)
    finally:
        if parent.poll() is None:
            parent.kill()
