"""Which status an agent reports: the precedence between safety, operator, databank and motion.

The agent remembers the last status it set (and why); what it publishes also depends on the
safety latch, the databank's reachability and whether the body is still moving or stuck.
"""

from __future__ import annotations

from collections.abc import Callable

from kinesphere.protocol import Status


def reported_status(
    status: str,
    detail: str,
    *,
    estopped: bool,
    reachable: bool | None,
    last_error: str,
    moving: bool,
    clamped: bool,
    settled: Callable[[], bool],
    blocked: Callable[[], str],
) -> tuple[str, str]:
    """The status and detail to publish, from the last ``status``/``detail`` the agent set.

    Precedence: e-stop, then what the operator caused (stopped, holding, error), then the
    databank's reachability (``last_error`` says why it is unreachable), then motion (moving,
    idle, clamped). Once ``settled()`` (the servos had their time after a trajectory ended), an
    idle or clamped body that ``blocked()`` explains (a non-empty reason) is an error. (Both
    are asked only then: a robot asks at every state it publishes.)
    """
    if estopped:
        return Status.ESTOP, detail
    if status in (Status.STOPPED, Status.HOLDING, Status.ERROR):
        return status, detail
    if reachable is False:
        return Status.DATABANK_UNREACHABLE, (
            detail if status == Status.DATABANK_UNREACHABLE else last_error
        )
    if status == Status.DATABANK_UNREACHABLE:  # it answers again
        status, detail = Status.MOVING, "databank reachable again"
    if status == Status.MOVING and not moving:
        status, detail = (Status.CLAMPED, detail) if clamped else (Status.IDLE, "at target")
    if status in (Status.IDLE, Status.CLAMPED) and settled():
        why = blocked()
        if why:
            return Status.ERROR, why
    return status, detail
