"""Hide the user info of URLs in text meant for people (errors, logs): ``http://USER:PW@HOST`` -> ``http://***@HOST``.

Ports and video sources in rig.json may carry credentials (``http://admin:secret@10.0.0.5``,
``rtsp://user:pw@cam/stream``). Every message that can show such a string passes it
through :func:`redact_urls`, which rewrites every ``SCHEME://USERINFO@`` in the text,
whatever the scheme (a scheme typo such as ``htp://`` included) and wherever the URL sits
in the message (quoted, inside a ``repr``, inside a JSON value).
"""

from __future__ import annotations

import re

# SCHEME://USERINFO@ where USERINFO has no '/', whitespace, quote or '@'. A password with
# an unescaped '@' ends the match at the last '@' before the host (greedy over non-'/').
_USERINFO = re.compile(r"(?P<scheme>[A-Za-z][A-Za-z0-9+.\-]*://)(?P<userinfo>[^/\s'\"@]*(?:@[^/\s'\"@]*)*)@")


def redact_urls(text: str) -> str:
    """``text`` with the user info of every URL replaced by ``***`` (idempotent)."""
    return _USERINFO.sub(lambda m: f"{m.group('scheme')}***@", text)
