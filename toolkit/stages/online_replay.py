"""The online stage's replay of its drives, with the checkpoint a stopped run resumes from.

:func:`replay_drives` runs :func:`toolkit.model.online.replay` over each drive in pieces of
``[online] checkpoint_every`` updates; after each piece :class:`ReplayLog` saves what is done
(every event met so far, every update with its B and mu, the learner of the drive under way
with its buffer as indices) to ``online/.checkpoint.npz``, written aside and renamed. A run
finding a checkpoint with its own key starts where it stopped: the buffer's patches are
taken again from the stream by those indices, so the state is the one saved, and the replay
goes on as if it had never stopped.
"""

from __future__ import annotations

import dataclasses
import io
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from toolkit.arrays import FloatArray, IntArray
from toolkit.atomic import atomic_write_bytes
from toolkit.config import OnlineLearnConfig
from toolkit.model.online import (
    Buffer,
    LearnerState,
    OnlineConfig,
    Reference,
    Stream,
    event_groups,
    replay,
    step_ends,
)
from toolkit.model.roughness import RoughnessParams

#: The integer columns of an update's row, in the order :class:`Replay` keeps them.
STEP_INTS = ("drive", "step", "version", "buffer_rough", "buffer_smooth", "steps_kept")


@dataclass(frozen=True)
class Drive:
    """A drive replayed from the start: its events' rows in the stream (in driven order)
    and the distance its first event began at (its distances count from there)."""

    rows: IntArray
    s0_m: float

    def stream(self, stream: Stream) -> Stream:
        """The drive's part of ``stream`` (its patches read as the replay asks), its
        distances from its start."""
        sub = stream.part(self.rows)
        return dataclasses.replace(sub, s_start_m=sub.s_start_m - self.s0_m)


@dataclass
class Replay:
    """What the replay has done so far: per event of the stream (E,) its score, standing,
    verdict and version when met; per update a row of :data:`STEP_INTS`, where it ended
    (m, ns), and B and mu after it;
    each finished drive's buffer (its events' rows in the stream); the drive under way and
    its learner."""

    r_combined: FloatArray
    standing: FloatArray
    predicted: np.ndarray
    version: IntArray
    steps: list[tuple[int, ...]] = field(default_factory=list)
    step_end: list[tuple[float, int]] = field(default_factory=list)
    b: list[tuple[float, ...]] = field(default_factory=list)
    mu: list[float] = field(default_factory=list)
    buffers: list[IntArray] = field(default_factory=list)
    drive: int = 0
    state: LearnerState | None = None
    update_s: list[float] = field(default_factory=list)
    refit_s: list[float] = field(default_factory=list)
    driven_s: float = 0.0
    resumed_at: str | None = None

    @classmethod
    def empty(cls, events: int) -> Replay:
        return cls(
            np.full(events, np.nan),
            np.full(events, np.nan),
            np.zeros(events, bool),
            np.full(events, -1, np.int64),
        )

    def model_after(self, drive: int, steps: int | None, first: LearnerState) -> RoughnessParams:
        """Drive ``drive``'s model after ``steps`` updates (None: at its end; fewer updates
        than that: at its end), or the start before any."""
        mine = [k for k, row in enumerate(self.steps) if row[0] == drive]
        if steps is not None:
            mine = mine[:steps]
        if not mine:
            return first.params
        return RoughnessParams.from_vector(self.b[mine[-1]], self.mu[mine[-1]])

    def step_end_ns(self, drive: int, steps: int | None) -> int:
        """When drive ``drive``'s model after ``steps`` updates (None: its last) stood:
        the end of that update (of its last, with fewer), or before the drive without any."""
        mine = [k for k, row in enumerate(self.steps) if row[0] == drive]
        if steps is not None:
            mine = mine[:steps]
        return self.step_end[mine[-1]][1] if mine else int(np.iinfo(np.int64).min)

    def steps_table(self) -> pa.Table:
        """``online/steps.parquet`` (schema ``online_steps``)."""
        ints = np.asarray(self.steps, np.int64).reshape(-1, len(STEP_INTS))
        col = {name: ints[:, j] for j, name in enumerate(STEP_INTS)}
        cols: dict[str, Any] = {
            "drive": col["drive"],
            "step": col["step"],
            "end_m": np.asarray([e[0] for e in self.step_end], np.float64),
            "end_ns": np.asarray([e[1] for e in self.step_end], np.int64),
            **{n: col[n] for n in STEP_INTS[2:]},
        }
        cols["b"] = pa.array([list(b) for b in self.b], pa.list_(pa.float64()))
        cols["mu"] = np.asarray(self.mu, np.float64)
        return pa.table(cols)

    def state_doc(self, log_id: np.ndarray, event_id: np.ndarray) -> dict[str, Any]:
        """``online/state.json``: each drive's learner at its end (B, mu, its version) and
        its buffer as (log, event) pairs, oldest first."""
        out = []
        for d, rows in enumerate(self.buffers):
            mine = [k for k, row in enumerate(self.steps) if row[0] == d]
            last = mine[-1] if mine else None
            mu = self.mu[last] if last is not None else None
            out.append(
                {
                    "drive": d,
                    "b": list(self.b[last]) if last is not None else None,
                    "mu": mu if mu is not None and np.isfinite(mu) else None,
                    "version": int(self.steps[last][2]) if last is not None else 0,
                    "buffer": [[str(log_id[i]), int(event_id[i])] for i in rows],
                }
            )
        return {"drives": out}


class ReplayLog:
    """The checkpoint file of a replay, keyed by what it was made from."""

    def __init__(self, path: Path, key: str, online: OnlineLearnConfig) -> None:
        self.path, self.key, self.every = path, key, online.checkpoint_every

    def save(self, done: Replay) -> None:
        """Write what ``done`` holds, aside then renamed."""
        state = done.state
        arrays: dict[str, Any] = {
            "key": np.asarray(self.key),
            "saved_at": np.asarray(time.strftime("%Y-%m-%d %H:%M:%S")),
            "r_combined": done.r_combined,
            "standing": done.standing,
            "predicted": done.predicted,
            "version": done.version,
            "steps": np.asarray(done.steps, np.int64).reshape(-1, len(STEP_INTS)),
            "end_m": np.asarray([e[0] for e in done.step_end], np.float64),
            "end_ns": np.asarray([e[1] for e in done.step_end], np.int64),
            "b": np.asarray(done.b, np.float64).reshape(len(done.b), -1),
            "mu": np.asarray(done.mu, np.float64),
            "buffer_drive": np.concatenate(
                [np.full(b.size, d, np.int64) for d, b in enumerate(done.buffers)]
                + [np.zeros(0, np.int64)]
            ),
            "buffer_rows": np.concatenate([*done.buffers, np.zeros(0, np.int64)]),
            "drive": np.asarray(done.drive),
        }
        if state is not None:
            arrays |= {
                "s_b": np.asarray(state.b),
                "s_mu": np.asarray(state.mu),
                "s_increments": np.asarray(state.increments),
                "s_ints": np.asarray([state.cursor, state.version, state.step], np.int64),
                "s_buffer": state.buffer.index,
                "s_b_sum": np.asarray(state.b_sum, np.float64),
                "s_scoring": np.asarray(state.scoring, np.float64),
                "s_origin": np.asarray(state.origin, np.float64),
                "s_origin_increments": np.asarray(state.origin_increments, np.float64),
                "s_pending": np.asarray(state.pending, np.float64),
                "s_pending_ready_ns": np.asarray(state.pending_ready_ns, np.int64),
                "s_reference": state.reference.index,
                "s_reference_known": np.asarray(state.reference.known, np.int64),
            }
        out = io.BytesIO()
        np.savez(out, **arrays)
        atomic_write_bytes(self.path, out.getvalue())

    def load(self, stream: Stream, drives: list[Drive]) -> Replay | None:
        """The replay saved, when there is a checkpoint of this key (None otherwise)."""
        if not self.path.is_file():
            return None
        try:
            with np.load(self.path, allow_pickle=False) as f:
                got = {k: f[k] for k in f.files}
        except (OSError, ValueError, KeyError):
            return None  # unreadable: replayed from the start, as if none
        if str(got["key"]) != self.key:
            return None
        done = Replay(got["r_combined"], got["standing"], got["predicted"], got["version"])
        done.steps = [tuple(r) for r in got["steps"].tolist()]
        done.step_end = list(zip(got["end_m"].tolist(), got["end_ns"].tolist(), strict=True))
        done.b = [tuple(r) for r in got["b"].tolist()]
        done.mu = got["mu"].tolist()
        done.drive = int(got["drive"])
        done.buffers = [got["buffer_rows"][got["buffer_drive"] == d] for d in range(done.drive)]
        done.resumed_at = str(got["saved_at"])
        if "s_b" in got:
            sub = drives[done.drive].stream(stream)
            index = got["s_buffer"].astype(np.int64)
            buffer = (
                Buffer.of(sub.patches.take(event_groups(index)), sub.rough[index], index)
                if index.size
                else Buffer()
            )
            ref_index = got["s_reference"].astype(np.int64)
            reference = Reference.of(
                sub.patches.take(event_groups(ref_index)),
                ref_index,
                int(got["s_reference_known"]),
            )
            cursor, version, step = (int(v) for v in got["s_ints"])
            done.state = LearnerState(
                tuple(got["s_b"].tolist()),
                float(got["s_mu"]),
                tuple(got["s_increments"].tolist()),
                cursor,
                version,
                step,
                buffer,
                tuple(got["s_b_sum"].tolist()),
                tuple(got["s_scoring"].tolist()),
                tuple(got["s_origin"].tolist()),
                tuple(got["s_origin_increments"].tolist()),
                tuple(got["s_pending"].tolist()),
                int(got["s_pending_ready_ns"]),
                reference,
            )
        return done

    def remove(self) -> None:
        self.path.unlink(missing_ok=True)


def replay_drives(
    stream: Stream,
    drives: list[Drive],
    first: LearnerState,
    config: OnlineConfig,
    log: ReplayLog,
    step: Callable[[], None],
) -> Replay:
    """Test-then-train over every drive from ``first``, resumed from ``log``'s checkpoint
    when it has one of its key, saved to it every ``log.every`` updates."""
    done = log.load(stream, drives) or Replay.empty(stream.events)
    for d in range(done.drive, len(drives)):
        sub = drives[d].stream(stream)
        state = done.state if done.state is not None else first
        total = step_ends(sub, config)[0].size
        while state.step < total:
            state = _piece(sub, drives[d], d, state, config, log.every, done, step)
            done.drive, done.state = d, state
            if state.step < total:
                log.save(done)
        done.buffers.append(drives[d].rows[state.buffer.index])
        done.drive, done.state = d + 1, None
        done.driven_s += (sub.t_known_ns.max() - sub.t_start_ns.min()) / 1e9
        if d + 1 < len(drives):
            log.save(done)
    return done


def _piece(
    sub: Stream,
    drive: Drive,
    d: int,
    state: LearnerState,
    config: OnlineConfig,
    every: int,
    done: Replay,
    step: Callable[[], None],
) -> LearnerState:
    """Up to ``every`` updates of drive ``d`` from ``state``, recorded in ``done``."""
    models: list[tuple[tuple[float, ...], float]] = []

    def after(s: LearnerState) -> None:
        models.append((s.b, s.mu))
        step()

    state, got = replay(sub, state, config, stop_after=every, progress=after)
    met = got.version >= 0
    rows = drive.rows[met]
    done.r_combined[rows] = got.r_combined[met]
    done.standing[rows] = got.standing[met]
    done.predicted[rows] = got.predicted[met]
    done.version[rows] = got.version[met]
    first_step = state.step - got.step_version.size
    for k in range(got.step_version.size):
        done.steps.append(
            (
                d,
                first_step + k,
                int(got.step_version[k]),
                int(got.buffer_rough[k]),
                int(got.buffer_smooth[k]),
                int(got.steps_kept[k]),
            )
        )
        done.step_end.append((float(got.step_end_m[k]), int(got.step_end_ns[k])))
        done.b.append(models[k][0])
        done.mu.append(models[k][1])
    done.update_s.extend(got.update_s.tolist())
    done.refit_s.extend(got.refit_s[got.refit_s > 0].tolist())
    return state


__all__ = ["Drive", "Replay", "ReplayLog", "STEP_INTS", "replay_drives"]
