"""The secure-stage tests' stream generator (tests/support/secure_streams.py) makes real MAVLink."""

from __future__ import annotations

import math

from mavframe import codec
from tests.support.secure_streams import StreamMaker, packet_of


def test_stream_frames_decode_to_what_was_made() -> None:
    """The generator's frames are real MAVLink: codec decodes them to the fields they carry."""
    from secuav_common.scenario import load_scenario

    maker = StreamMaker(load_scenario("anchors8"), seed=3)
    seen: set[int] = set()
    for fr in maker.frames(2.0):
        pkt = packet_of(fr.raw, fr.t_s)
        fields = codec.decode(pkt)
        seen.add(pkt.header.msgid)
        for name, value in fr.attacked.items():
            if isinstance(value, float):
                assert math.isclose(fields[name], value, rel_tol=1e-6, abs_tol=1e-6)
            elif not isinstance(value, list | tuple):
                assert fields[name] == value
    assert {32, 33, 132, 242} <= seen
