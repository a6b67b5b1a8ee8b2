"""The embedded broker's one account: with a username and password set, nobody else gets in.

amqtt loads this class by name from the broker configuration
(:func:`secuav_common.broker.amqtt_config`); it replaces amqtt's anonymous
plugin, so a client without the right username and password is refused at
CONNECT. Compared in constant time. The password reaches the broker process
through its environment (``SECUAV_EMBEDDED_BROKER_PASSWORD``), never its
command line, which ``ps`` shows to every user.
"""

from __future__ import annotations

import hmac
from dataclasses import dataclass

from amqtt.plugins.base import BaseAuthPlugin
from amqtt.session import Session


class OneAccountAuthPlugin(BaseAuthPlugin):
    @dataclass
    class Config:
        username: str = ""
        password: str = ""

    async def authenticate(self, *, session: Session) -> bool:
        cfg = self.context.config
        want_user, want_pw = getattr(cfg, "username", ""), getattr(cfg, "password", "")
        if not want_user or session.username is None:
            return False
        given_pw = session.password or ""
        user_ok = hmac.compare_digest(session.username.encode(), want_user.encode())
        pw_ok = hmac.compare_digest(given_pw.encode(), want_pw.encode())
        return user_ok and pw_ok
