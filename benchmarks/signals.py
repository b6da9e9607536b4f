"""Benchmark: the first Ctrl-C or SIGTERM stops every verb, whenever it lands (issue "Truth
far from home", point 4).

Prepares a workspace from the sample log (``terrain run``), times each verb once, then runs
it ``--moments`` times more, sending the signal at a moment drawn uniformly over that time
(start-up and imports included), and checks each run: the shell's code (130 Ctrl-C, 143
SIGTERM, or 0 if the run ended before the signal), exactly one ``stopped (...)`` line, no
traceback. Prints a line per verb and signal. Usage::

    python benchmarks/signals.py [--moments 50] [--signals TERM INT] [--verbs pose project ...]
"""

from __future__ import annotations

import argparse
import json
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: Before this, a signal may land in the interpreter's own start-up (site.py), where no code
#: of the toolkit has run yet; measured at 0.017-0.043 s.
STARTUP_S = 0.1
REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "sample_logs" / "sample.mcap"


def terrain(*args: str) -> list[str]:
    return [sys.executable, "-m", "toolkit", *args]


def verbs(ws: Path, tmp: Path) -> dict[str, list[str]]:
    """Each verb's command line on the prepared workspace (each redoes its work)."""
    # The log's link; its generations beside it are hidden folders.
    (log_id,) = [p.name for p in (ws / "logs").iterdir() if not p.name.startswith(".")]
    return {
        "ingest": terrain("ingest", str(SAMPLE), "-w", str(ws), "--overwrite"),
        "pose": terrain("pose", "-w", str(ws), "--overwrite"),
        "project": terrain("project", "-w", str(ws), "--overwrite"),
        "label": terrain("label", "-w", str(ws), "--overwrite"),
        "tables": terrain("tables", "-w", str(ws), "--overwrite"),
        "learn": terrain("learn", "-w", str(ws), "--overwrite"),
        "evaluate": terrain("evaluate", "-w", str(ws), "--overwrite"),
        "run": terrain("run", str(SAMPLE), "-w", str(tmp / "run-ws")),
        "info": terrain("info", str(SAMPLE)),
        "logs": terrain("logs", "-w", str(ws)),
        "export": terrain("export", "-w", str(ws), "--out", str(tmp / "export"), "--overwrite"),
        "viz": terrain(
            "viz", "-w", str(ws), "--log", log_id, "--out", str(tmp / "viz.mcap"), "--overwrite"
        ),
        "sim": terrain(
            "sim",
            str(tmp / "sim.mcap"),
            "--profile",
            "sample",
            "--distance-m",
            "300",
            "--overwrite",
        ),
    }


def one(
    cmd: list[str], delay_s: float | None, signum: int, cleanup: Path | None
) -> tuple[int, str]:
    if cleanup is not None:
        shutil.rmtree(cleanup, ignore_errors=True)
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if delay_s is not None:
        time.sleep(delay_s)
        proc.send_signal(signum)
    try:
        _, err = proc.communicate(timeout=600)
    except subprocess.TimeoutExpired:
        proc.kill()
        return -999, "timed out"
    return proc.returncode, err


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--moments", type=int, default=50)
    parser.add_argument("--signals", nargs="+", default=["TERM", "INT"])
    parser.add_argument("--verbs", nargs="+", default=None)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        ws = tmp / "ws"
        subprocess.run(terrain("-q", "run", str(SAMPLE), "-w", str(ws)), check=True)
        table = verbs(ws, tmp)
        for name in args.verbs or list(table):
            cmd = table[name]
            cleanup = tmp / "run-ws" if name == "run" else None
            t0 = time.perf_counter()
            code, err = one(cmd, None, 0, cleanup)
            full_s = time.perf_counter() - t0
            if code != 0:
                raise SystemExit(f"{name}: exit {code} without a signal: {err[-500:]}")
            for sig in args.signals:
                signum = getattr(signal, f"SIG{sig}")
                stopped, finished, startup, bad = 0, 0, 0, []
                for _ in range(args.moments):
                    delay = rng.uniform(0.0, full_s)
                    code, err = one(cmd, delay, signum, cleanup)
                    lines = err.count("terrain: error: stopped (")
                    if code == 128 + signum and lines == 1 and "Traceback" not in err:
                        stopped += 1
                    elif code == 0 and lines == 0:
                        finished += 1  # it ended before the signal landed
                    elif code == -signum and not err and delay < STARTUP_S:
                        # Killed by the signal's default action before the interpreter ran
                        # a line of the toolkit (site.py's start-up): stopped, no line.
                        startup += 1
                    else:
                        bad.append({"at_s": round(delay, 3), "code": code, "err": err[-300:]})
                print(
                    json.dumps(
                        {
                            "verb": name,
                            "signal": sig,
                            "run_s": round(full_s, 2),
                            "stopped": stopped,
                            "finished_first": finished,
                            "killed_in_startup": startup,
                            "wrong": len(bad),
                            "examples": bad[:3],
                        }
                    ),
                    flush=True,
                )


if __name__ == "__main__":
    main()
