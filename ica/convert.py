"""Between wire messages and the ICA core's own types (both directions)."""

from __future__ import annotations

import math

from dica.ica.core import request as core
from dica.ica.core.walk import WalkSlot
from dica.schemas import messages as m
from dica.schemas.codec import now_ns


def request_to_core(msg: m.Request) -> core.Request:
    tss = core.Tss(msg.t_s, msg.x_m, msg.y_m, msg.heading_rad)
    return core.Request(
        vin=msg.vin,
        seq=msg.seq,
        in_lane=msg.in_lane,
        out_lane=msg.out_lane,
        length_m=msg.length_m,
        width_m=msg.width_m,
        t0_s=msg.t0_s,
        dist_to_entry_m=msg.dist_to_entry_m,
        speed_mps=msg.speed_mps,
        tss=tss,
        t_obs_s=msg.t_obs_s,
        exit_room_m=math.inf if msg.exit_room_m >= m.BIG else msg.exit_room_m,
        network_room_m=math.inf if msg.network_room_m >= m.BIG else msg.network_room_m,
    )


def request_from_core(req: core.Request) -> m.Request:
    return m.Request(
        vin=req.vin,
        seq=req.seq,
        in_lane=req.in_lane,
        out_lane=req.out_lane,
        length_m=float(req.length_m),
        width_m=float(req.width_m),
        t0_s=float(req.t0_s),
        dist_to_entry_m=float(req.dist_to_entry_m),
        speed_mps=float(req.speed_mps),
        t_s=req.tss.t_s,
        x_m=req.tss.x_m,
        y_m=req.tss.y_m,
        heading_rad=req.tss.heading_rad,
        t_obs_s=float(req.t0_s if math.isnan(req.t_obs_s) else req.t_obs_s),
        sent_ns=now_ns(),
        exit_room_m=min(float(req.exit_room_m), m.BIG),
        network_room_m=min(max(float(req.network_room_m), 0.0), m.BIG),
    )


def response_from_core(conf: core.Confirmation) -> m.Response:
    return m.Response(
        vin=conf.vin,
        seq=conf.seq,
        route_id=conf.route_id,
        t_s=conf.tss.t_s,
        x_m=conf.tss.x_m,
        y_m=conf.tss.y_m,
        heading_rad=conf.tss.heading_rad,
        entry_time_s=float(conf.entry_time_s),
        exit_time_s=float(conf.exit_time_s),
        delay_s=float(conf.delay_s),
        iterations=int(conf.iterations),
        sent_ns=now_ns(),
    )


def response_to_core(msg: m.Response) -> core.Confirmation:
    return core.Confirmation(
        vin=msg.vin,
        seq=msg.seq,
        route_id=msg.route_id,
        tss=core.Tss(msg.t_s, msg.x_m, msg.y_m, msg.heading_rad),
        entry_time_s=msg.entry_time_s,
        exit_time_s=msg.exit_time_s,
        delay_s=msg.delay_s,
        iterations=msg.iterations,
    )


def reject_from_core(rej: core.Rejection) -> m.Reject:
    return m.Reject(rej.vin[:128], rej.seq, rej.reason.value, rej.detail[:512], now_ns())


def reject_to_core(msg: m.Reject) -> core.Rejection:
    try:
        reason = core.Reason(msg.reason)
    except ValueError:
        reason = core.Reason.BAD_STATE
    return core.Rejection(msg.vin, msg.seq, reason, msg.detail)


def go_from_slot(slot: WalkSlot, given_s: float) -> m.Go:
    """A walker's slot as its GO, whole (the gateway reads the start and end; an
    observer draws the rest)."""
    eta = slot.eta_s if math.isfinite(slot.eta_s) else slot.end_s
    return m.Go(
        slot.person, slot.crossing, float(slot.start_s), float(slot.end_s), now_ns(),
        float(given_s), int(slot.side), float(slot.near_m), float(slot.near_lo_m),
        float(slot.v_lo), float(slot.v_hi), float(eta), float(slot.late_s),
    )  # fmt: skip
