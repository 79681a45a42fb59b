"""Max-pressure signal control (Varaiya 2013), the standard adaptive network controller
of the signal-control literature: at each junction, after a minimum green, give green to
the phase whose movements have the most pressure (vehicles waiting to go less vehicles
on the lanes they go to), through the program's own yellow and all-red.

Each light keeps the phase plan netconvert built for it (its greens, which links
each lets go) and its clearance times; only the order and length of the greens
are decided here, every step, from the lanes' vehicle counts. Pressure uses no
forecast and no coordination, which is what makes it decentralised and, in
theory, throughput-optimal.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

MIN_GREEN_S = 8.0  # [s] a green lasts at least this long before pressure may end it


@dataclass(slots=True)
class _Light:
    tls: str
    greens: list[str]  # the program's green states
    # per green, its movements: (incoming lane, outgoing lane) pairs it lets go
    moves: list[list[tuple[str, str]]]
    yellow_s: float
    red_s: float
    current: int = 0
    since_s: float = 0.0
    # the clearance under way: (state, until) steps, then the next green
    plan: list[tuple[str, float]] = field(default_factory=list)
    next_green: int = 0


class MaxPressure:
    """Max-pressure control of the net's lights ``lights`` (ids) through TraCI."""

    def __init__(self, ls, lights: Iterable[str], min_green_s: float = MIN_GREEN_S) -> None:
        self.ls = ls
        self.min_green_s = min_green_s
        self.lights = [self._light(t) for t in lights]
        self.switches = 0
        for x in self.lights:
            ls.trafficlight.setRedYellowGreenState(x.tls, x.greens[0])

    def _light(self, tls: str) -> _Light:
        tl = self.ls.trafficlight
        logic = tl.getAllProgramLogics(tls)[0]
        links = tl.getControlledLinks(tls)
        greens, moves = [], []
        yellow = red = 0.0
        for p in logic.phases:
            s = p.state
            if "y" in s or "Y" in s:
                yellow = max(yellow, p.duration)
            elif not any(c in "Gg" for c in s):
                red = max(red, p.duration)
            elif s not in greens:
                greens.append(s)
                pairs = {(ln[0][0], ln[0][1]) for i, ln in enumerate(links) if ln and s[i] in "Gg"}
                moves.append(sorted(pairs))
        return _Light(tls, greens, moves, yellow, red)

    def step(self, t_s: float) -> None:
        """Advance every light to ``t_s``: finish clearances, maybe start one."""
        counts: dict[str, int] = {}

        def n(lane: str) -> int:
            if lane not in counts:
                counts[lane] = self.ls.lane.getLastStepVehicleNumber(lane)
            return counts[lane]

        tl = self.ls.trafficlight
        for x in self.lights:
            if x.plan:
                while x.plan and t_s >= x.plan[0][1] - 1e-9:
                    x.plan.pop(0)
                    if x.plan:
                        tl.setRedYellowGreenState(x.tls, x.plan[0][0])
                if not x.plan:
                    x.current, x.since_s = x.next_green, t_s
                    tl.setRedYellowGreenState(x.tls, x.greens[x.current])
                continue
            if len(x.greens) < 2 or t_s - x.since_s < self.min_green_s:
                continue
            pressure = [sum(n(a) - n(b) for a, b in m) for m in x.moves]
            best = max(range(len(pressure)), key=lambda i: (pressure[i], i == x.current))
            if best != x.current and pressure[best] > pressure[x.current]:
                self._clear(x, best, t_s)

    def _clear(self, x: _Light, to: int, t_s: float) -> None:
        """Yellow on the links that lose green, then all red, then green ``to``."""
        old, new = x.greens[x.current], x.greens[to]
        yellow = "".join(
            c if c in "Gg" and new[i] in "Gg" else ("y" if c in "Gg" else "r")
            for i, c in enumerate(old)
        )
        red = "".join("r" if c == "y" else c for c in yellow)
        x.plan = [(yellow, t_s + x.yellow_s), (red, t_s + x.yellow_s + x.red_s)]
        x.next_green = to
        self.switches += 1
        self.ls.trafficlight.setRedYellowGreenState(x.tls, yellow)
