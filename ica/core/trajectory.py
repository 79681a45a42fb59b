"""Sampled trajectories along a route: the TSS in the route's own coordinate."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dica.ica.core.kernels.dtot import entry_time
from dica.ica.core.kernels.planner import profile_position
from dica.ica.core.kernels.route import front_heading, tss_of
from dica.ica.core.planner import Profile
from dica.ica.core.route import Route


@dataclass(frozen=True, slots=True, eq=False)
class Trajectory:
    """Front-bumper arc length ``s_m`` [m] sampled every ``step_s`` from ``t0_s``.

    Between samples a vehicle moves at constant speed, which is exactly what
    SUMO does with ``setSpeed((s[k+1] - s[k]) / step)`` each step, so a
    confirmed trajectory is flown without tracking error in simulation.
    """

    t0_s: float
    step_s: float
    s_m: np.ndarray

    def __len__(self) -> int:
        return len(self.s_m)

    def shifted(self, dt_s: float) -> Trajectory:
        """The same positions ``dt_s`` later (earlier if negative): a plan run late or
        early by the time pad."""
        return Trajectory(self.t0_s + dt_s, self.step_s, self.s_m)

    @property
    def t_s(self) -> np.ndarray:
        return self.t0_s + self.step_s * np.arange(len(self.s_m))

    def speeds(self) -> np.ndarray:
        """Speed over each step [m/s], (N-1,)."""
        return np.diff(self.s_m) / self.step_s

    def entry_index(self) -> int:
        """Index of the last sample before the front passes the entry line (s > 0)."""
        inside = np.nonzero(self.s_m > 0.0)[0]
        if len(inside) == 0:
            return len(self.s_m) - 1
        return max(int(inside[0]) - 1, 0)

    def entry_speed_mps(self) -> float:
        """Speed over the step in which the front passes the entry line, at least
        0.1 m/s (a separation needs a vehicle that moves)."""
        k = min(self.entry_index(), len(self.s_m) - 2)
        return max(float(self.s_m[k + 1] - self.s_m[k]) / self.step_s, 0.1)

    def exit_index(self, s_end_m: float) -> int:
        """Index of the first sample at which the front is at ``s_end_m`` or beyond."""
        out = np.nonzero(self.s_m >= s_end_m - 1e-9)[0]
        return int(out[0]) if len(out) else len(self.s_m) - 1

    def entry_time_s(self) -> float:
        """Time the front reaches s = 0, linear between samples as the vehicle moves
        (compiled, :func:`ica.core.kernels.dtot.entry_time`; :meth:`entry_time_reference`)."""
        if len(self.s_m) == 0:
            raise ValueError("a trajectory without samples has no entry time")
        return entry_time(self.t0_s, self.step_s, np.asarray(self.s_m, dtype=float))

    def entry_time_reference(self) -> float:
        """:meth:`entry_time_s` in numpy."""
        k = self.entry_index()
        if self.s_m[k] > 0.0 or k + 1 >= len(self.s_m):
            return self.t0_s + k * self.step_s
        s0, s1 = self.s_m[k], self.s_m[k + 1]
        return self.t0_s + (k + (0.0 - s0) / (s1 - s0)) * self.step_s

    def tss(
        self, route: Route, length_m: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """As a TSS: times, front-bumper x and y, headings (:meth:`xy_heading`)."""
        xy = np.ascontiguousarray(route.xy, dtype=float)
        s = np.asarray(self.s_m, dtype=float)
        return tss_of(self.t0_s, self.step_s, s, float(length_m), route.s, xy)

    def xy_heading(self, route: Route, length_m: float) -> tuple[np.ndarray, np.ndarray]:
        """Front-bumper points (N, 2) and headings [rad, CCW from +x], rear-to-front."""
        xy = np.ascontiguousarray(route.xy, dtype=float)
        return front_heading(np.asarray(self.s_m, dtype=float), float(length_m), route.s, xy)


def sample(profile: Profile, t0_s: float, step_s: float, s_end_m: float) -> Trajectory:
    """Sample a plan from the request time until the front is at or past ``s_end_m``."""
    t_out = profile.time_at(s_end_m)
    if not math.isfinite(t_out):
        raise ValueError("plan never leaves the junction")
    n = math.ceil(t_out / step_s - 1e-9) + 1
    s = np.empty(n)  # profile.position(step_s * np.arange(n)), compiled
    profile_position(profile.t_s, profile.s_m, profile.v_mps, profile.a_mps2, step_s, s)
    return Trajectory(t0_s, step_s, s)
