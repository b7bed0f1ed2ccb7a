"""The answer to ``{p}/ecl/{platform}/body``: a platform's body, so viewers need no files.

A viewer on an operator's laptop has only the core installed, yet must draw every robot it
sees. The databank already holds each served platform's description (it reads the eURDF for
the ECL), so it answers with the eURDF text as it is on disk (primitive shapes only: tens of
KiB), the neutral pose and the base kind. The answer never changes while the process runs,
so it is encoded once per platform.
"""

from __future__ import annotations

from kinesphere.errors import KinesphereError
from kinesphere.platforms.platform import Platform
from kinesphere.protocol import MAX_LARGE_PAYLOAD, BodyModel, encode


def body_model(platform: Platform) -> BodyModel:
    """The BodyModel of ``platform``, read from its eURDF file."""
    path = platform.eurdf.path
    if path is None:
        raise KinesphereError("internal", f"{platform.name}: eURDF has no file to send")
    body = BodyModel(
        platform=platform.name,
        eurdf=path.read_text(encoding="utf-8"),
        base_kind=platform.base.kind,
        neutral=dict(platform.neutral),
        version=platform.eurdf.sha256,
    )
    size = len(encode(body))
    if size > MAX_LARGE_PAYLOAD:  # receivers would refuse it: say so here instead
        raise KinesphereError(
            "internal", f"{platform.name}: body of {size} bytes exceeds {MAX_LARGE_PAYLOAD}"
        )
    return body
