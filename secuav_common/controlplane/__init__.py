"""The control plane, in one place: topics, payloads, the MQTT session, request and acknowledgement.

- :mod:`~secuav_common.controlplane.address`: where the broker is (``mqtt://``, ``mqtts://``);
- :mod:`~secuav_common.controlplane.topics`: the topic grammar, its builders and the one parser;
- :mod:`~secuav_common.controlplane.payloads`: the pydantic model of each topic's payload, decoding that
  names the topic, field and value of a bad message, and the proxy's request decoding;
- :mod:`~secuav_common.controlplane.session`: one MQTT session with reconnect, backoff, TLS, auth, last will;
- :mod:`~secuav_common.controlplane.requests`: send a ``.../set`` and wait for the ``.../state`` that
  carries its request id;
- :mod:`~secuav_common.controlplane.switches`: the runtime switches, one module each (topic leaf, scope,
  payload models, ``secuav-attack`` verbs, where the proxy's side lives), and the registry the proxy, the
  payload checks and ``secuav-attack`` iterate.

Depends only on aiomqtt, pydantic and the broker's address: the proxy, the console, the simulator, the
demos and ``secuav-attack`` all speak the plane through it. Nothing is imported here, so a process that only
needs the grammar does not load the MQTT client.
"""
