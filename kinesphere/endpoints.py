"""Default Zenoh endpoints, importable without loading Zenoh (help texts use them).

:mod:`kinesphere.zconfig` re-exports every name here.
"""

from __future__ import annotations

LOOPBACK_HOST = "127.0.0.1"
LOOPBACK_ANY_PORT = f"tcp/{LOOPBACK_HOST}:0"
"""Listen on loopback only, on a port the OS picks."""
DEFAULT_ENDPOINT = f"tcp/{LOOPBACK_HOST}:7447"
"""Where a service listens (and a client connects) when no endpoint is given: one machine."""
