"""``secuav-attack status --watch`` marks a profile that changes frames toward the vehicle."""

from __future__ import annotations

import json
import time

from mitm_proxy.tools.board import Board
from mitm_proxy.tools.watch import Rates, table


def test_the_profile_cell_says_when_the_vehicle_is_lied_to() -> None:
    board = Board()
    for sysid, directions in ((1, ["downlink"]), (2, ["uplink"]), (3, ["downlink", "uplink"])):
        state = {"sysid": sysid, "profile": f"p{sysid}", "directions": directions, "ok": True}
        board.receive(f"secuav/v{sysid}/attack/state", json.dumps(state).encode())
    board.receive("secuav/v4/attack/state", json.dumps({"sysid": 4, "profile": "old", "ok": True}).encode())
    rows = {line.split()[0]: line for line in table(board, Rates(), time.monotonic())[1:]}
    assert " p1 " in rows["v1"] and "(to vehicle)" not in rows["v1"]
    assert " p2 (to vehicle) " in rows["v2"] and " p3 (both ways) " in rows["v3"]
    assert " old " in rows["v4"]  # an older proxy: no directions, shown as before
