"""mavframe: the MAVLink frame layer every SecUAV part shares.

A pure library (no sockets, no asyncio): the proxy, the recorder
(``secuav-record``), the offline evaluation and the simulator's wire code all
cut, check, decode, re-pack, sign and log frames through it, so they agree on
what a valid frame is byte for byte.

- :mod:`mavframe.frames`: :func:`~mavframe.frames.split` a datagram into
  CRC-checked frames (peeking at headers only); :class:`~mavframe.frames.StreamFramer`
  for byte streams (TCP, serial);
- :mod:`mavframe.packet`: :class:`~mavframe.packet.Header`, :class:`~mavframe.packet.Packet`,
  :class:`~mavframe.packet.Direction`;
- :mod:`mavframe.codec`: decode a targeted frame to pymavlink's field dict,
  re-pack a changed one with its original header, build new frames;
- :mod:`mavframe.layout`: message ids, payload start and field offsets (read off the dialect,
  never typed by hand), ``target_system`` of a frame;
- :mod:`mavframe.signing`: MAVLink 2 signing keys, verification and re-signing;
- :mod:`mavframe.tlog`: the .tlog format QGroundControl and MAVProxy write, read and written.
"""
