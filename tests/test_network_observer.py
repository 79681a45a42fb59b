"""The network's observer over real Zenoh on loopback: what it hears twice or late does
not change what it draws."""

from __future__ import annotations

import threading
import time

import numpy as np

from dica.deploy.transport import open_session, publisher
from dica.schemas import keys
from dica.schemas.codec import encode, now_ns
from dica.schemas.messages import Clock, State, VehicleState
from dica.sim_gateway.network_observer import NetworkObserver
from dica.sim_gateway.scenario import default_scenario
from dica.tools.loopback import router


def _vs(vin: str, x: float) -> VehicleState:
    return VehicleState(vin, "r1", "W_in_0", 20.0, 10.0, x, 0.0, 90.0, 5.0, 1.8, 13.9, True,
                        0.0, False, -1, -1, -1, False, False, "agent-1", np.zeros(0))  # fmt: skip


def test_a_moment_heard_twice_or_late_is_drawn_once(tmp_path):
    from dica.ica.netfile import load_intersection
    from tests.test_recording import _read, _rows

    sc = default_scenario("ch45")
    inter = load_intersection(sc.net_path, sc.junction_id)
    j = inter.junction_id
    with router() as endpoint:
        listen_s = open_session(connect=endpoint)
        talk_s = open_session(connect=endpoint)
        try:
            obs = NetworkObserver(listen_s, [inter], [], tmp_path / "network.rrd", _log())
            t = threading.Thread(target=obs.run, daemon=True)
            t.start()
            vehicles, clock = publisher(talk_s, keys.vehicles(j)), publisher(talk_s, keys.clock(j))
            deadline = time.monotonic() + 10
            while not vehicles.matching_status.matching and time.monotonic() < deadline:
                time.sleep(0.05)
            now = State("", 1, 0, 0.05, (_vs("a", 0.0), _vs("b", 10.0)), now_ns())
            vehicles.put(encode(now))
            vehicles.put(encode(now))  # twice
            vehicles.put(encode(State("", 0, 0, 0.0, (_vs("late", 5.0),), now_ns())))  # late
            clock.put(encode(Clock(2, 0.1, "lockstep", 1.0, True, now_ns())))
            t.join(timeout=15)
            assert not t.is_alive()
            obs.close()
        finally:
            listen_s.close()
            talk_s.close()
    drawn = _rows(_read(tmp_path / "network.rrd")["/network/vehicles"], "LineStrips2D:strips")
    assert [len(v) for _, v in drawn] == [2]  # step 1: a and b, each once; not the late one


def _log():
    import logging

    return logging.getLogger("test")
