"""The fixed-cycle re-timing: the dissertation's cycle model and proportional greens."""

from __future__ import annotations

import math

import pytest

from sim_gateway.signals import LOST_PER_PHASE_S, YELLOW_S, cycle_length_s, retime

STATES = ["GGgr", "yyyr", "rrrG", "rrry"]
LANES = ["a_0", "a_1", "b_0", "c_0"]


def test_cycle_model():
    assert cycle_length_s(16.0, 0.0) == pytest.approx(24.0)
    assert cycle_length_s(16.0, 0.5) == pytest.approx(24.0 * math.exp(0.9))


def test_greens_share_the_effective_green_by_critical_flow_ratio():
    flows = {"a_0": 900.0, "a_1": 450.0, "b_0": 1000.0, "c_0": 360.0}
    durations, timing = retime(STATES, LANES, flows)
    y1 = 900.0 / 1800.0  # 'G' lanes of phase 0: a_0, a_1 (b_0 is only permissive 'g')
    y2 = 360.0 / 1800.0
    assert timing.flow_ratio_sum == pytest.approx(y1 + y2)
    lost = 2 * LOST_PER_PHASE_S
    cycle = cycle_length_s(lost, y1 + y2)
    assert sum(durations) == pytest.approx(cycle)
    assert durations[1] == durations[3] == YELLOW_S
    g_eff = [durations[0] + YELLOW_S - LOST_PER_PHASE_S, durations[2] + YELLOW_S - LOST_PER_PHASE_S]
    assert g_eff[0] / g_eff[1] == pytest.approx(y1 / y2)
