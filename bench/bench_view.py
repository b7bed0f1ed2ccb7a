"""``kinesphere view`` with 8 robots streaming state at 50 Hz: does it keep its frame rate?

Eight stand-in robots (two each of Baxter, NAO, youBot, PackBot) run in a separate process,
each with a liveliness token, every joint moving, 50 states per second. The view runs
in this process against the real databank service (in-process, shipped databanks) with one
websocket client connected (a browser's traffic without a browser's rendering). Measured
over a window: frames drawn per second against the requested rate, robots re-posed per
second against the states that arrived, the cost of a frame against its budget, and the
bytes sent to the browser. Baselines in the same run: a bare Zenoh subscriber counting the
same states (what arrives at all), and the same view while the robots stand still.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import threading
import time
from typing import Any

import numpy as np

from kinesphere import zconfig
from kinesphere.keyexpr import Keys

KEYS = Keys("bench-view")
FLEET = {f"{p}-{i}": p for p in ("baxter", "nao", "youbot", "packbot") for i in (1, 2)}
STATE_HZ = 50.0
FPS = 30.0
WINDOW_S = 8.0


def robots(endpoint: str, moving: Any, stop: Any) -> None:
    """The stand-in fleet (a child process): tokens and states, all joints swinging."""
    from kinesphere.platforms.platform import load_platform
    from kinesphere.protocol import RobotState, encode

    with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        plats = {rid: load_platform(p) for rid, p in FLEET.items()}
        tokens = [s.liveliness().declare_token(KEYS.alive_robot(r)) for r in FLEET]
        pubs = {r: s.declare_publisher(KEYS.state(r)) for r in FLEET}
        seq, t0, period = 0, time.monotonic(), 1.0 / STATE_HZ
        while not stop.is_set():
            seq += 1
            t = time.monotonic() - t0
            for rid, plat in plats.items():
                lim = [plat.eurdf.limits[j] for j in plat.joint_names]
                swing = 0.5 + 0.4 * np.sin(t + np.arange(len(lim))) if moving.is_set() else \
                    np.full(len(lim), 0.5)
                q = [float(x.lower + (x.upper - x.lower) * w) if np.isfinite(x.upper - x.lower)
                     else float(w) for x, w in zip(lim, swing, strict=True)]
                pubs[rid].put(encode(RobotState(
                    robot_id=rid, platform=plat.name, seq=seq, stamp_ns=time.time_ns(),
                    joint_names=list(plat.joint_names), q=q, qd=[], base_pose=[0.0, 0.0, 0.0],
                    status="moving", last_command_seq=-1)))
            time.sleep(max(0.0, t0 + seq * period - time.monotonic()))
        zconfig.undeclare(*tokens, *pubs.values())


def drain(port: int, stop: threading.Event, got: list[int]) -> None:
    """A websocket client reading everything the view sends (no rendering)."""
    import viser
    from websockets.sync.client import connect
    from websockets.typing import Subprotocol

    with connect(f"ws://127.0.0.1:{port}",
                 subprotocols=[Subprotocol(f"viser-v{viser.__version__}")]) as ws:
        while not stop.is_set():
            try:
                data = ws.recv(timeout=0.2)
            except TimeoutError:
                continue
            except Exception:  # the view closed the connection: the run is over
                return
            got[0] += len(data)


def measure(view: Any, counter: list[int], window: float) -> dict[str, float]:
    stats = view.stats
    f0, r0, c0, n0, b0 = stats.frames, stats.robot_updates, len(stats.costs_s), counter[0], 0
    t0 = time.monotonic()
    time.sleep(window)  # a measuring window, not synchronisation
    dt = time.monotonic() - t0
    costs = np.array(stats.costs_s[c0:]) * 1000
    return {"fps": (stats.frames - f0) / dt, "robot_updates": (stats.robot_updates - r0) / dt,
            "states": (counter[0] - n0) / dt, "p50_ms": float(np.median(costs)),
            "p99_ms": float(np.percentile(costs, 99)), "b0": b0}


def main() -> None:
    logging.getLogger("websockets").setLevel(logging.WARNING)
    from kinesphere.clients.view.app import FleetView
    from kinesphere.services.databank.service import DatabankService
    from kinesphere.services.ecl.ecl import Ecl

    ctx = mp.get_context("spawn")
    moving, stop = ctx.Event(), ctx.Event()
    with zconfig.loopback_hub() as (hub, endpoint), \
            zconfig.session(config=zconfig.loopback_config(endpoint)) as db_s, \
            zconfig.session(config=zconfig.loopback_config(endpoint)) as view_s:
        ecls = {p: Ecl.open(p) for p in set(FLEET.values())}
        with DatabankService(db_s, ecls, KEYS, "bench", known_platforms=ecls):
            counter = [0]
            bare = view_s.declare_subscriber(KEYS.state("*"),
                                             lambda _: counter.__setitem__(0, counter[0] + 1))
            view = FleetView(view_s, KEYS, port=zconfig.free_port(), fps=FPS)
            ws_stop, sent = threading.Event(), [0]
            ws = threading.Thread(target=drain, args=(view.port, ws_stop, sent), daemon=True)
            fleet = ctx.Process(target=robots, args=(endpoint, moving, stop), daemon=True)
            loop = threading.Thread(target=view.run, daemon=True)
            try:
                fleet.start()
                loop.start()
                ws.start()
                deadline = time.monotonic() + 60
                while len(view.drawings) < len(FLEET) and time.monotonic() < deadline:
                    time.sleep(0.1)  # waiting for 8 bodies to be drawn (bounded)
                print(f"{len(view.drawings)} robots drawn, {FPS:g} fps requested, "
                      f"{STATE_HZ:g} Hz states each")
                idle = measure(view, counter, WINDOW_S / 2)
                moving.set()
                b0 = sent[0]
                busy = measure(view, counter, WINDOW_S)
                kib = (sent[0] - b0) / WINDOW_S / 1024
            finally:
                stop.set()
                ws_stop.set()
                fleet.join(10)
                view.close()
                zconfig.undeclare(bare)
    budget = 1000 / FPS
    print(f"states arriving (bare subscriber baseline): {busy['states']:.0f}/s "
          f"({busy['states'] / (STATE_HZ * len(FLEET)):.2f}x of {STATE_HZ * len(FLEET):.0f}/s)")
    print(f"view frames while all 8 move: {busy['fps']:.1f}/s = {busy['fps'] / FPS:.2f}x the "
          f"requested {FPS:g}; robots re-posed {busy['robot_updates']:.0f}/s "
          f"({busy['robot_updates'] / len(FLEET):.1f} per robot per second)")
    print(f"frame cost p50 {busy['p50_ms']:.2f} ms, p99 {busy['p99_ms']:.2f} ms = "
          f"{busy['p50_ms'] / budget:.2f}x / {busy['p99_ms'] / budget:.2f}x the {budget:.1f} "
          f"ms budget; idle baseline p50 {idle['p50_ms']:.2f} ms "
          f"(moving/idle {busy['p50_ms'] / max(idle['p50_ms'], 1e-6):.1f}x)")
    print(f"to the browser: {kib:.0f} KiB/s")
