"""Embedded run: one process, SUMO through libsumo, the ICA core called directly.

The world (:mod:`sim_gateway.world`) is the same as the cluster gateway's; the
vehicles are the same state machines as in a vehicle-agent process
(:mod:`vehicle_agent.machine`), and they reach the ICA core by a direct call
instead of a Zenoh query. It is the fast default for experiments.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from dica.ica.core.controller import Controller, build_controller
from dica.ica.core.dica import Green
from dica.ica.core.envelope import green_bounds, human_limits
from dica.ica.core.intersection import Intersection
from dica.ica.core.request import Confirmation, Reason, Rejection, Request, RequestError
from dica.ica.core.revocation import DROPPED, KEPT, Reorder
from dica.ica.core.walk import WalkSlot
from dica.ica.core.window import WindowOrder
from dica.sim_gateway.demand import Arrival, schedule_for
from dica.sim_gateway.humans import SignalHeads
from dica.sim_gateway.junction import Car, Seen
from dica.sim_gateway.light_control import ReactiveLight, setup_signal
from dica.sim_gateway.runconfig import (
    LIGHTS,
    RunConfig,
    RunError,
    RunResult,
)
from dica.sim_gateway.scenario import ScenarioError, light_net, stop_net
from dica.sim_gateway.signals import Phase as SignalPhase
from dica.sim_gateway.sumo_io import import_libsumo, start_sumo
from dica.sim_gateway.walkers import Walkers
from dica.sim_gateway.world import World
from dica.vehicle_agent.actuation import Actuation
from dica.vehicle_agent.machine import PENDING, Phase, Vehicle

__all__ = ["LIGHTS", "RunConfig", "RunError", "RunResult", "run"]


class LocalLink:
    """A vehicle's link to an ICA in the same process: a direct, timed call."""

    def __init__(self, ica: Controller) -> None:
        self.ica = ica
        self.compute_s: list[float] = []
        # what the region's detector reads as a vehicle passes it: EV or not, and its speed
        self.detector: dict[str, tuple[bool, float]] = {}
        self.revoked: list[str] = []  # reactive DICA: revoked this step, and their new plans
        self.revised: dict[str, Confirmation] = {}
        self.reorders: list[Reorder] = []  # reactive DICA's decisions, to record
        self.window: list[Request] | None = None  # a window's requests, when windowed
        self.green_s: list[float] = []  # the ICA's time per human driver's green asked

    def detect(self, vin: str, lane: str, t_s: float) -> Rejection | None:
        try:
            ev, speed = self.detector.get(vin, (False, None))
            self.ica.detect(vin, lane, t_s, emergency=ev, speed_mps=speed)
            self._revoke()
        except RequestError as e:
            return Rejection(vin, -1, e.reason, e.detail)
        return None

    def _revoke(self) -> bool:
        """In process a revocation reaches its vehicle at once: acknowledge it now.
        True if anything was revoked. (Not in the cluster's way, ``replans_revoked``
        off: there the vehicles answer for themselves, see LocalDrivers._deliver.)"""
        ica = self.ica
        if not ica.replans_revoked:
            return False
        revoked = False
        for r in ica.take_reorders():
            self.reorders.append(r)
            self.revoked += r.revoked
            revoked = revoked or bool(r.revoked)
            for vin in r.revoked:
                self.revised.update((c.vin, c) for c in ica.acknowledge(vin))
        return revoked

    def request(self, req: Request, now_s: float):
        if self.window is not None:  # answered when the window closes (LocalDrivers)
            self.window.append(req)
            return PENDING
        return self.decide(req, now_s)

    def decide(self, req: Request, now_s: float) -> Confirmation | Rejection:
        t_c = time.perf_counter()
        answer = self.ica.handle(req, now_s)
        if self._revoke() and isinstance(answer, Rejection) and answer.reason is Reason.HELD:
            # an EV's request started its event; the revocations have reached their
            # vehicles (in process, at once), so the EV asks again straight away
            answer = self.ica.handle(req, now_s)
        self.compute_s.append(time.perf_counter() - t_c)
        return answer

    def cancel(self, vin: str, seq: int) -> None:
        self.ica.cancel(vin, seq)

    def answer_revoke(self, vin: str, seq: int, dropped: bool) -> None:
        if dropped:
            self.ica.acknowledge(vin, seq)
        else:
            self.ica.restore(vin, seq)


class LocalDrivers:
    """The vehicles' machines, all in this process, with the ICA beside them."""

    def __init__(self, ica: Controller, cfg: RunConfig) -> None:
        self.ica = ica
        self.cfg = cfg
        self.link = LocalLink(ica)
        self.vehicles: dict[str, Vehicle] = {}
        self.rejections: dict[str, int] = {}
        self.recorded: set[str] = set()  # VINs whose confirmation is in the recording
        self.revocations: list[tuple[float, str, str]] = []  # (t, vin, what), to record
        self.kept: list[tuple[float, str, str]] = []  # revoked plans that stand: (t, vin, why)
        self.walks: list[tuple[float, WalkSlot]] | None = None  # slots given, to record
        # human drivers' greens and their reservations as given, to record
        self.greens: list[tuple[float, Green, list]] | None = None
        self.green_refused: dict[str, int] = {}  # greens asked for too soon, by reason
        cfg_ica = ica.config  # what the ICA assumes
        self.limits = human_limits(cfg_ica.caps.road_mps, cfg_ica.green_late_s)
        self.delivered: set[tuple[str, int]] = set()  # revocations handed to their vehicles
        self.order = WindowOrder(ica) if cfg.window_s else None
        self.close_s = cfg.window_s  # when the current window closes
        if self.order is not None:
            self.order.separations.precompute()  # none measured while a window waits
            self.link.window = []

    def walk(self, walkers: Walkers, t: float, junction: str | None = None) -> None:
        """The walkers seen across this step (their slots end now), the roadside's WALK
        requests of this step, each answered with its slot, and the walkers whose start
        has come let go; in a network, only those of ``junction`` (this ICA's)."""
        for person, crossing, at in walkers.cleared:
            if junction is None or at == junction:
                self.ica.walked(person, crossing, t)
        for ask in walkers.asks:
            if junction is not None and ask.junction != junction:
                continue
            slot = self.ica.walk(ask.person, ask.crossing, ask.ready_s, t, ask.walk_m,
                                 ask.speed_mps, ask.side, ask.near_m,
                                 ask.near_lo_m)  # fmt: skip
            walkers.answer(ask.person, slot.start_s, slot.end_s, t)
            if self.walks is not None:
                self.walks.append((t, slot))
        walkers.release(t)

    def humans(self, heads: SignalHeads, seen: list[Seen], t: float) -> None:
        """The human drivers of this step, the ICA asked in this process
        (:meth:`sim_gateway.humans.SignalHeads.serve`)."""
        self.ica.advance(t)
        heads.serve(seen, t, self)

    # -- the roadside's desk at the ICA for human drivers (sim_gateway.humans.Desk) --------
    def spotted(self, car: Car, t: float) -> bool:
        self.link.detect(car.vin, car.route.in_lane, t)
        return True

    def green(
        self, car: Car, t: float, near_m: float, again: bool, v_mps: float = 0.0
    ) -> tuple[float, tuple, float] | None:
        t_c = time.perf_counter()
        try:
            if again:
                g = self.ica.regreen(car.vin, t, car.length_m, car.width_m, self.limits, near_m)
            else:
                g = self.ica.green(car.vin, t, car.length_m, car.width_m, self.limits, near_m,
                                   v_mps)  # fmt: skip
        except RequestError as e:  # not yet (one ahead has not begun to enter): again
            why = str(e.reason)
            self.green_refused[why] = self.green_refused.get(why, 0) + 1
            return None
        finally:
            if not again:
                self.link.green_s.append(time.perf_counter() - t_c)
        if g is None:
            return None
        if self.greens is not None:  # as given: its reservations may shrink this very step
            held = self.ica.confirmed
            self.greens.append((t, g, [held[k] for k in g.keys if k in held]))
        return g.green_s, g.routes, g.green_s  # in this process: lit on time

    def tighten(self, car: Car, t: float, s_m: float, v_mps: float, lane: str) -> tuple | None:
        return self.ica.tighten(car.vin, t, s_m, v_mps, lane, self.limits)

    def step(self, t: float, seen: list[Seen]) -> list[Actuation]:
        self.ica.advance(t)
        self.link._revoke()  # an EV event may start as the clock moves
        out = []
        for s in seen:
            v = self.vehicles.get(s.car.vin)
            if v is None:
                c = s.car
                v = Vehicle(
                    c.vin,
                    c.route,
                    c.length_m,
                    c.width_m,
                    c.entry_speed_mps,
                    self.ica.config,
                    self.cfg.retry_s,
                    lead_s=self.cfg.plan_lead_s,
                )
                v.rejections = self.rejections  # one tally for the run
                self.vehicles[c.vin] = v
            if v.phase is Phase.APPROACHING:
                self.link.detector[s.car.vin] = (s.car.ev, s.obs.speed_mps)
            cmd = v.step(s.obs, self.link)
            if cmd is not None:
                out.append(cmd)
            if s.obs.exited:
                del self.vehicles[s.car.vin]
                self.link.detector.pop(s.car.vin, None)
        if self.order is not None and t + 1e-9 >= self.close_s:
            out += self._close_window(t)
        if self.ica.replans_revoked:
            out += self._revise(t)
        else:
            out += self._deliver()
        self._answered()
        return out

    def _close_window(self, t: float) -> list[Actuation]:
        """Decide the window's requests, in the order that delays them least; each
        plan starts no earlier than now, as every vehicle planned a window ahead."""
        w = self.cfg.window_s
        self.close_s = (math.floor(t / w + 1e-9) + 1) * w
        reqs, self.link.window = self.link.window, []
        out = []
        for req in self.order.order(reqs):
            answer = self.link.decide(req, t)
            v = self.vehicles.get(req.vin)
            cmd = v.answered(answer, t) if v is not None else None
            if cmd is not None:
                out.append(cmd)
        return out

    def _answered(self) -> None:
        """What became of revoked plans this step, to record: a plan is withdrawn once
        its vehicle has dropped it, not when the revocation is sent (it may be kept)."""
        answers = self.ica.take_answers()
        if self.ica.replans_revoked:
            return  # withdrawn with their replacements, at once (see _revise)
        for a in answers:
            if a.outcome == DROPPED:
                self.recorded.discard(a.vin)  # its next plan is recorded once it flies it
                self.revocations.append((a.t_s, a.vin, "revoked"))
            elif a.outcome == KEPT:
                self.kept.append((a.t_s, a.vin, "kept its plan: it could not stop"))
            else:
                self.kept.append((a.t_s, a.vin, "no answer before its plan ended"))

    def _deliver(self) -> list[Actuation]:
        """The cluster's way: this step's REVOKEs reach their vehicles, as they reach
        a lockstep agent before it answers the STATE whose query caused them; each
        vehicle's actuator drops its plan (or keeps it) and the vehicle tells the ICA
        at its next observation (see _answered)."""
        self.link.reorders += self.ica.take_reorders()
        out = []
        for vin, seq in self.ica.due_revocations():
            if (vin, seq) in self.delivered:
                continue
            self.delivered.add((vin, seq))
            v = self.vehicles.get(vin)
            cmd = v.revoke(seq, self.link) if v is not None else None
            if cmd is not None:
                out.append(cmd)
        return out

    def _revise(self, t: float) -> list[Actuation]:
        """The revoked vehicles of this step fly their new plans (or, without one,
        brake and ask again): the machines learn of revocation and replacement at once."""
        link, ica = self.link, self.ica
        ica.settle()
        link.revised.update((c.vin, c) for c in ica.take_confirmations())
        out = []
        for vin in link.revoked:
            v = self.vehicles.get(vin)
            if v is not None:
                new = link.revised.get(vin)
                out.append(v.revoked(new, t))
                self.recorded.discard(vin)  # its new plan is recorded once it flies it
                self.revocations.append((t, vin, "revoked, replanned" if new else "revoked"))
        link.revoked, link.revised = [], {}
        return out

    def requests(self) -> dict:
        greens = (
            {"greens_asked": len(self.link.green_s), "greens_refused": dict(self.green_refused),
             "green_p99_ms": _ms(lambda x: np.percentile(x, 99), self.link.green_s)}
            if self.link.green_s
            else {}
        )  # fmt: skip
        return (
            request_figures(self.link.compute_s, self.rejections)
            | greens
            | (
                {}
                if self.order is None
                else {
                    "windows_ordered": self.order.windows,
                    "windows_reordered": self.order.reordered,
                    # the ordering's own cost per window of two requests or more
                    "window_order_ms_median": _ms(np.median, self.order.order_s),
                    "window_order_ms_max": _ms(np.max, self.order.order_s),
                }
            )
        )


def request_figures(compute_s: list[float], rejections: dict[str, int]) -> dict:
    """A run's requests: how many, the rejections by reason, the ICA's time per request."""
    rt = np.array(compute_s) if compute_s else np.zeros(1)
    return {
        "count": len(compute_s),
        "rejections": dict(rejections),
        "median_ms": float(np.median(rt) * 1e3),
        "p99_ms": float(np.percentile(rt, 99) * 1e3),
    }


def _ms(f, xs: list[float]) -> float | None:
    return float(f(xs) * 1e3) if xs else None


def run(
    cfg: RunConfig,
    inter: Intersection,
    progress: Callable[[float, int, int], None] | None = None,
    rrd_path: Path | None = None,
    run_dir: Path | None = None,
    schedule: list[Arrival] | None = None,
) -> RunResult:
    """Run one simulation to the end and return its metrics and safety report.

    With ``rrd_path`` the run is also recorded as Rerun space-time visuals
    (the same recorder the cluster's observer uses). A light baseline on a
    junction without a light of its kind gets one from netconvert, in
    ``run_dir`` (a temporary directory if None), with a line on stderr.
    ``schedule`` replaces the random demand with given arrivals (scripted scenarios).
    """
    with tempfile.TemporaryDirectory(prefix="dica-light-") as scratch:
        return _run(cfg, inter, progress, rrd_path, Path(run_dir or scratch), schedule)


def _run(
    cfg: RunConfig,
    inter: Intersection,
    progress: Callable[[float, int, int], None] | None,
    rrd_path: Path | None,
    run_dir: Path,
    given: list[Arrival] | None = None,
) -> RunResult:
    ls = import_libsumo()
    light = cfg.algorithm in LIGHTS
    spec = cfg.controller_spec()
    ica_cfg = spec.config
    ica = build_controller(spec, inter)
    ica.prepare()
    schedule, spec, horizon = schedule_for(cfg, inter, ica_cfg.step_s)
    if given is not None:
        schedule = sorted(given, key=lambda a: a.arrival_s)
    built = None
    if cfg.algorithm == "allway-stop":
        try:
            net, built = stop_net(Path(cfg.net_path), inter.junction_id, run_dir)
        except ScenarioError as e:
            raise RunError(str(e)) from None
        print(built, file=sys.stderr)
        cmd = start_sumo(ls, dataclasses.replace(cfg, net_path=str(net)), ica_cfg.step_s)
    elif light:
        try:
            net, built = light_net(
                Path(cfg.net_path),
                inter.junction_id,
                "actuated" if cfg.algorithm == "actuated" else "static",
                run_dir,
            )
        except ScenarioError as e:
            raise RunError(str(e)) from None
        if built is not None:
            print(built, file=sys.stderr)
        cmd = start_sumo(ls, dataclasses.replace(cfg, net_path=str(net)), ica_cfg.step_s)
    else:
        cmd = start_sumo(ls, cfg, ica_cfg.step_s)
    try:
        if cfg.algorithm == "allway-stop":
            signal = {"type": cfg.algorithm}
        else:
            signal = setup_signal(ls, cfg, inter, spec) if light else None
        if signal is not None and built is not None:
            signal["built"] = built
        preempt = None
        if cfg.algorithm == "reactive-light":
            program = [SignalPhase(d, st, kind, d, d) for d, st, kind in signal["phases"]]
            preempt = ReactiveLight(ls, inter, program)
        recorder = open_recording(inter, rrd_path)
        world = World(
            ls, cfg, inter, ica_cfg, schedule, horizon, signalised=light,
            want_xy=bool(recorder), predict_s=cfg.plan_lead_s,
        )  # fmt: skip
        drivers = LocalDrivers(ica, cfg)
        if recorder is not None:
            drivers.walks = []
            drivers.greens = []
        try:
            while True:
                seen = world.step()
                if world.walkers is not None and not light:
                    drivers.walk(world.walkers, world.t)  # the roadside asks first
                if world.heads is not None and not light:
                    drivers.humans(world.heads, world.human_seen, world.t)
                if not light:
                    world.apply(drivers.step(world.t, seen))
                elif preempt is not None:
                    preempt.step(world.t, seen)
                if recorder is not None:
                    record_step(recorder, drivers, seen, cfg, world.t, world.walkers,
                                world.heads, world.human_seen)  # fmt: skip
                world.end_step(progress)
                if world.done():
                    break
        finally:
            if recorder is not None:
                recorder.close()
        result = world.result(drivers.requests(), cmd)
        result.signal = signal
        summary = ica.summary(events=True)
        if summary is not None:
            result.extra["reactive"] = summary
        if preempt is not None:
            result.extra["preemption"] = preempt.summary()
        return result
    finally:
        ls.close()


def open_recording(inter: Intersection, rrd_path: Path | None, application_id: str = "dica"):
    if rrd_path is None:
        return None
    from dica.sim_gateway.recording import SpaceTimeRecorder

    try:
        rec = SpaceTimeRecorder(inter, rrd_path, application_id=application_id)
    except OSError as e:
        raise RunError(f"cannot write {rrd_path}: {e}") from None
    rec.geometry()
    return _Recording(rec)


def _record_humans(
    r: _Recording, drivers: LocalDrivers, heads: SignalHeads, human_seen: list[Seen], t: float
) -> None:
    """Human drivers drawn as such, each green's envelopes (what the ICA reserved, and
    the fastest and slowest crossing of each route) and the heads at the lines."""
    rec = r.rec
    for s in human_seen:
        if s.car.vin not in r.humans:
            r.humans.add(s.car.vin)
            rec.human(s.car.vin)
    for t_g, g, given in drivers.greens or ():
        routes = []
        for c in given:
            fast, slow = green_bounds(c.dtot.route, c.length_m, g.green_s, heads.step_s,
                                      heads.limits, g.near_m, g.speed_mps)  # fmt: skip
            routes.append((c.dtot.route.id, c.dtot, fast, slow))
        rec.envelope(t_g, g.vin, routes)
    if drivers.greens:
        drivers.greens.clear()
    if not r.humans:  # no head drawn before the first human driver (as an observer)
        return
    red, green = [], []
    for s in human_seen:
        d = heads.drivers.get(s.car.vin)
        if d is None or not s.car.head or s.car.exited or not s.car.s_m <= 0.0:
            continue
        at = s.car.route.points(0.0).reshape(-1)[:2]
        (green if d.resumed else red).append(at)
    rec.heads(t, np.array(red).reshape(-1, 2), np.array(green).reshape(-1, 2))


class _Recording:
    """The recorder and what it has already been told: confirmations, rejections."""

    def __init__(self, rec) -> None:
        self.rec = rec
        self.wake: dict[str, float] = {}  # when each vehicle may ask again, as last seen
        self.tally: dict[str, int] = {}  # rejections per reason, as last seen
        self.emergency: set[str] = set()  # EVs the recorder has been told of
        self.humans: set[str] = set()  # human drivers the recorder has been told of

    def close(self) -> None:
        self.rec.close()


def record_step(
    r: _Recording,
    drivers: LocalDrivers,
    seen: list[Seen],
    cfg: RunConfig,
    t: float,
    walkers: Walkers | None = None,
    heads: SignalHeads | None = None,
    human_seen: list[Seen] = (),
) -> None:
    """This step's new confirmations and rejections, every observed vehicle's footprint,
    with ``walkers`` the slots given this step and the people, and with ``heads`` the
    human drivers, the envelopes of the greens given this step and the signal heads."""
    rec = r.rec
    if heads is not None:
        _record_humans(r, drivers, heads, human_seen, t)
        seen = [*seen, *human_seen]
    for s in seen:  # before any confirmation: an EV's plan is drawn in its colour
        if s.car.ev and s.car.vin not in r.emergency:
            r.emergency.add(s.car.vin)
            rec.emergency(s.car.vin)
    for o in drivers.link.reorders:
        rec.reordered(
            o.t_s, o.ev, o.lane, o.solver, o.order, o.ev_entry_before_s, o.ev_entry_after_s,
            revoked=o.revoked, refused=o.refused,
        )  # fmt: skip
    drivers.link.reorders.clear()
    for t_rev, vin, what in drivers.revocations:  # a revoked plan is not flown from here on
        rec.withdrawn(t_rev, vin, what)
    drivers.revocations.clear()
    for t_kept, vin, why in drivers.kept:
        rec.kept(t_kept, vin, why)
    drivers.kept.clear()
    rejected = []
    for s in seen:
        v = drivers.vehicles.get(s.car.vin)
        if v is None:
            continue
        conf = v.confirmation
        if conf is not None and s.car.vin not in drivers.recorded:
            drivers.recorded.add(s.car.vin)
            tss = conf.tss
            rec.confirmed(
                conf.vin,
                conf.route_id,
                tss.t_s,
                tss.x_m,
                tss.y_m,
                tss.heading_rad,
                s.car.length_m,
                s.car.width_m,
                conf.entry_time_s,
                conf.exit_time_s,
                now_s=s.obs.t_s,
                delay_s=conf.delay_s,
                rounds=conf.iterations,
                margin_m=cfg.margin_m,
                time_pad_s=cfg.time_pad_s,
            )
        elif conf is None and v.next_request_s != r.wake.get(v.vin, v.next_request_s):
            rejected.append(v.vin)  # told to wait: its request was answered with a no
        r.wake[v.vin] = v.next_request_s
    if drivers.rejections != r.tally:
        new = {k: n - r.tally.get(k, 0) for k, n in drivers.rejections.items()}
        reasons = [k for k, n in new.items() if n > 0]
        r.tally = dict(drivers.rejections)
        for vin in rejected or ["-"]:
            rec.rejected(t, vin, "/".join(reasons))
    rec.footprints(
        t,
        [s.car.vin for s in seen],
        np.array([s.xy[0] for s in seen]),
        np.array([s.xy[1] for s in seen]),
        np.array([s.angle_deg for s in seen]),
        np.array([s.car.length_m for s in seen]),
        np.array([s.car.width_m for s in seen]),
        route_ids=[s.car.route.id for s in seen],
    )
    if walkers is not None:
        for t_walk, slot in drivers.walks or ():
            rec.walk(t_walk, slot)
        rec.people(t, walkers.xy, walkers.waiting_mask())
    if drivers.walks:
        drivers.walks.clear()
