"""How an agent runs: the options ``kinesphere agent`` and tests give :class:`Agent`."""

from __future__ import annotations

import math
from dataclasses import dataclass

from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import DEFAULT_PREFIX
from kinesphere.robots.agent.body import BODIES, DEFAULT_BODY
from kinesphere.robots.agent.trajectory import DEFAULT_MARGIN


@dataclass(frozen=True)
class AgentOptions:
    """How an agent runs; the single source of its defaults (``kinesphere agent`` reads them).

    Control ``rate`` and ``state_rate`` in Hz, ``speed`` (robot seconds per wall second, 0 =
    unpaced), key ``prefix``, ``groups`` it obeys, databank query timeout, joint-limit clamp
    ``margin``, and the ``body`` it drives (a name in ``body.BODIES``).
    """

    rate: float = 500.0
    state_rate: float = 50.0
    speed: float = 1.0
    prefix: str = DEFAULT_PREFIX
    groups: tuple[str, ...] = ()
    query_timeout_s: float = 1.0
    margin: float = DEFAULT_MARGIN
    body: str = DEFAULT_BODY

    def __post_init__(self) -> None:
        checks = (
            (math.isfinite(self.rate) and self.rate > 0, f"rate must be > 0 Hz, got {self.rate}"),
            (0 < self.state_rate <= self.rate,
             f"state rate must be in (0, rate], got {self.state_rate}"),
            (math.isfinite(self.speed) and self.speed >= 0,
             f"speed must be >= 0 (0 = unpaced), got {self.speed}"),
            (self.query_timeout_s > 0, f"query timeout must be > 0, got {self.query_timeout_s}"),
            (self.margin >= 0, f"margin must be >= 0, got {self.margin}"),
            (self.body in BODIES,
             f"unknown body {self.body!r}; valid: {', '.join(sorted(BODIES))}"),
        )
        for ok, message in checks:
            if not ok:
                raise KinesphereError("malformed", message)
