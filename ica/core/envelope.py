"""Human drivers: every way a driver the ICA cannot command may cross once its signal
head turns green, as one reservation.

A human-driven vehicle stands at its lane's line until the head shows green. From
then on it is somewhere between two bounds, both derived from SUMO's default driver
(Krauss) and the limits the roadside states for human drivers (:class:`DriverLimits`):

- **fastest**: it moves at the green at once (a step early), accelerates at the type's full
  acceleration and reaches the type's top speed (the limit times the highest speed
  factor a human is given);
- **slowest**: it moves :attr:`DriverLimits.moves_s` late (its head may turn green up to
  :attr:`DriverLimits.late_s` after the green's time, a LIT's way to the roadside, and
  it reacts :attr:`DriverLimits.react_s` after that), accelerates at
  ``(1 - sigma)`` of it (Krauss's dawdling takes at most ``sigma * accel * step`` off
  each step's speed) and cruises at the lowest speed factor times the lowest limit on
  its way, less one step's dawdle.

Its front is then never ahead of the fast bound nor behind the slow one. The
envelope's timed occupancies are the slow bound's footprints, each held from the time
the fast bound could first touch it to the time the slow bound has surely left it
(:func:`envelope_dtot`), so any crossing between the bounds stays inside them, in
continuous time. A lane's routes are all reserved (the ICA cannot know where a human
turns). Pure: routes and numbers in, trajectories and DTOTs out.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from dica.ica.core.dtot import Dtot, build_dtot
from dica.ica.core.kernels.follow import Krauss
from dica.ica.core.kernels.follow import follow_delay as _follow_kernel
from dica.ica.core.route import Route
from dica.ica.core.trajectory import Trajectory
from dica.ica.core.zones import RouteGrid, Shape

STOP_SHORT_M = 0.5  # [m] a human stands this far short of its line at a red head
ROLL_DECEL_MPS2 = 4.5  # [m/s^2] the most a driver slowing for its red head brakes (SUMO's decel)
ROLL_NEAR_M = 60.0  # [m] a driver rolling towards its line is given a green from this near


@dataclass(frozen=True, slots=True)
class DriverLimits:
    """What the roadside assumes of a human driver (SUMO's Krauss with these limits)."""

    accel_mps2: float = 2.6  # SUMO's passenger car: Krauss never accelerates harder
    sigma: float = 0.5  # Krauss's imperfection
    speed_factor_min: float = 0.9  # each human's share of the limit is drawn in these bounds
    speed_factor_max: float = 1.1
    top_mps: float = 70.0 / 3.6 * 1.1  # the type's own top speed (never exceeded)
    react_s: float = 1.0  # [s] from the green until it surely moves
    # [s] how late after its green time the roadside may still turn a head green (the
    # LIT's way to it); a LIT later than that is dropped and the head stays red
    late_s: float = 0.0

    def __post_init__(self) -> None:
        if not (
            self.accel_mps2 > 0.0
            and 0.0 <= self.sigma < 1.0
            and 0.0 < self.speed_factor_min <= self.speed_factor_max
            and self.top_mps > 0.0
            and self.react_s >= 0.0
            and 0.0 <= self.late_s <= 10.0
        ):
            raise ValueError(f"driver limits out of range: {self}")

    @property
    def moves_s(self) -> float:
        """[s] from its green time until the driver surely moves: the head may turn green
        up to :attr:`late_s` late, and the driver reacts :attr:`react_s` after that."""
        return self.react_s + self.late_s

    def slow_mps(self, route: Route, step_s: float) -> float:
        """The slowest a human cruises along ``route`` (at least 1 m/s): the lowest limit on
        its way, the junction's own lanes (a turn) included, at the lowest speed factor,
        less one step's dawdle."""
        limit = min(route.road_mps, route.exit_mps, route.via_mps)
        return max(self.speed_factor_min * limit - self.sigma * self.accel_mps2 * step_s, 1.0)


def human_limits(road_mps: float, late_s: float = 0.0) -> DriverLimits:
    """What the roadside and the ICA assume of a human driver on a road of ``road_mps``:
    SUMO's passenger car, at most a tenth over the limit, its head turned green up to
    ``late_s`` after its green time. Both derive it from the same configuration, so
    neither has to send it."""
    return DriverLimits(top_mps=road_mps * DriverLimits().speed_factor_max, late_s=late_s)


def profile(
    t0_s: float, step_s: float, s0_m: float, s_end_m: float, wait_s: float, accel: float, top: float
) -> Trajectory:
    """Front positions every ``step_s`` from ``t0_s``: standing at ``s0_m`` for
    ``wait_s``, then accelerating at ``accel`` up to ``top`` until past ``s_end_m``."""
    dist = s_end_m - s0_m
    t_acc = top / accel
    d_acc = 0.5 * accel * t_acc * t_acc
    moving = math.sqrt(2.0 * dist / accel) if dist <= d_acc else t_acc + (dist - d_acc) / top
    n = max(math.ceil((wait_s + moving) / step_s - 1e-9) + 2, 2)
    t = np.arange(n) * step_s - wait_s
    tm = np.clip(t, 0.0, None)
    s = np.where(tm <= t_acc, 0.5 * accel * tm * tm, d_acc + top * (tm - t_acc))
    return Trajectory(t0_s, step_s, s0_m + s)


def bounds(
    route: Route,
    length_m: float,
    green_s: float,
    step_s: float,
    limits: DriverLimits,
    dist_m: float = STOP_SHORT_M,
) -> tuple[Trajectory, Trajectory]:
    """The fastest and the slowest crossing of ``route`` by a driver standing ``dist_m``
    short of the line, from the green at ``green_s``, each until the rear is out of the
    junction."""
    s_end = route.cross_length_m + length_m
    s0 = -dist_m
    # a step's head start: a simulator's step takes the new speed over the whole step (SUMO's
    # Euler update), which runs half a step ahead of continuous acceleration, and more
    fast = profile(green_s, step_s, s0, s_end, -step_s, limits.accel_mps2, limits.top_mps)
    slow_a = (1.0 - limits.sigma) * limits.accel_mps2
    slow = profile(
        green_s, step_s, s0, s_end, limits.moves_s, slow_a, limits.slow_mps(route, step_s)
    )
    return fast, slow


def euler(
    t0_s: float,
    step_s: float,
    s0_m: float,
    v0_mps: float,
    s_end_m: float,
    wait_steps: int,
    accel: float,
    top: float,
) -> Trajectory:
    """Front positions every ``step_s`` from ``t0_s`` of a driver at ``s0_m`` and
    ``v0_mps`` that stands ``wait_steps`` steps, then gains ``accel * step_s`` of speed a
    step up to ``top`` (starting at most at ``top``), until past ``s_end_m``. SUMO's
    update, in which each step's new speed carries the vehicle over the step."""
    v0 = min(max(v0_mps, 0.0), top)
    dv = accel * step_s
    n_acc = math.ceil(max(top - v0, 0.0) / dv)
    n = wait_steps + n_acc + math.ceil(max(s_end_m - s0_m, 0.0) / (top * step_s)) + 2
    j = np.arange(1, n + 1) - wait_steps
    v = np.where(j > 0, np.minimum(v0 + dv * j, top), 0.0)
    s = s0_m + step_s * np.concatenate([[0.0], np.cumsum(v)])
    past = int(np.searchsorted(s, s_end_m, side="right"))
    return Trajectory(t0_s, step_s, s[: min(past + 1, len(s))])


def bounds_from(
    route: Route,
    length_m: float,
    t0_s: float,
    s0_m: float,
    v0_mps: float,
    step_s: float,
    limits: DriverLimits,
    wait_s: float = 0.0,
) -> tuple[Trajectory, Trajectory]:
    """The fastest and the slowest crossing of ``route`` from where a driver is seen, its
    front at ``s0_m`` at ``v0_mps`` at ``t0_s``: no faster than full acceleration from
    there, no slower than the dawdler's (Krauss never takes more than ``sigma * accel *
    step`` off a step's gain, nor brakes with the way clear), after ``wait_s`` if it has
    not surely moved yet. Each until the rear is out of the junction."""
    s_end = route.cross_length_m + length_m
    fast = euler(t0_s, step_s, s0_m, v0_mps, s_end, 0, limits.accel_mps2, limits.top_mps)
    slow_a = (1.0 - limits.sigma) * limits.accel_mps2
    stand = math.ceil(max(wait_s, 0.0) / step_s - 1e-9)
    slow = euler(t0_s, step_s, s0_m, v0_mps, s_end, stand, slow_a, limits.slow_mps(route, step_s))
    return fast, slow


def bounds_rolling(
    route: Route,
    length_m: float,
    green_s: float,
    step_s: float,
    limits: DriverLimits,
    dist_m: float,
    v_mps: float,
) -> tuple[Trajectory, Trajectory]:
    """The fastest and the slowest crossing of ``route`` by a driver seen ``dist_m`` short
    of its line at ``v_mps``, slowing for its red head, whose head turns green at
    ``green_s`` (now): no faster than full acceleration from there; no slower than
    braking on at :data:`ROLL_DECEL_MPS2` (its head was red) until it surely moves (its
    head may turn green late, and it reacts after that), standing if that stops it,
    then the dawdler's. Each until the rear is out."""
    s_end = route.cross_length_m + length_m
    fast = euler(green_s, step_s, -dist_m, v_mps, s_end, 0, limits.accel_mps2, limits.top_mps)
    react = math.ceil(limits.moves_s / step_s - 1e-9)
    slow = _braking(green_s, step_s, -dist_m, v_mps, s_end, react, limits, route)
    return fast, slow


def green_bounds(
    route: Route,
    length_m: float,
    green_s: float,
    step_s: float,
    limits: DriverLimits,
    dist_m: float = STOP_SHORT_M,
    v_mps: float = 0.0,
) -> tuple[Trajectory, Trajectory]:
    """The bounds a green was given with: :func:`bounds` for a driver standing ``dist_m``
    short of its line, :func:`bounds_rolling` for one rolling towards it at ``v_mps``."""
    if v_mps > 0.0:
        return bounds_rolling(route, length_m, green_s, step_s, limits, dist_m, v_mps)
    return bounds(route, length_m, green_s, step_s, limits, dist_m)


def _braking(
    t0_s: float,
    step_s: float,
    s0_m: float,
    v0_mps: float,
    s_end_m: float,
    steps: int,
    limits: DriverLimits,
    route: Route,
) -> Trajectory:
    """The dawdler's way from ``s0_m`` at ``v0_mps``, after braking at
    :data:`ROLL_DECEL_MPS2` for ``steps`` steps (standing once stopped)."""
    v = np.maximum(max(v0_mps, 0.0) - ROLL_DECEL_MPS2 * step_s * np.arange(1, steps + 1), 0.0)
    head = s0_m + step_s * np.concatenate([[0.0], np.cumsum(v)])
    slow_a = (1.0 - limits.sigma) * limits.accel_mps2
    v_on = float(v[-1]) if steps else v0_mps
    rest = euler(t0_s + steps * step_s, step_s, float(head[-1]), v_on, s_end_m, 0, slow_a,
                 limits.slow_mps(route, step_s))  # fmt: skip
    return Trajectory(t0_s, step_s, np.concatenate([head[:-1], rest.s_m]))


def bounds_seen(
    route: Route,
    length_m: float,
    t_s: float,
    s_m: float,
    v_mps: float,
    step_s: float,
    limits: DriverLimits,
    green_s: float,
) -> tuple[Trajectory, Trajectory]:
    """:func:`bounds_from` for a driver on its green since ``green_s``, seen at ``t_s``: one
    still standing at its line may not have reacted yet, and may wait until its reaction
    time is up. The ICA reserves these bounds and the roadside audits against them."""
    left = green_s + limits.moves_s - t_s
    if v_mps <= 1e-9 and s_m <= 0.0:
        return bounds_from(route, length_m, t_s, s_m, v_mps, step_s, limits, left)
    if left <= 1e-9:
        return bounds_from(route, length_m, t_s, s_m, v_mps, step_s, limits)
    # moving within its reaction time: it may still be braking for its red (a rolling green)
    fast, _ = bounds_from(route, length_m, t_s, s_m, v_mps, step_s, limits)
    steps = math.ceil(left / step_s - 1e-9)
    s_end = route.cross_length_m + length_m
    return fast, _braking(t_s, step_s, s_m, v_mps, s_end, steps, limits, route)


def first_reach(traj: Trajectory, s_m: np.ndarray) -> np.ndarray:
    """For each position in ``s_m``, the time of the last sample of ``traj`` before its
    front reaches it (the first sample if it is there already): no sooner than that is
    the front at ``s_m``."""
    i = np.searchsorted(traj.s_m, s_m, side="left")
    return traj.t0_s + traj.step_s * np.maximum(i - 1, 0)


def envelope_dtot(
    route: Route,
    shape: Shape,
    fast: Trajectory,
    slow: Trajectory,
    margin_m: float,
    grid: RouteGrid | None = None,
    estimated: bool = False,
) -> Dtot:
    """The timed occupancies of every crossing between ``fast`` and ``slow``: the slow
    bound's, each interval opened as early as the fast bound can reach the position the
    slow one held at the interval's start (no sooner can it touch that footprint)."""
    d = build_dtot(route, shape, slow, margin_m, grid, estimated)
    k = np.clip(np.round((d.lb_s - slow.t0_s) / slow.step_s).astype(int), 0, len(slow) - 1)
    lb = np.minimum(first_reach(fast, slow.s_m[k]), d.lb_s)
    return dataclasses.replace(d, lb_s=np.maximum.accumulate(lb))


# SUMO's Krauss follows the vehicle ahead at no more than its safe speed
# -tau b + sqrt((tau b)^2 + v_lead^2 + 2 b gap), the gap net of its standstill gap
KRAUSS_TAU_S = 1.0
KRAUSS_DECEL_MPS2 = 4.5
MIN_GAP_M = 2.5
_KRAUSS = tuple(Krauss(KRAUSS_TAU_S, KRAUSS_DECEL_MPS2, MIN_GAP_M))


def _lead_at(lead: Trajectory, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Front position and speed of ``lead`` at times ``t``: standing at its first sample
    before it, carried on at its last speed after it."""
    s, dt = lead.s_m, lead.step_s
    v_all = np.diff(s) / dt if len(s) > 1 else np.zeros(1)
    k = np.clip(((t - lead.t0_s) / dt).astype(int), 0, len(s) - 1)
    pos = np.interp(t, lead.t_s, s)
    end = lead.t_s[-1]
    after = t > end
    pos = np.where(after, s[-1] + v_all[-1] * (t - end), pos)
    speed = np.where(after, v_all[-1], v_all[np.minimum(k, len(v_all) - 1)])
    return pos, speed


def follow_delay(
    fast: Trajectory,
    cross_m: float,
    length_m: float,
    lead: Trajectory,
    lead_cross_m: float,
    lead_length_m: float,
    from_m: float = -math.inf,
) -> float:
    """:func:`follow_delay_numpy` in one compiled call
    (:func:`ica.core.kernels.follow.follow_delay`), bit for bit."""
    return _follow_kernel(
        (float(fast.t0_s), float(fast.step_s), float(cross_m), float(length_m), float(from_m)),
        np.ascontiguousarray(fast.s_m, dtype=float),
        (float(lead.t0_s), float(lead.step_s), float(lead_cross_m), float(lead_length_m)),
        np.ascontiguousarray(lead.s_m, dtype=float),
        _KRAUSS,
    )


def follow_delay_numpy(
    fast: Trajectory,
    cross_m: float,
    length_m: float,
    lead: Trajectory,
    lead_cross_m: float,
    lead_length_m: float,
    from_m: float = -math.inf,
) -> float:
    """How much later a human's fastest crossing (``fast``, of a route ``cross_m``
    long) must start so that it never comes close enough behind a vehicle leaving by
    the same exit lane at its slowest (``lead``: a human's slow bound, or a plan) to
    have to brake while it is still inside the junction; 0 if it never does. Both are
    measured from the exit line, the lead carrying on at its last speed beyond its
    trajectory, which it does if the way ahead is clear: a follower that never brakes
    inside keeps to its own envelope. The follower is watched from its position
    ``from_m`` on: a connected vehicle's plan from its entry line (0), since short of
    it the vehicle is on its own approach under its plan, where a delay does not move
    the samples it already flies, and where no lead on the exit lane is in its way."""
    u_f = fast.s_m[:-1] - cross_m
    inside = (u_f - length_m < 0.0) & (fast.s_m[:-1] >= from_m)
    if not inside.any():
        return 0.0
    t = fast.t_s[:-1][inside]
    u_f = u_f[inside]
    v_f = (np.diff(fast.s_m) / fast.step_s)[inside]  # its speed over the next step
    pos, v_l = _lead_at(lead, t)
    rear = pos - lead_cross_m - lead_length_m
    tb = KRAUSS_TAU_S * KRAUSS_DECEL_MPS2
    gap = rear - u_f - MIN_GAP_M
    safe = -tb + np.sqrt(tb * tb + v_l * v_l + 2.0 * KRAUSS_DECEL_MPS2 * np.maximum(gap, 0.0))
    bad = (gap < 0.0) | (v_f > safe + 1e-9)
    if not bad.any():
        return 0.0
    # the gap at which it need not brake, and when the lead's rear is that far ahead
    need = np.maximum(((v_f + tb) ** 2 - tb * tb - v_l * v_l) / (2.0 * KRAUSS_DECEL_MPS2), 0.0)
    target = (u_f + MIN_GAP_M + need + lead_cross_m + lead_length_m)[bad]
    s, end = lead.s_m, lead.t_s[-1]
    v_end = (s[-1] - s[-2]) / lead.step_s if len(s) > 1 else 0.0
    beyond = target > s[-1]
    i = np.searchsorted(s, target, side="left")
    reach = np.where(
        beyond,
        end + (target - s[-1]) / max(v_end, 0.1),
        lead.t0_s + lead.step_s * np.minimum(i, len(s) - 1),
    )
    return float(max((reach - t[bad]).max(), fast.step_s))


def path_s(traj: Trajectory, t_s: float) -> float:
    """Where ``traj``'s front is at ``t_s`` (held at its ends), linear between samples."""
    return float(np.interp(t_s, traj.t_s, traj.s_m))
