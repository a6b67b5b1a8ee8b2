"""Record what a link received and what it forwarded, as .tlog files plus an index.

``DIR/original.tlog`` holds every valid frame as it arrived, ``DIR/forwarded.tlog``
every frame as it left (both directions, interleaved in time), in the .tlog
format of :mod:`mavframe.tlog` that pymavlink's ``mavlogdump.py`` and MAVExplorer read.
A delayed frame is stamped with the time it is due to leave.

``DIR/index.json`` is a JSON array, one object per frame a stage changed,
injected, delayed or dropped: ``{"index": n, "original": k, "msgid": m,
"direction": "downlink"|"uplink", "changed": bool, "injected": bool,
"dropped": bool, "delay_s": d, "notes": [...]}``. ``index`` counts frames in
forwarded.tlog from 0 (``null`` for a dropped frame), ``original`` counts frames
in original.tlog (``null`` for an injected one), and ``notes`` name the rules
that acted (``attack:<profile>:rules[<i>]``). ``DIR/profiles.json`` is a JSON array,
one object per attack profile installed or cleared on the link while recording
(the one in force at the start first): ``{"t": epoch s, "original": k,
"profile": name|null, "hash": h|null, "directions": ["downlink", "uplink"]}``, where
``original`` is the number of frames original.tlog held then (the profile acts from
that frame on) and ``directions`` says which way it changes frames (downlink:
toward the ground, uplink: toward the vehicle). Both are written as frames go
(memory stays flat on long runs) and closed by :meth:`Recorder.close`; all
files are flushed at least every second.

Recording never changes what is forwarded: the pipeline only hands bytes to a
bounded queue, and one writer thread does the disk work (a slow disk would
otherwise stall the event loop; a full one raised into the pipeline, and the
link then forwarded frames raw, past the attack and secure stages). When the
queue is full the recording loses that chunk (counted in ``lost_chunks``);
when a write fails the recording stops with one error line and forwarding goes on.
"""

from __future__ import annotations

import json
import logging
import queue
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import IO

from mavframe import tlog
from mavframe.packet import Direction, Header, Packet

__all__ = ["Recorder"]

log = logging.getLogger(__name__)
QUEUE_CHUNKS = 20_000  # about a few seconds of a busy link; beyond that the recording, not the link, loses
_ORIGINAL, _FORWARDED, _INDEX, _PROFILES = 0, 1, 2, 3
_FLUSH, _STOP = -1, -2


class Recorder:
    """Writes one link's recording into ``directory`` (created if missing)."""

    def __init__(self, directory: str | Path, link: int = 0, *, wall_clock: Callable[[], float] = time.time) -> None:
        self.directory = Path(directory)
        self.link = link
        self._clock = wall_clock
        self._queue: queue.Queue[tuple[int, bytes]] = queue.Queue(QUEUE_CHUNKS)
        self._n_index = 0
        self._n_profiles = 0
        self.original_count = 0
        self.forwarded_count = 0
        self._first = 0  # original.tlog index of the first frame of the datagram in flight
        self.lost_chunks = 0
        self.failed: str | None = None  # why recording stopped, if it did
        self.closed = False
        self._flushed_at = self._clock()
        self._files: list[IO[bytes]] = []
        self._writer: threading.Thread | None = None
        try:  # a directory that cannot be made or written: no recording, one error, the link still forwards
            self.directory.mkdir(parents=True, exist_ok=True)
            for name in ("original.tlog", "forwarded.tlog", "index.json", "profiles.json"):
                self._files.append(open(self.directory / name, "wb"))  # noqa: SIM115 - the writer thread closes them
        except OSError as exc:
            for f in self._files:
                f.close()
            self._fail(f"{exc.strerror or exc} ({exc.filename or self.directory})")
            return
        self._put(_INDEX, b"[")
        self._put(_PROFILES, b"[")
        self._writer = threading.Thread(target=self._write_loop, name=f"recorder-{link}", daemon=True)
        self._writer.start()

    def _fail(self, reason: str) -> None:
        self.failed = reason
        log.error("record.failed", extra={"link": self.link, "dir": str(self.directory), "error": reason,
                                          "effect": "recording stopped; forwarding goes on"})  # fmt: skip

    def _put(self, file: int, data: bytes) -> None:
        if self.failed is not None or self.closed:
            return
        try:
            self._queue.put_nowait((file, data))
        except queue.Full:
            self.lost_chunks += 1

    def _write_loop(self) -> None:
        """The writer thread: everything that touches the disk happens here."""
        while True:
            file, data = self._queue.get()
            if file == _STOP:
                break
            if self.failed is not None:
                continue  # drain what was queued before the failure
            try:
                if file == _FLUSH:
                    for f in self._files:
                        f.flush()
                else:
                    self._files[file].write(data)
            except OSError as exc:
                self._fail(f"{exc.strerror or exc} ({self._files[max(file, 0)].name})")
        for f in self._files:
            try:
                f.close()
            except OSError as exc:  # the last flush of a full disk
                if self.failed is None:
                    self._fail(f"{exc.strerror or exc} ({f.name})")

    FLUSH_EVERY_S = 1.0  # a crash or SIGKILL loses at most about this much of the recording

    def _stamp(self, delay_s: float = 0.0) -> bytes:
        now = self._clock()
        if now - self._flushed_at >= self.FLUSH_EVERY_S:
            self._flushed_at = now
            self.flush()
        return tlog.stamp(now + delay_s)

    # -- the pipeline's observer hooks (mitm_proxy.core.pipeline.Observer) ---------------------------------

    def frames_in(self, direction: Direction, frames: Sequence[tuple[Header, bytes]]) -> None:
        """Frames as received (one datagram's worth), in original.tlog."""
        self._first = self.original_count
        stamp = self._stamp()
        self._put(_ORIGINAL, b"".join(stamp + raw for _, raw in frames))
        self.original_count += len(frames)

    def after_stage(self, stage: object, pkts: Sequence[Packet]) -> None:
        pass

    def frame_out(self, direction: Direction, pos: int, header: Header, raw: bytes, data: bytes,
                  pkt: Packet | None, delay_s: float) -> None:  # fmt: skip
        """One forwarded frame; when a stage handled it (``pkt``), the index says what happened."""
        self._put(_FORWARDED, self._stamp(delay_s) + data)
        if pkt is not None and (pkt.changed or pkt.injected or delay_s > 0.0):
            self._entry(self.forwarded_count, self._first + pos, pkt.header.msgid, pkt, delay_s)
        self.forwarded_count += 1

    def dropped(self, direction: Direction, pos: int, header: Header, raw: bytes, pkt: Packet) -> None:
        """A frame a stage dropped: only the index records it."""
        self._entry(None, self._first + pos, header.msgid, pkt, 0.0, dropped=True)

    def _entry(
        self, index: int | None, original: int | None, msgid: int, pkt: Packet, delay_s: float, dropped: bool = False
    ) -> None:
        entry = {
            "index": index,
            "original": None if pkt.injected else original,
            "msgid": msgid,
            "direction": pkt.direction.value,
            "changed": pkt.changed,
            "injected": pkt.injected,
            "dropped": dropped,
            "delay_s": round(delay_s, 6),
            "notes": list(pkt.notes),
        }
        self._put(_INDEX, (("\n" if self._n_index == 0 else ",\n") + json.dumps(entry)).encode())
        self._n_index += 1

    def profile(self, name: str | None, content_hash: str | None, directions: Sequence[str]) -> None:
        """The attack profile now in force (None: cleared), from the next frame on: a line in profiles.json."""
        entry = {"t": round(self._clock(), 6), "original": self.original_count, "profile": name,
                 "hash": content_hash, "directions": list(directions)}  # fmt: skip
        self._put(_PROFILES, (("\n" if self._n_profiles == 0 else ",\n") + json.dumps(entry)).encode())
        self._n_profiles += 1

    def flush(self) -> None:
        """Ask the writer to flush every file (it happens on its thread, after what is queued)."""
        self._put(_FLUSH, b"")

    def close(self, timeout_s: float = 10.0) -> None:
        """Finish index.json and profiles.json, write what is queued and close the files; safe to call twice."""
        if self.closed:
            return
        self._put(_INDEX, b"\n]\n")
        self._put(_PROFILES, b"\n]\n")
        self.closed = True
        if self._writer is None:  # it never started (the directory was unusable)
            return
        try:
            self._queue.put((_STOP, b""), timeout=timeout_s)
        except queue.Full:  # the writer is stuck on a dead disk: leave it, it is a daemon thread
            return
        self._writer.join(timeout_s)

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
