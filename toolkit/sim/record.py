"""The simulator's record in the metadata of the logs it writes, and the origin it holds.

``terrain sim`` adds an MCAP metadata record named :data:`SIM_RECORD` (profile, seed, the
world's parameters and its frame's geodetic origin): the stages that compare with the truth
rebuild the simulated world from it, and find its frame through :func:`sim_origin`.
"""

from __future__ import annotations

import json
from collections.abc import Mapping

from toolkit.geodesy import GeodeticOrigin

#: The metadata record and key holding the simulator's world-frame origin.
SIM_RECORD = "terrain_sim"
SIM_ORIGIN_KEY = "origin"


def sim_origin(mcap_metadata: Mapping[str, Mapping[str, str]]) -> GeodeticOrigin | None:
    """The simulator's world-frame origin from the log's metadata records (None if absent
    or unreadable: not a simulated log)."""
    text = mcap_metadata.get(SIM_RECORD, {}).get(SIM_ORIGIN_KEY)
    if text is None:
        return None
    try:
        o = json.loads(text)
        return GeodeticOrigin(
            float(o["latitude_deg"]), float(o["longitude_deg"]), float(o["altitude_m"])
        )
    except (ValueError, KeyError, TypeError):
        return None


__all__ = ["SIM_ORIGIN_KEY", "SIM_RECORD", "sim_origin"]
