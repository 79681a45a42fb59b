"""Pedestrian crossings in the junction's geometry: read from any net that has them, each
a strip that a vehicle on a route touches over one span of front positions."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from dica.ica.core.crosswalk import Crosswalk, span, spans
from dica.ica.core.limits import SpeedCaps, Turn
from dica.ica.core.route import build_route
from dica.ica.netfile import load_intersection
from tests.dica_cli import DICA, dica_run
from tests.user_nets import make, tool

ROOT = Path(__file__).resolve().parents[1]


def _straight() -> object:
    """West to east along y = 0: the entry line at x = 0, the exit line at x = 20."""
    return build_route(
        route_id="w>e", in_lane="w_0", out_lane="e_0", via_lanes=(),
        in_shape=np.array([[-100.0, 0.0], [0.0, 0.0]]), via_shapes=[],
        out_shape=np.array([[20.0, 0.0], [120.0, 0.0]]), turn=Turn.THROUGH,
        caps=SpeedCaps(), approach_m=60.0, tail_m=20.0,
    )  # fmt: skip


def test_a_car_holds_a_crossing_from_its_front_in_to_its_rear_out():
    # a 4 m strip across the road at x = 10 and a walker's body (BODY_M, 0.5 m) over each
    # edge: a 5 m car touches it from front at 7.5 to rear at 12.5, front at 17.5
    walk = Crosswalk("c", np.array([[10.0, -6.0], [10.0, 6.0]]), 4.0)
    a, b = span(_straight(), walk, 5.0, 1.8)
    assert 7.2 <= a <= 7.5 and 17.5 <= b <= 17.8
    # grown by a margin: longer on both sides
    a2, b2 = span(_straight(), walk, 5.0, 1.8, margin_m=0.5)
    assert a2 == pytest.approx(a - 0.5, abs=0.11) and b2 == pytest.approx(b + 0.5, abs=0.11)
    assert walk.length_m == pytest.approx(12.0)


def test_a_crossing_off_the_route_is_never_touched():
    walk = Crosswalk("far", np.array([[10.0, 8.0], [10.0, 20.0]]), 4.0)  # beside the road
    assert span(_straight(), walk, 5.0, 1.8) is None
    assert spans((_straight(),), (walk,), 5.0, 1.8) == {"w>e": []}


def test_a_bent_crossing_is_one_strip_per_segment():
    walk = Crosswalk("bent", np.array([[0.0, 0.0], [5.0, 0.0], [5.0, 0.0], [5.0, 5.0]]), 3.0)
    strips = walk.strips()
    assert len(strips) == 2  # the segment of no length is left out
    assert walk.length_m == pytest.approx(10.0)


@pytest.mark.parametrize(
    "shape, width",
    [(np.array([[0.0, 0.0]]), 4.0), (np.array([[0.0, 0.0], [1.0, 0.0]]), 0.0),
     (np.array([[0.0, np.nan], [1.0, 0.0]]), 4.0)],
)  # fmt: skip
def test_a_crossing_needs_a_centre_line_and_a_width(shape, width):
    with pytest.raises(ValueError, match="crossing x"):
        Crosswalk("x", shape, width)


@pytest.fixture(scope="module")
def walk_net(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 3x3 grid of 2-lane streets, 100 m blocks, with sidewalks and crossings guessed."""
    out = tmp_path_factory.mktemp("crosswalk") / "xwalk.net.xml"
    make([tool("netgenerate"), "--grid", "--grid.number", "3", "--grid.length", "100",
          "--default.lanenumber", "2", "--sidewalks.guess", "true",
          "--crossings.guess", "true", "--no-turnarounds", "true", "-o", str(out)])  # fmt: skip
    return out


def test_a_nets_crossings_are_read_and_every_route_passes_two(walk_net):
    x = load_intersection(walk_net, "B1")
    assert [c.id for c in x.crosswalks] == [":B1_c0", ":B1_c1", ":B1_c2", ":B1_c3"]
    for c in x.crosswalks:
        assert c.width_m == pytest.approx(4.0) and 10.0 < c.length_m < 15.0
        assert len(c.crosses) == 2  # the arm's road in and its road out
        assert len(c.corners) == 2  # a walking area at each end
    over = spans(x.routes, x.crosswalks, 5.0, 1.8, 0.25)
    x_crosses = {c.id: c.crosses for c in x.crosswalks}
    for r in x.routes:
        # the crossing on its arm in, then the one on its arm out (and, turning, the
        # corner of the one between, which its body sweeps)
        first, last = over[r.id][0], over[r.id][-1]
        assert first[0] != last[0] and 2 <= len(over[r.id]) <= 3
        # at the entry line, or up to a few metres short of it: a walker's body over the
        # strip's edge, and the corners' walking areas where the arm's lanes end
        assert -3.0 < first[1] < 0.5
        assert last[2] > r.cross_length_m  # the rear clears it after the exit line
        arms = {a for cid, *_ in over[r.id] for a in x_crosses[cid]}
        assert r.in_lane.rsplit("_", 1)[0] in arms and r.out_lane.rsplit("_", 1)[0] in arms


@pytest.mark.parametrize(
    "edge, junction, mine",
    [(":B1_c0", "B1", True), (":B1_c12", "B1", True), (":B1_1_c0", "B1", False),
     (":B1_w0", "B1", False), (":B1_c", "B1", False), (":B1_c0x", "B1", False),
     (":cluster_1_2_c3", "cluster_1_2", True), (":B_c0", "B1", False)],
)  # fmt: skip
def test_a_crossing_belongs_to_its_own_junction_only(edge, junction, mine):
    from dica.ica.netfile import is_crossing_of

    assert is_crossing_of(edge, junction) is mine


def test_a_net_without_crossings_has_none(tmp_path):
    from tests.user_nets import build_nets

    assert load_intersection(build_nets(tmp_path)["grid"], "B1").crosswalks == ()


def test_geometry_lists_the_crossings(walk_net):
    p = dica_run(
        [*DICA, "geometry", "--net", str(walk_net),
         "--junction", "B1", "--json"],
        capture_output=True, text=True, cwd=ROOT, timeout=60,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    doc = json.loads(p.stdout)
    assert len(doc["crossings"]) == 4
    assert all(len(r["crossings"]) >= 2 for r in doc["routes"])


def test_the_recording_draws_the_crossings(walk_net, tmp_path):
    from dica.sim_gateway.recording import SpaceTimeRecorder
    from dica.sim_gateway.recording.network_view import TopDrawing
    from tests.test_recording import _read, _static

    x = load_intersection(walk_net, "B1")
    rec = SpaceTimeRecorder(x, tmp_path / "b1.rrd")
    rec.geometry()
    rec.close()
    strips = _static(_read(tmp_path / "b1.rrd")["/junction/crossings"], "LineStrips2D:strips")
    assert len(strips) == 4 and all(len(s) == 5 for s in strips)  # closed rectangles
    top = TopDrawing([x, load_intersection(walk_net, "A1")], tmp_path / "network.rrd")
    top.geometry([])
    top.close()
    strips = _static(_read(tmp_path / "network.rrd")["/network/crossings"], "LineStrips2D:strips")
    assert len(strips) == 4 + 3  # A1, on the grid's edge, has three arms


def test_the_recording_bands_hold_vehicles_walkers_and_people_on_a_crossing(walk_net, tmp_path):
    """A crossing's band in the conflict-point chart: a box for a confirmed vehicle's hold
    over the stretch its body covers, boxes for a walker's reservation, and a dot for a
    person on the strip, red only outside every walker's reservation there."""
    from dica.ica.core.dica import Dica
    from dica.sim_gateway.recording import SpaceTimeRecorder
    from dica.sim_gateway.recording.crossing_chart import front_positions
    from dica.sim_gateway.recording.style import rgba
    from tests.test_recording import _read, _rows

    x = load_intersection(walk_net, "B1")
    ica = Dica(x)
    through = x.route("A1B1_1", "B1C1_1")
    conf = _car(ica, through, "car", 0.0)
    tss = conf.tss
    s = front_positions(through, tss.x_m, tss.y_m)  # from 30 m before its entry line
    assert s[0] == pytest.approx(-30.0, abs=0.05) and np.all(np.diff(s) >= -1e-9)
    slot = ica.walk("amy", ":B1_c1", 0.0, 0.0, side=0, near_m=3.0, near_lo_m=2.0)
    c1 = next(c for c in x.crosswalks if c.id == ":B1_c1")
    rec = SpaceTimeRecorder(x, tmp_path / "b1.rrd")
    rec.geometry()
    rec.confirmed("car", through.id, tss.t_s, tss.x_m, tss.y_m, tss.heading_rad, 5.0, 1.8,
                  conf.entry_time_s, conf.exit_time_s, now_s=0.0)  # fmt: skip
    rec.walk(0.0, slot)
    mid = c1.shape[0] + (c1.shape[-1] - c1.shape[0]) * 0.5  # half-way across
    t_mid = slot.over(c1.length_m / 2, c1.length_m / 2, c1.length_m, 0.0)[0] + 0.1
    rec.people(t_mid, np.array([mid]), np.array([False]))
    rec.people(slot.end_s + 5.0, np.array([mid]), np.array([False]))  # on it, out of time
    rec.close()
    data = _read(tmp_path / "b1.rrd")
    holds = [v for _, v in _rows(data["/charts/data/zones/crossing_holds"], "Boxes2D:labels")]
    shape = ica.confirmed["car"].dtot.shape  # the crossings the ICA holds for it
    assert sorted(label.split()[2] for label in holds[0]) == sorted(
        cid for cid, _, _ in ica.crossing_spans(through, shape)
    )
    assert {":B1_c1", ":B1_c3"} <= {label.split()[2] for label in holds[0]}
    walks = [v for _, v in _rows(data["/charts/data/zones/walks"], "Boxes2D:labels")]
    assert len(walks[0]) >= 4 and all(label.startswith("amy walks :B1_c1") for label in walks[0])
    dots = [v for _, v in _rows(data["/charts/data/zones/people"], "Points2D:colors")]
    red = rgba((220, 30, 30))
    assert [[c == red for c in row] for row in dots] == [[False], [True]]


# -- walkers and vehicles ------------------------------------------------------------
def _car(ica, route, vin: str, t0: float, d: float = 30.0, speed: float = 10.0):
    from dica.ica.core.proposal import propose
    from dica.ica.core.request import Confirmation

    ica.detect(vin, route.in_lane, t0)
    out = ica.handle(
        propose(route, vin=vin, seq=0, t0_s=t0, dist_to_entry_m=d, speed_mps=speed,
                config=ica.config),
        t0,
    )  # fmt: skip
    assert isinstance(out, Confirmation), out
    return out


def _holds(ica, vin: str, crossing: str) -> tuple[float, float]:
    from dica.ica.core.walk import hold

    c = ica.confirmed[vin]
    (a, b) = next((a, b) for cid, a, b in ica.crossing_spans(c.dtot.route, c.dtot.shape)
                  if cid == crossing)  # fmt: skip
    return hold(c.dtot.trajectory, a, b, c.out_mps)


def _meets(ica, vin: str, slot) -> bool:
    """Whether confirmed ``vin``'s body and ``slot``'s walker can be on the same stretch of
    its crossing at once (with the gap between)."""
    c = ica.confirmed[vin]
    t_in, t_out = _holds(ica, vin, slot.crossing)
    u_lo, u_hi = ica.crossing_reach(c.dtot.route, c.dtot.shape)[slot.crossing]
    length = ica.walks.crosswalks[slot.crossing].length_m
    a, b = slot.over(u_lo, u_hi, length, ica.walks.clear_s)
    gap = ica.walks.gap_s
    return b > a and a - gap < t_out - 1e-9 and b + gap > t_in + 1e-9


def test_a_walker_goes_once_the_confirmed_vehicles_are_past_its_way(walk_net):
    from dica.ica.core.dica import Dica

    x = load_intersection(walk_net, "B1")
    for side in (0, 1):
        ica = Dica(x)
        through = x.route("A1B1_1", "B1C1_1")  # west to east: crosses c3 (its arm in), then c1
        _car(ica, through, "car", 0.0)
        t_in, t_out = _holds(ica, "car", ":B1_c3")
        assert 0.0 < t_in < t_out
        slot = ica.walk("amy", ":B1_c3", 0.0, 0.0, side=side, near_m=2.0)  # as the car comes
        assert not _meets(ica, "car", slot)
        # a slow walk over the whole crossing from the car's own lane would meet it
        lane = ica.crossing_reach(through, ica.confirmed["car"].dtot.shape)[":B1_c3"]
        assert -12.0 <= lane[0] < lane[1] <= x.crosswalks[3].length_m + 12.0
        # a walker of no stated speed: from 1.0 to 2.5 m/s
        assert (slot.v_lo, slot.v_hi) == (1.0, 2.5)
    # a new phase: stepping off 3 s late, a slow walk (1.0 m/s) from KERB_M (6 m) short of
    # it to its far end, 2 s more
    assert slot.end_s - slot.start_s == pytest.approx(3.0 + (12.8 + 6.0) / 1.0 + 2.0)
    # a crossing no vehicle holds: with the junction's walk phase that has not begun
    bob = ica.walk("bob", ":B1_c0", 0.0, 0.0)
    assert bob.start_s == slot.start_s
    # once it has begun, the next phase leaves the vehicles their window first: after the
    # walkers are expected across at their own pace (before the slow walk's end)
    first_end = ica.walks.last_end
    assert slot.start_s < first_end <= max(slot.end_s, bob.end_s)
    late = ica.walk("cyd", ":B1_c0", slot.start_s + 1.0, slot.start_s + 1.0)
    assert late.start_s == pytest.approx(first_end + ica.walks.phase_gap_s)
    # seen across sooner, a walker's slot ends there: vehicles need not wait out its walk
    assert ica.walked("bob", ":B1_c0", bob.start_s + 9.0)
    assert ica.walks.slot_of("bob", ":B1_c0").end_s == pytest.approx(bob.start_s + 9.0)
    assert not ica.walked("bob", ":B1_c0", bob.start_s + 12.0)  # never later again


def test_a_walker_may_be_on_the_crossing_as_soon_as_its_shortest_way_allows():
    """A walker round a corner may cut across it: it may be on the crossing as soon as
    the shortest way (``near_lo_m``) allows, and still on it as late as the longest
    (``near_m``) does; the shortest is never taken longer than the longest."""
    from dica.ica.core.crosswalk import BODY_M
    from dica.ica.core.walk import LAG_S, WalkSlot

    w = WalkSlot("amy", "c", 10.0, 60.0, side=0, near_m=9.0, v_lo=1.0, v_hi=2.0,
                 near_lo_m=3.0)  # fmt: skip
    t_in, t_out = w.over(4.0, 5.0, 16.0, 0.0)
    assert t_in == pytest.approx(10.0 + (4.0 + 3.0 - BODY_M) / 2.0)
    assert t_out == pytest.approx(10.0 + LAG_S + (5.0 + 9.0 + BODY_M) / 1.0)
    # not told the shortest: at the crossing's end at once, at 2.5 m/s on from there
    bob = WalkSlot("bob", "c", 10.0, 60.0, near_m=9.0)
    assert bob.over(4.0, 5.0, 16.0, 0.0)[0] == pytest.approx(10.0 + (4.0 - BODY_M) / 2.5)
    from dica.ica.core.walk import Walkways

    ways = Walkways((Crosswalk("c", np.array([[0.0, 0.0], [16.0, 0.0]]), 4.0),))
    assert ways.slot("cyd", "c", 0.0, near_m=2.0, near_lo_m=5.0).near_lo_m == 2.0


def test_the_shortest_way_to_a_crossing_is_to_the_edge_of_its_end():
    from dica.sim_gateway.walkers import to_end_edge

    shape = np.array([[0.0, 0.0], [16.0, 0.0]])  # 4 m wide: its end 0 from y = -2 to 2
    assert to_end_edge(np.array([-3.0, 1.0]), shape, 4.0, 0) == pytest.approx(3.0)
    assert to_end_edge(np.array([-3.0, 6.0]), shape, 4.0, 0) == pytest.approx(5.0)
    assert to_end_edge(np.array([19.0, 0.0]), shape, 4.0, 1) == pytest.approx(3.0)
    assert to_end_edge(np.array([1.0, 0.0]), shape, 4.0, 0) == 0.0  # on it already


@pytest.mark.parametrize("compiled", [True, False])  # the compiled rounds, the Python loop
def test_a_vehicle_waits_for_the_walkers_on_its_way(walk_net, compiled, monkeypatch):
    from dica.ica.core.dica import Dica

    monkeypatch.setattr(Dica, "compiled_loop", compiled)
    x = load_intersection(walk_net, "B1")
    free = Dica(x)
    through = x.route("A1B1_1", "B1C1_1")
    alone = _car(free, through, "car", 0.0)
    waited = []
    for side in (0, 1):
        ica = Dica(x)
        slot = ica.walk("amy", ":B1_c1", 0.0, 0.0, side=side)  # the crossing on its way out
        held = _car(ica, through, "car", 0.0)
        assert not _meets(ica, "car", slot)  # never on her stretch while she may be there
        waited.append(held.entry_time_s - alone.entry_time_s)
    assert max(waited) > 0.5  # from one side or the other, she is in its lane as it comes
    # a route that passes neither walker's crossing does not wait
    right = x.route("B2B1_1", "B1A1_1")  # south turning right: c0 then c3, none held
    assert ":B1_c1" not in {
        cid for cid, _, _ in free.crossing_spans(right, free.confirmed["car"].dtot.shape)
    }
    ica2 = Dica(x)
    ica2.walk("amy", ":B1_c1", 0.0, 0.0)
    base = Dica(x)
    assert _car(ica2, right, "r", 0.0).entry_time_s == _car(base, right, "r", 0.0).entry_time_s


def test_a_walk_asked_twice_gets_the_same_slot(walk_net):
    """A WALK repeated (its answer lost, or the message twice) must not hold the crossing
    twice, nor move the walker's moment: even with a vehicle confirmed in between."""
    from dica.ica.core.dica import Dica

    x = load_intersection(walk_net, "B1")
    ica = Dica(x)
    first = ica.walk("amy", ":B1_c3", 0.0, 0.0)
    _car(ica, x.route("A1B1_1", "B1C1_1"), "car", 0.5)  # over :B1_c3, after amy
    assert ica.walk("amy", ":B1_c3", 0.0, 1.0) == first
    assert (
        ica.walks.reserve(ica.walks.slot("amy", ":B1_c3", 99.0)) == first
    )  # a journal replayed twice
    assert len(ica.walks.slots[":B1_c3"]) == 1
    other = ica.walk("bob", ":B1_c3", 0.0, 1.0)  # another walker: a slot of its own
    assert other.person == "bob" and len(ica.walks.slots[":B1_c3"]) == 2
    ica.advance(first.end_s + 0.1)  # once across, amy may ask anew
    assert ica.walks.slot_of("amy", ":B1_c3") is None


def test_a_walker_let_go_late_stays_inside_a_slot_that_allows_for_it(walk_net):
    """The roadside may let a walker go up to ``late_s`` after its start (its GO's way to a
    real roadside): a walker let go that late, stepping off its lag after that and
    walking its slowest, is on each stretch of the crossing only while its slot holds
    that stretch; the same slot without the allowance would hold it only by the last
    step's margin (``clear_s``), which is not the link's to spend. A slot the
    roadside never let go is dropped (UNLIT), and the walker's next ask is a new slot;
    the ICA's walkers allow the configured lateness."""
    from dica.ica.core.config import IcaConfig
    from dica.ica.core.crosswalk import BODY_M, CORNER_M
    from dica.ica.core.dica import Dica
    from dica.ica.core.walk import LAG_S, Walkways

    c = Crosswalk("c", np.array([[0.0, 0.0], [16.0, 0.0]]), 4.0)
    late, plain = Walkways((c,), late_s=0.5), Walkways((c,))
    for side in (0, 1):
        walk = 4.0 + 16.0 + CORNER_M  # from the kerb 4 m short, off the corner beyond
        w = late.slot("amy", "c", 10.0, walk, side=side, near_m=4.0)
        w0 = plain.slot("amy", "c", 10.0, walk, side=side, near_m=4.0)
        assert w.end_s == pytest.approx(w0.end_s + 0.5) and w.late_s == 0.5
        off = 10.0 + 0.5 + LAG_S  # let go late, stepping off its lag after that
        lost = False
        for u in np.arange(0.0, 16.0, 0.5):
            along = u if side == 0 else 16.0 - u  # metres walked on the crossing
            leaves = off + (4.0 + along + BODY_M) / w.v_lo  # its body's reach past u
            assert leaves <= w.over(u, u, 16.0, late.clear_s)[1] + 1e-9
            lost |= leaves > w0.over(u, u, 16.0, plain.clear_s)[1] - plain.clear_s + 1e-9
        assert lost
        assert off + walk / w.v_lo + late.clear_s <= w.end_s + 1e-9
    x = load_intersection(walk_net, "B1")
    ica = Dica(x, IcaConfig(green_late_s=0.3))
    first = ica.walk("amy", ":B1_c3", 0.0, 0.0)
    assert first.late_s == 0.3
    assert not ica.unwalk("amy", ":B1_c3", first.start_s + 1.0)  # not that slot
    assert ica.unwalk("amy", ":B1_c3", first.start_s)
    assert ica.walks.slot_of("amy", ":B1_c3") is None
    assert not ica.unwalk("amy", ":B1_c3", first.start_s)  # told twice: once
    again = ica.walk("amy", ":B1_c3", 0.0, 2.0)
    assert again is not first and again.start_s >= 2.0


def test_walkers_are_forgotten_once_across_and_bad_asks_refused(walk_net):
    from dica.ica.core.dica import Dica
    from dica.ica.core.request import RequestError

    x = load_intersection(walk_net, "B1")
    ica = Dica(x)
    slot = ica.walk("amy", ":B1_c1", 0.0, 0.0)
    ica.advance(slot.end_s + 0.1)
    assert ica.walks.slots[":B1_c1"] == []
    with pytest.raises(RequestError, match="no crossing"):
        ica.walk("amy", ":A0_c0", 0.0, 0.0)
    with pytest.raises(RequestError, match="not finite"):
        ica.walk("amy", ":B1_c1", math.nan, 0.0)
    # the shortest way to the crossing: 0 and up, finite; never past the longest way
    for bad in (-1e-9, math.inf, math.nan):
        with pytest.raises(RequestError, match="distance is not one"):
            ica.walk("bob", ":B1_c1", 0.0, 0.0, near_m=3.0, near_lo_m=bad)
    assert ica.walk("cyd", ":B1_c1", 0.0, 0.0, near_m=3.0, near_lo_m=0.0).near_lo_m == 0.0
    assert ica.walk("dee", ":B1_c1", 0.0, 0.0, near_m=3.0, near_lo_m=5.0).near_lo_m == 3.0


# -- over Zenoh ------------------------------------------------------------------------
@pytest.mark.cluster
def test_the_ica_process_gives_walkers_their_slot_and_keeps_it_over_a_restart(walk_net, tmp_path):
    """WALK on dica/<j>/walk/gateway: a GO with the slot; anyone else refused; the slot
    journalled, so the restarted ICA still delays a vehicle through that crossing."""
    from dica.ica.convert import request_from_core
    from dica.ica.core.dica import Dica
    from dica.ica.core.proposal import propose
    from dica.schemas import keys
    from dica.schemas.codec import decode, encode, now_ns
    from dica.schemas.messages import Ack, Across, Clock, Detect, Go, Reject, Response, Walk
    from dica.tools.loopback import router_and_ica

    def ask(session, key, msg):
        (r,) = [r for r in session.get(key, payload=encode(msg), timeout=5.0) if r.ok]
        return decode(r.ok.payload.to_bytes())

    def end(session, ica, k):
        session.put(keys.clock("B1"), encode(Clock(k, 0.05 * k, "lockstep", 1.0, True, now_ns())))
        assert ica.wait(15) == 0

    args = ("--net", str(walk_net), "--junction", "B1", "--out", str(tmp_path))
    with router_and_ica("B1", args) as (session, ica):
        heard = []  # the slots the ICA publishes for observers
        sub = session.declare_subscriber(keys.walks("B1"), lambda s: heard.append(s))
        go = ask(
            session,
            keys.walk("B1", "gateway"),
            Walk("amy", ":B1_c1", 0.0, 0.0, 0.0, 0, 0.0, 0.0, now_ns()),
        )
        assert isinstance(go, Go) and go.person == "amy" and go.start_s == 0.0
        assert go.end_s == pytest.approx(3.0 + 12.8 + 6.0 + 2.0)
        no = ask(
            session,
            keys.walk("B1", "agent-1"),
            Walk("bob", ":B1_c1", 0.0, 0.0, 0.0, 0, 0.0, 0.0, now_ns()),
        )
        assert isinstance(no, Reject) and "only the roadside" in no.detail
        no = ask(
            session,
            keys.walk("B1", "gateway"),
            Walk("bob", ":Z_c9", 0.0, 0.0, 0.0, 0, 0.0, 0.0, now_ns()),
        )
        assert isinstance(no, Reject) and no.reason == "bad_state"
        again = ask(
            session,
            keys.walk("B1", "gateway"),
            Walk("amy", ":B1_c1", 3.0, 0.0, 0.0, 0, 0.0, 0.0, now_ns()),
        )
        same = ("person", "crossing", "start_s", "end_s", "side", "near_m", "v_lo", "v_hi")
        assert [getattr(again, f) for f in same] == [getattr(go, f) for f in same]
        # published once, whole: an observer draws the walker's reservation from it
        (pub,) = [decode(s.payload.to_bytes(), Go) for s in heard]
        assert str(heard[0].key_expr) == keys.walks("B1", "amy") and pub == go
        assert (pub.v_lo, pub.v_hi) == (1.0, 2.5) and go.start_s < pub.eta_s <= go.end_s
        sub.undeclare()
        done = ask(session, keys.walk("B1", "gateway"), Across("zed", ":B1_c1", 1.0, now_ns()))
        assert isinstance(done, Ack) and done.of == "across"  # a walker it never had: no harm
        (bad,) = [r for r in session.get(keys.walk("B1", "gateway"), payload=b"\x93\x01",
                                         timeout=5.0) if r.ok]  # fmt: skip
        assert decode(bad.ok.payload.to_bytes()).reason == "bad_message"
        end(session, ica, 1)
    with router_and_ica("B1", args) as (session, ica):  # the same journal
        x = load_intersection(walk_net, "B1")
        route = x.route("A1B1_1", "B1C1_1")  # leaves over :B1_c1
        session.put(keys.clock("B1"), encode(Clock(1, 0.05, "lockstep", 1.0, False, now_ns())))
        det = Detect("car", route.in_lane, 0.0, False, 10.0, now_ns())
        assert isinstance(ask(session, keys.detect("B1", "a"), det), Ack)
        req = propose(route, vin="car", seq=0, t0_s=0.05, dist_to_entry_m=30.0, speed_mps=10.0)
        got = ask(session, keys.request("B1", "a"), request_from_core(req))
        assert isinstance(got, Response)
        alone = Dica(x)
        alone.detect("car", route.in_lane, 0.0)
        free = alone.handle(req, 0.05)
        assert got.entry_time_s > free.entry_time_s + 1.0  # it waits for amy
        end(session, ica, 2)
    stats = json.loads((tmp_path / "ica.json").read_text())
    first, second = stats["incarnations"]
    assert first["walks"] == 1 and first["repeated"] == 1 and stats["walks"] == 1
    assert second["journal_replayed"]["walks"] == 1


def test_a_walkers_go_dropped_late_frees_its_slot_on_the_ica_and_over_a_restart(walk_net, tmp_path):
    """An ICA told the roadside may let walkers go up to 0.3 s late (--green-late): its GO
    says so and its slot allows for it; the roadside's UNLIT for that crossing (the GO
    came too late, the walker stayed at its kerb) frees the slot, once however often
    told, and an agent's is refused; journalled, so the restarted ICA lets a car through
    where the slot was, which it made wait while the slot stood."""
    from dica.ica.convert import request_from_core
    from dica.ica.core.dica import Dica
    from dica.ica.core.proposal import propose
    from dica.schemas import keys
    from dica.schemas.codec import decode, encode, now_ns
    from dica.schemas.messages import Ack, Clock, Detect, Go, Reject, Response, Unlit, Walk
    from dica.tools.loopback import router_and_ica

    def ask(session, key, msg):
        (r,) = [r for r in session.get(key, payload=encode(msg), timeout=5.0) if r.ok]
        return decode(r.ok.payload.to_bytes())

    def clock(session, ica, k, end):
        session.put(keys.clock("B1"), encode(Clock(k, 0.05 * k, "lockstep", 1.0, end, now_ns())))
        if end:
            assert ica.wait(15) == 0

    x = load_intersection(walk_net, "B1")
    route = x.route("A1B1_1", "B1C1_1")  # leaves over :B1_c1
    req = propose(route, vin="car", seq=0, t0_s=0.05, dist_to_entry_m=30.0, speed_mps=10.0)
    alone = Dica(x)
    alone.detect("car", route.in_lane, 0.0)
    free = alone.handle(req, 0.05).entry_time_s
    args = ("--net", str(walk_net), "--junction", "B1", "--out", str(tmp_path),
            "--green-late", "0.3")  # fmt: skip
    gw = keys.walk("B1", "gateway")
    with router_and_ica("B1", args) as (session, ica):
        walk = Walk("amy", ":B1_c1", 0.0, 0.0, 0.0, 0, 0.0, 0.0, now_ns())
        go = ask(session, gw, walk)
        assert isinstance(go, Go) and go.late_s == pytest.approx(0.3)
        assert go.end_s == pytest.approx(0.3 + 3.0 + 12.8 + 6.0 + 2.0)
        drop = Unlit("amy", 0.0, go.start_s, now_ns(), ":B1_c1")
        no = ask(session, keys.human("B1", "agent-1"), drop)
        assert isinstance(no, Reject) and "only the roadside" in no.detail
        for _ in range(2):  # told twice (a lost ACK): dropped once
            assert isinstance(ask(session, keys.human("B1", "gateway"), drop), Ack)
        elsewhere = Unlit("amy", 0.0, go.start_s, now_ns(), ":Z_c9")  # no crossing of B1
        no = ask(session, keys.human("B1", "gateway"), elsewhere)
        assert isinstance(no, Reject) and no.reason == "bad_state"
        clock(session, ica, 1, False)
        det = Detect("car", route.in_lane, 0.0, False, 10.0, now_ns())
        assert isinstance(ask(session, keys.detect("B1", "a"), det), Ack)
        got = ask(session, keys.request("B1", "a"), request_from_core(req))
        assert isinstance(got, Response) and got.entry_time_s < free + 1.0  # amy's slot gone
        clock(session, ica, 2, True)
    with router_and_ica("B1", args) as (session, ica):  # the same journal
        clock(session, ica, 1, False)
        again = ask(session, gw, Walk("amy", ":B1_c1", 0.05, 0.0, 0.0, 0, 0.0, 0.0, now_ns()))
        assert isinstance(again, Go) and again.start_s >= 0.05  # a new slot, not the dropped
        clock(session, ica, 2, True)
    first, second = json.loads((tmp_path / "ica.json").read_text())["incarnations"]
    assert first["unlit"] == 1 and second["journal_replayed"]["walks"] == 1


def test_a_plan_held_far_ahead_by_walkers_waits_its_turn_but_never_for_ever(walk_net):
    """A plan that would hold a crossing more than HOLD_AHEAD_S ahead is refused (walkers
    asking meanwhile would wait for it); the vehicle asking on for CLAIM_S is confirmed
    anyway, so walkers cannot keep it out."""
    from dica.ica.core.dica import Dica
    from dica.ica.core.proposal import propose
    from dica.ica.core.request import Confirmation, Reason, Rejection
    from dica.ica.core.walk import CLAIM_S, HOLD_AHEAD_S

    x = load_intersection(walk_net, "B1")
    ica = Dica(x)
    through = x.route("A1B1_1", "B1C1_1")
    ica.walk("slow", ":B1_c1", 0.0, 0.0, speed_mps=0.1, side=0)  # 0.08 m/s: a long walk
    ica.detect("car", through.in_lane, 0.0)

    def ask(t: float, seq: int):
        req = propose(through, vin="car", seq=seq, t0_s=t, dist_to_entry_m=0.5, speed_mps=0.0,
                      config=ica.config)  # fmt: skip
        return ica.handle(req, t)

    first = ask(0.0, 0)
    assert isinstance(first, Rejection) and first.reason is Reason.WALKERS
    assert f"at most {HOLD_AHEAD_S:.0f} s ahead" in first.detail
    assert isinstance(ask(CLAIM_S / 2, 1), Rejection)  # still its turn to wait
    got = ask(CLAIM_S + 0.5, 2)
    assert isinstance(got, Confirmation) and ica.walk_claims == 1
    assert got.entry_time_s > CLAIM_S + HOLD_AHEAD_S - 10.0  # after the slow walker


def test_no_walker_waits_past_the_bound_and_no_claim_holds_a_crossing_beyond_it(walk_net):
    """A walker who cannot join the phase that has begun starts a new one at most
    WAIT_BOUND_S after it asked, even when the window after that phase would end later;
    a vehicle that claims its turn may not hold a crossing further ahead than that."""
    from dica.ica.core.dica import Dica
    from dica.ica.core.proposal import propose
    from dica.ica.core.request import Confirmation, Reason, Rejection
    from dica.ica.core.walk import CLAIM_S, WAIT_BOUND_S

    x = load_intersection(walk_net, "B1")
    ica = Dica(x)
    through = x.route("A1B1_1", "B1C1_1")
    slow = ica.walk("slow", ":B1_c1", 0.0, 0.0, speed_mps=0.1, side=1)  # 0.08 m/s
    assert slow.start_s == 0.0 and slow.eta_s > 150.0  # the phase: one very long walk
    ica.detect("car", through.in_lane, 0.0)  # a vehicle waits for a plan

    def ask(t: float, seq: int):
        req = propose(through, vin="car", seq=seq, t0_s=t, dist_to_entry_m=0.5, speed_mps=0.0,
                      config=ica.config)  # fmt: skip
        return ica.handle(req, t)

    # the window after the phase would start the next one after 185 s: the bound cuts it
    assert ica.walks.next_phase_s_for(True) > 1.0 + WAIT_BOUND_S
    amy = ica.walk("amy", ":B1_c0", 1.0, 1.0)
    assert amy.start_s == pytest.approx(1.0 + WAIT_BOUND_S)
    # the car, past the slow walker only well over 90 s ahead, is refused even as it claims
    for k, t in enumerate((10.0, 10.0 + CLAIM_S + 0.5, 10.0 + 2.0 * CLAIM_S)):
        got = ask(t, k)
        assert isinstance(got, Rejection) and got.reason is Reason.WALKERS
    assert f"at most {WAIT_BOUND_S:.0f} s ahead" in got.detail and ica.walk_claims == 0
    # once the walker is seen across, the car goes
    assert ica.walked("slow", ":B1_c1", 50.0)
    got = ask(50.0, 3)
    assert isinstance(got, Confirmation), got


def test_walkers_start_within_the_bound_among_vehicles_at_random(walk_net):
    """Walkers (some very slow) and vehicles past saturation asking at random on every
    crossing and route for ten minutes: every walker's start is within WAIT_BOUND_S of its
    ask, and no confirmed plan meets a walker's slot."""
    import random

    from dica.ica.core.dica import Dica
    from dica.ica.core.proposal import propose
    from dica.ica.core.request import Confirmation
    from dica.ica.core.walk import WAIT_BOUND_S

    x = load_intersection(walk_net, "B1")
    ica = Dica(x)
    rng = random.Random(21)
    crossings = [c.id for c in x.crosswalks]
    routes = list(x.routes)
    waiting: dict[str, tuple] = {}  # vin: (route, asks so far)
    slots, waits, n = [], [], 0
    t = 0.0
    while t < 600.0:
        if rng.random() < 0.2:  # some 1,400 walkers an hour over the junction, some slow
            c = rng.choice(crossings)
            slot = ica.walk(f"p{len(slots)}", c, t, t, speed_mps=rng.uniform(0.3, 1.6),
                            side=rng.randrange(2), near_m=rng.uniform(0.0, 6.0))  # fmt: skip
            assert slot.start_s <= t + WAIT_BOUND_S + 1e-9
            waits.append(slot.start_s - t)
            assert not any(_clash(ica, vin, slot) for vin in ica.confirmed)
            slots.append(slot)
        if rng.random() < 0.3:
            vin = f"v{n}"
            n += 1
            ica.detect(vin, (r := rng.choice(routes)).in_lane, t)
            waiting[vin] = (r, 0)
        for vin, (r, k) in list(waiting.items()):
            got = ica.handle(propose(r, vin=vin, seq=k, t0_s=t, dist_to_entry_m=30.0,
                                     speed_mps=10.0, config=ica.config), t)  # fmt: skip
            if isinstance(got, Confirmation):
                del waiting[vin]
                assert not any(_clash(ica, vin, s) for s in slots)
            else:
                waiting[vin] = (r, k + 1)
        ica.walks.advance(t - 300.0)  # keep the slots of the last minutes in the book
        t += 0.5
    assert len(slots) > 200 and n - len(waiting) > 200, (len(slots), n, len(waiting))
    # the slow walkers and the claims stack up the phases: the bound is what stops them
    assert max(waits) > 0.9 * WAIT_BOUND_S and ica.walk_claims > 10


def _clash(ica, vin: str, slot) -> bool:
    """:func:`_meets`, for a vehicle whose route may not pass ``slot``'s crossing."""
    c = ica.confirmed[vin]
    passes = {cid for cid, _a, _b in ica.crossing_spans(c.dtot.route, c.dtot.shape)}
    return slot.crossing in passes and _meets(ica, vin, slot)


def test_a_restarted_ica_keeps_walkers_slots_and_what_was_seen_across(walk_net, tmp_path):
    """The journal holds each slot whole (where the walker stands, its pace, its expected
    end) and each ACROSS: replayed into a fresh core, the slots are the same, the one
    seen across ends where it was seen, and a repeat of either changes nothing."""
    from dica.ica.core.dica import Dica
    from dica.ica.journal import Journal, replay

    x = load_intersection(walk_net, "B1")
    ica = Dica(x)
    amy = ica.walk("amy", ":B1_c1", 0.0, 0.0, walk_m=20.0, speed_mps=1.3, side=1, near_m=2.5)
    bob = ica.walk("bob", ":B1_c1", 0.5, 0.5)
    assert ica.walked("amy", ":B1_c1", amy.start_s + 8.0)
    journal = Journal(tmp_path / "ica.journal", sync=False)
    journal.walk(amy)
    journal.walk(bob)
    journal.across("amy", ":B1_c1", amy.start_s + 8.0)
    journal.walk(amy)  # written twice (a repeated WALK): still one slot
    journal.across("amy", ":B1_c1", amy.start_s + 12.0)  # later than the end: no change
    journal.close()
    again = Dica(x)
    got = replay(tmp_path / "ica.journal", again)
    assert got.walks == 3
    assert again.walks.slots[":B1_c1"] == ica.walks.slots[":B1_c1"]
    assert again.walks.slot_of("amy", ":B1_c1").end_s == pytest.approx(amy.start_s + 8.0)
    assert again.walks.slot_of("bob", ":B1_c1") == bob


# -- walkers and human drivers -------------------------------------------------------
def _envelope_holds(ica, vin: str, crossing: str, limits) -> list[tuple[float, float]]:
    """Each of human ``vin``'s reservations on ``crossing``: from its fastest touch to
    its slowest leaving, worked out here from the bounds its green was given with."""
    from dica.ica.core.envelope import first_reach, green_bounds
    from dica.ica.core.walk import hold

    g = ica.greens[vin]
    out = []
    for key in g.keys:
        c = ica.confirmed[key]
        r, shape = c.dtot.route, c.dtot.shape
        fast, slow = green_bounds(r, c.length_m, g.green_s, ica.config.step_s, limits,
                                  g.near_m, g.speed_mps)  # fmt: skip
        for cid, a, b in ica.crossing_spans(r, shape):
            if cid == crossing:
                v = (slow.s_m[-1] - slow.s_m[-2]) / slow.step_s
                out.append((float(first_reach(fast, np.array([a]))[0]), hold(slow, a, b, v)[1]))
    return out


def test_a_human_drivers_green_and_a_walkers_slot_keep_clear_of_each_other(walk_net):
    """A walker's slot on a crossing every route of a human's lane passes: a green that
    would hold the crossing far ahead (walkers asking meanwhile would wait for it) is
    refused, and later the green comes only once the slot is past its envelope's
    stretch; a walker asking after a green starts once every envelope on its way has
    left, counted from the human's fastest touch (not its slowest)."""
    from dica.ica.core.dica import Dica
    from dica.ica.core.envelope import human_limits
    from dica.ica.core.request import Reason, RequestError

    x = load_intersection(walk_net, "B1")
    limits = human_limits(max(r.road_mps for r in x.routes))
    lane = "A1B1_1"  # west, the inner lane: through to the east, and left to the north
    crossing = ":B1_c3"  # over the west arm, which every route of the lane passes first
    assert all(any(c == crossing for c, _, _ in ica_spans) for ica_spans in (
        Dica(x).crossing_spans(r, _shape()) for r in x.routes_from(lane) if r.cars))  # fmt: skip
    # a walker first: the human's green waits until the slot is off its stretch
    ica = Dica(x)
    slot = ica.walk("amy", crossing, 0.0, 0.0, near_m=2.0)
    ica.detect("h", lane, 0.0)
    with pytest.raises(RequestError) as e:  # after the walk, 25 s ahead or more: not yet
        ica.green("h", 0.0, 4.5, 1.8, limits)
    assert e.value.reason == Reason.WALKERS
    ica.advance(10.0)
    g = ica.green("h", 10.0, 4.5, 1.8, limits)
    assert g.green_s > slot.start_s + 10.0
    lone = Dica(x)
    lone.detect("h", lane, 0.0)
    assert lone.green("h", 0.0, 4.5, 1.8, limits).green_s == 0.0  # alone: at once
    for t_in, t_out in _envelope_holds(ica, "h", crossing, limits):
        assert not _slot_meets(ica, slot, "h", t_in, t_out)
    # the human first: a walker after it starts once the envelopes have left its way
    ica = Dica(x)
    ica.detect("h", lane, 0.0)
    ica.green("h", 0.0, 4.5, 1.8, limits, 25.0, 10.0)  # rolling, at once
    late = ica.walk("bob", crossing, 0.0, 0.0, near_m=2.0)
    holds = _envelope_holds(ica, "h", crossing, limits)
    assert all(not _slot_meets(ica, late, "h", a, b) for a, b in holds)
    assert late.start_s > min(a for a, _ in holds)
    # refused for holding a crossing too far ahead, its time counts towards its claim (as
    # a plan's does: after 20 s it may hold one up to 90 s ahead, so it cannot starve)
    ica = Dica(x)
    ica.walk("amy", crossing, 0.0, 0.0, near_m=2.0)
    ica.detect("h", lane, 0.0)
    with pytest.raises(RequestError):
        ica.green("h", 0.0, 4.5, 1.8, limits)
    assert ica._walk_refused == {"h": 0.0}


def _shape():
    from dica.ica.core.zones import Shape

    return Shape.of(4.5, 1.8)


def _slot_meets(ica, slot, vin: str, t_in: float, t_out: float) -> bool:
    c = ica.confirmed[vin]
    u_lo, u_hi = ica.crossing_reach(c.dtot.route, c.dtot.shape)[slot.crossing]
    length = ica.walks.crosswalks[slot.crossing].length_m
    a, b = slot.over(u_lo, u_hi, length, ica.walks.clear_s)
    pad, gap = 2.0 * ica.config.time_pad_s, ica.walks.gap_s
    return b > a and a - gap < t_out + pad - 1e-9 and b + gap > t_in - pad + 1e-9
