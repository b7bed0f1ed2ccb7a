"""Nested queries in the databank service, on real loopback sessions and the shipped Baxter
databank: answered by the solver's worker, never on Zenoh's threads (a plain query asked
behind a cold nested one is answered first), remembered, and refused when too many wait."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import pytest
import zenoh

from kinesphere import protocol as pr
from kinesphere.services.databank.service import DatabankService
from kinesphere.services.databank.solves import Solves
from kinesphere.services.ecl.ecl import Ecl
from support.databank import pose_of, raw_get, serving
from support.network import OWN_KEYS as KEYS
from support.wait import WAIT_S, until

UPPER = ("right_upper_arm", "right_shoulder")
FORE = ("right_forearm", "right_elbow")


def nested(d1: str, d2: str) -> bytes:
    return pr.encode(pr.CompoundRequest(parts=[pr.SpatialCommand(*UPPER, d1, 3),
                                               pr.SpatialCommand(*FORE, d2, 3)]))


@pytest.fixture
def net() -> Iterator[tuple[DatabankService, zenoh.Session]]:
    """A fresh service (its solver cold) serving Baxter, and a querier, on a hub."""
    with serving({"baxter": Ecl.open("baxter")}, "nest") as (svc, client, _):
        yield svc, client


def test_a_cold_nested_solve_does_not_hold_up_other_queries(
    net: tuple[DatabankService, zenoh.Session],
) -> None:
    svc, c = net
    arrived: dict[str, float] = {}

    def ask_nested() -> None:
        replies = raw_get(c, KEYS.compound("baxter"), nested("forward-high", "left-middle"),
                          timeout=30.0)
        arrived["nested"] = time.monotonic()
        pose = pose_of(replies)
        assert pose.is_compound and [w.word for w in pose.words] == ["right_upper_arm"]

    asker = threading.Thread(target=ask_nested)
    asker.start()
    until(lambda: svc.solves.waiting() > 0 or "nested" in arrived, WAIT_S,
          "the solver's worker to hold the nested query", every=0.001)
    plain = pose_of(raw_get(c, KEYS.pose("baxter", "right_arm", "right_shoulder", "left-high",
                                         2)))
    arrived["plain"] = time.monotonic()
    asker.join()
    assert plain.p_id == 2
    assert arrived["plain"] < arrived["nested"], "the plain query waited for the solver"


def test_nested_answers_are_remembered_and_cut_limbs_answer_on_pose_keys(
    net: tuple[DatabankService, zenoh.Session],
) -> None:
    svc, c = net
    solver = svc.ecl("baxter").nested()
    first = pose_of(raw_get(c, KEYS.compound("baxter"), nested("right-middle", "forward-low"),
                            timeout=30.0))
    solves = solver.solves
    again = pose_of(raw_get(c, KEYS.compound("baxter"), nested("right-middle", "forward-low")))
    assert again == first and solver.solves == solves
    key = KEYS.pose("baxter", *UPPER, "right-middle", 3)
    cut = pose_of(raw_get(c, key, timeout=30.0))
    assert (cut.limb, cut.k_id, cut.words[0].end) == ("limb_11", pr.NO_ID, "distal_12")
    assert cut.joints != first.joints  # the forearm was left to its posture, not pointed
    assert pose_of(raw_get(c, key)) == cut and svc.answers.get(key) is not None


def test_too_many_nested_queries_waiting_are_refused_not_queued() -> None:
    def one_waiting(svc: DatabankService) -> None:  # beside the one being solved
        svc.solves = Solves("busy", max_jobs=1)

    with serving({"baxter": Ecl.open("baxter")}, "busy", one_waiting) as (_, client, _e):
        pending = [client.get(KEYS.compound("baxter"), payload=nested(d, "forward-low"),
                              timeout=30.0)
                   for d in ("forward-high", "right-high", "right-middle", "right-low",
                             "forward-low")]
        codes = []
        for replies in pending:
            err = next(iter(replies)).err
            codes.append("ok" if err is None else pr.error_from_reply(err.payload).code)
    assert codes[0] == "ok" and "unavailable" in codes, codes
