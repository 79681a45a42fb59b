"""Window ordering: a window's requests decided together, in the order that delays them least."""

from __future__ import annotations

import json

import pytest

from dica.ica.core.config import IcaConfig
from dica.ica.core.dica import Dica
from dica.ica.core.proposal import propose
from dica.ica.core.request import Confirmation
from dica.ica.core.window import WindowOrder
from dica.sim_gateway.audit import conflicts
from tests.dica_cli import DICA, dica_run
from tests.test_reactive import flown
from tests.test_run_sumo import ROOT

CFG = IcaConfig()
FAR = "W_in_1", "E_out_1"  # through from the west
NEAR = "N_in_1", "S_out_1"  # through from the north: crosses it


def request(inter, vin, lanes, d, v, seq=0):
    route = inter.route(*lanes)
    return propose(route, vin=vin, seq=seq, t0_s=0.0, dist_to_entry_m=d, speed_mps=v, config=CFG)


def _decide(inter, order: list[str]) -> dict[str, Confirmation]:
    """The far car was detected first; decide both requests in ``order``."""
    ica = Dica(inter, CFG)
    ica.advance(0.0)
    ica.detect("far", FAR[0], -2.0)
    ica.detect("near", NEAR[0], -1.0)
    reqs = {
        "far": request(inter, "far", FAR, 30.0, 6.0),
        "near": request(inter, "near", NEAR, 25.0, 10.0),
    }
    out = {}
    for vin in order:
        conf = ica.handle(reqs[vin], 0.0)
        assert isinstance(conf, Confirmation)
        out[vin] = conf
    return out


def test_the_window_lets_the_second_car_go_first_when_that_delays_the_two_less(ch45):
    ica = Dica(ch45, CFG)
    ica.advance(0.0)
    ica.detect("far", FAR[0], -2.0)
    ica.detect("near", NEAR[0], -1.0)
    window = WindowOrder(ica)
    reqs = [request(ch45, "far", FAR, 30.0, 6.0), request(ch45, "near", NEAR, 25.0, 10.0)]
    assert [r.vin for r in window.order(reqs)] == ["near", "far"]
    assert (window.windows, window.reordered) == (1, 1)
    assert [r.vin for r in window.order(reqs[:1])] == ["far"]  # alone: nothing to order

    fcfs, windowed = _decide(ch45, ["far", "near"]), _decide(ch45, ["near", "far"])
    # DICA decides each plan as before, each against all confirmed: only the order differs
    total = {k: sum(c.delay_s for c in v.values()) for k, v in (("fcfs", fcfs), ("w", windowed))}
    assert total["w"] < total["fcfs"] - 1.0
    assert windowed["near"].entry_time_s < fcfs["near"].entry_time_s - 1.0
    assert conflicts(flown(ch45, list(windowed.values())), CFG.margin_m) == []


def test_a_lane_s_order_is_kept_and_unknown_requests_come_last(ch45):
    ica = Dica(ch45, CFG)
    ica.advance(0.0)
    for vin, t in (("a", -3.0), ("b", -2.0), ("x", -1.0)):
        ica.detect(vin, NEAR[0] if vin != "x" else FAR[0], t)
    reqs = [
        request(ch45, "b", NEAR, 20.0, 9.0),  # behind a in its lane, though it asked first
        request(ch45, "x", FAR, 5.0, 9.0),
        request(ch45, "a", NEAR, 6.0, 9.0),
        request(ch45, "ghost", NEAR, 30.0, 9.0),  # never detected: DICA will say so
    ]
    order = [r.vin for r in WindowOrder(ica).order(reqs)]
    assert order.index("a") < order.index("b") and order[-1] == "ghost"
    assert sorted(order) == ["a", "b", "ghost", "x"]


@pytest.mark.sumo
def test_a_windowed_run_in_sumo_is_safe_and_reorders(tmp_path):
    out = tmp_path / "w"
    p = dica_run(
        [*DICA, "run", "--volume", "500", "--duration", "150",
         "--window", "0.5", "--out", str(out), "--quiet"],
        capture_output=True, text=True, cwd=ROOT, timeout=600,
    )  # fmt: skip
    assert p.returncode == 0, p.stdout + p.stderr
    m = json.loads((out / "metrics.json").read_text())
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0 and m["unconfirmed_entries"] == 0
    assert m["requests"]["windows_ordered"] >= 5 and m["requests"]["windows_reordered"] >= 1
    assert m["timing"]["plans_refused"] == 0  # every plan starts where its vehicle is
    assert json.loads((out / "config.json").read_text())["run"]["window_s"] == 0.5
