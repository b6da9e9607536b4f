"""Exact duplicates among one topic's messages: same log time and the same payload bytes.

A recorder that writes a chunk twice, or a bag merged with an overlapping copy of itself,
repeats messages byte for byte. They must be dropped (and counted), never written twice; a
message that merely shares its log time with another but differs in content is kept.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: Exact duplicates are looked for among messages of the same topic this close in log time.
DUPLICATE_WINDOW_NS = 2_000_000_000


class DuplicateFilter:
    """Finds exact duplicates of one topic: same log time and same payload bytes.

    Only messages sharing a log time with another are compared byte for byte, so the common
    case costs one sort of the batch's times. Messages of the last ``window_ns`` of log time
    are remembered across batches (a repeated chunk lands in another batch).
    """

    def __init__(self, window_ns: int = DUPLICATE_WINDOW_NS) -> None:
        self.window_ns = window_ns
        self._times = np.zeros(0, dtype=np.int64)
        self._payloads: list[bytes] = []

    def check(self, log_time_ns: np.ndarray, payloads: Sequence[bytes]) -> np.ndarray:
        """Boolean mask of the batch's messages that duplicate an earlier one."""
        times = np.asarray(log_time_ns, dtype=np.int64)
        n_old = len(self._times)
        all_t = np.concatenate([self._times, times])
        dup = np.zeros(len(times), dtype=bool)
        order = np.argsort(all_t, kind="stable")
        sorted_t = all_t[order]
        same = sorted_t[1:] == sorted_t[:-1]
        if same.any():
            flag = np.zeros(len(all_t), dtype=bool)
            flag[order[1:][same]] = True
            flag[order[:-1][same]] = True
            seen: set[tuple[int, bytes]] = set()
            # Rare: only messages sharing a log time with another are compared.
            for i in np.flatnonzero(flag).tolist():
                data = self._payloads[i] if i < n_old else bytes(payloads[i - n_old])
                key = (int(all_t[i]), data)
                if key in seen:
                    if i >= n_old:
                        dup[i - n_old] = True
                else:
                    seen.add(key)
        if len(all_t):
            keep_from = int(all_t.max()) - self.window_ns
            keep_old = np.flatnonzero(self._times >= keep_from)
            keep_new = np.flatnonzero((times >= keep_from) & ~dup)
            self._times = np.concatenate([self._times[keep_old], times[keep_new]])
            self._payloads = [self._payloads[i] for i in keep_old.tolist()] + [
                payloads[i] for i in keep_new.tolist()
            ]
        return dup
