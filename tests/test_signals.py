"""Light baselines: clearance from the formulas, the dissertation's cycle model on
top, and real SUMO runs of both lights on junctions signalised by netconvert."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from dica.sim_gateway.signals import (
    ALL_RED,
    GREEN,
    LOST_PER_PHASE_S,
    YELLOW,
    SignalLink,
    all_red_time_s,
    cycle_length_s,
    phases_of,
    retime,
    with_clearance,
    yellow_time_s,
)
from tests.dica_cli import DICA, dica_run

ROOT = Path(__file__).resolve().parents[1]
STATES = ["GGgr", "yyyr", "rrrG", "rrry"]
LANES = ["a_0", "a_1", "b_0", "c_0"]
FAST = SignalLink("a_0", 19.44, 20.0, 19.44)  # through at the road limit
TURN = SignalLink("b_0", 19.44, 25.0, 8.0)  # a left turn taken at 8 m/s
LINKS = [FAST, FAST, TURN, SignalLink("c_0", 13.9, 12.0, 6.0)]


def test_formulas():
    assert yellow_time_s(18.0) == pytest.approx(1.0 + 18.0 / 6.0)
    assert all_red_time_s(20.0, 5.0, 12.5) == pytest.approx(2.0)


def test_clearance_inserts_all_red_and_never_shortens_the_nets_own():
    phases = phases_of([30.0, 6.0, 10.0, 2.0], STATES)
    assert [p.kind for p in phases] == [GREEN, YELLOW, GREEN, YELLOW]
    out = with_clearance(phases, LINKS, 5.0)
    assert [p.kind for p in out] == [GREEN, YELLOW, ALL_RED, GREEN, YELLOW, ALL_RED]
    assert out[1].duration_s == 6.0  # the net's own 6 s beats 1 + 19.44 / 6
    assert out[4].duration_s == pytest.approx(yellow_time_s(13.9))  # 2 s was too short
    assert out[2].state == "rrrr" and out[5].state == "rrrr"
    # the slowest link decides: the left turn at 8 m/s
    assert out[2].duration_s == pytest.approx(all_red_time_s(25.0, 5.0, 8.0))
    assert out[5].duration_s == pytest.approx(all_red_time_s(12.0, 5.0, 6.0))
    assert out[0] == phases[0] and out[3] == phases[2]  # greens untouched


def test_clearance_keeps_continuing_greens_and_lengthens_own_all_red():
    # link 2 stays green through the change (a permissive left becoming protected)
    phases = phases_of([30.0, 4.0, 9.0, 10.0, 4.0], ["GGgr", "yyGr", "rrGr", "rrGG", "rryy"])
    assert [p.kind for p in phases] == [GREEN, YELLOW, ALL_RED, GREEN, YELLOW]
    out = with_clearance(phases, LINKS, 5.0)
    assert [p.kind for p in out] == [GREEN, YELLOW, ALL_RED, GREEN, YELLOW, ALL_RED]
    assert out[2].state == "rrGr"
    assert out[2].duration_s == 9.0  # the net's own all-red was longer
    assert out[5].state == "rrrr"


def test_clearance_wraps_round_the_cycle():
    phases = phases_of([1.0, 30.0, 3.0], ["rrrr", "GGrr", "yyrr"])
    assert [p.kind for p in phases] == [ALL_RED, GREEN, YELLOW]
    out = with_clearance(phases, LINKS, 5.0)
    assert [p.kind for p in out] == [ALL_RED, GREEN, YELLOW]
    assert out[0].duration_s == pytest.approx(all_red_time_s(20.0, 5.0, 19.44))


def test_cycle_model():
    assert cycle_length_s(16.0, 0.0) == pytest.approx(24.0)
    assert cycle_length_s(16.0, 0.5) == pytest.approx(24.0 * math.exp(0.9))


def test_greens_share_the_effective_green_by_critical_flow_ratio():
    flows = {"a_0": 900.0, "a_1": 450.0, "b_0": 1000.0, "c_0": 360.0}
    phases = with_clearance(phases_of([30.0, 3.0, 10.0, 3.0], STATES), LINKS, 5.0)
    out, timing = retime(phases, LANES, flows)
    y1 = 900.0 / 1800.0  # 'G' lanes of phase 0: a_0, a_1 (b_0 is only permissive 'g')
    y2 = 360.0 / 1800.0
    assert timing.flow_ratio_sum == pytest.approx(y1 + y2)
    clear = [out[1].duration_s + out[2].duration_s, out[4].duration_s + out[5].duration_s]
    lost = [max(LOST_PER_PHASE_S, c) for c in clear]
    cycle = cycle_length_s(sum(lost), y1 + y2)
    assert sum(p.duration_s for p in out) == pytest.approx(cycle)
    assert timing.cycle_s == pytest.approx(cycle)
    g_eff = [out[0].duration_s + clear[0] - lost[0], out[3].duration_s + clear[1] - lost[1]]
    assert g_eff[0] / g_eff[1] == pytest.approx(y1 / y2)
    assert [p.duration_s for k, p in enumerate(out) if k not in (0, 3)] == [
        p.duration_s for k, p in enumerate(phases) if k not in (0, 3)
    ]


def test_dissertation_timing_without_all_red_is_unchanged():
    """3 s yellow, no all-red, lost time 4 s a phase: greens get 1 s beyond their share."""
    phases = phases_of([30.0, 3.0, 10.0, 3.0], STATES)
    out, timing = retime(phases, LANES, {"a_0": 900.0, "c_0": 360.0})
    cycle = cycle_length_s(2 * LOST_PER_PHASE_S, 0.7)
    assert timing.cycle_s == pytest.approx(cycle)
    assert out[0].duration_s == pytest.approx((cycle - 8.0) * 0.5 / 0.7 + 1.0)


@pytest.mark.parametrize("algorithm", ["fixed", "actuated"])
@pytest.mark.parametrize("junction", ["skewed", "tee"])
def test_lights_never_collide_on_junctions_signalised_by_netconvert(
    request, tmp_path, junction, algorithm
):
    """Volume 500 on a skewed 4-way and a T junction without lights: each is
    signalised in the run directory, and neither light lets two vehicles touch.
    (Before the clearance times, the fixed light on the skewed junction had
    SUMO collisions within 150 s of this seed.)"""
    net = request.getfixturevalue(f"{junction}_net")
    out = tmp_path / "run"
    args = ["--net", str(net), "--junction", "J", "--algorithm", algorithm, "--volume", "500"]
    args += ["--duration", "180", "--seed", "12", "--out", str(out), "--quiet"]
    p = dica_run(
        [*DICA, "run", *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=600,
    )
    assert p.returncode == 0, p.stdout + p.stderr
    assert "had no traffic light: signalised by netconvert" in p.stderr
    assert list(out.glob(f"*-tls-{'static' if algorithm == 'fixed' else 'actuated'}.net.xml"))
    m = json.loads((out / "metrics.json").read_text())
    assert m["collisions"] == 0 and m["sumo_collisions"] == 0
    assert m["crossed"] > 60
    signal = json.loads((out / "config.json").read_text())["signal"]
    kinds = [kind for _, _, kind in signal["phases"]]
    assert kinds.count(ALL_RED) == kinds.count(YELLOW) >= 2
    assert all(d >= 5.0 for d, _, kind in signal["phases"] if kind == YELLOW)  # netconvert's 5 s
