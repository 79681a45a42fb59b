"""The vehicle's side of a REQUEST: propose the fastest TSS from the current state."""

from __future__ import annotations

from dica.ica.core.config import IcaConfig
from dica.ica.core.planner import Planner
from dica.ica.core.request import Reason, Request, RequestError, Tss
from dica.ica.core.route import Route
from dica.ica.core.trajectory import sample


def propose(
    route: Route,
    *,
    vin: str,
    seq: int,
    t0_s: float,
    dist_to_entry_m: float,
    speed_mps: float,
    length_m: float = 5.0,
    width_m: float = 1.8,
    config: IcaConfig | None = None,
) -> Request:
    """A REQUEST with the time-optimal plan a vehicle would ask for.

    Raises RequestError(INFEASIBLE) when the vehicle cannot slow to the
    route's cap before the entry line (it must not ask; it must stop).
    """
    cfg = config or IcaConfig()
    s_end = route.cross_length_m + length_m
    planner = Planner(
        d_m=dist_to_entry_m,
        v0_mps=speed_mps,
        road_mps=route.road_mps,
        cap_mps=route.speed_cap_mps,
        s_end_m=s_end,
        kin=cfg.kinematics,
    )
    profile = planner.fastest()
    if profile is None:
        raise RequestError(Reason.INFEASIBLE, "cannot reach the entry line at the crossing cap")
    traj = sample(profile, t0_s, cfg.step_s, s_end)
    front, heading = traj.xy_heading(route, length_m)
    return Request(
        vin=vin,
        seq=seq,
        in_lane=route.in_lane,
        out_lane=route.out_lane,
        length_m=length_m,
        width_m=width_m,
        t0_s=t0_s,
        dist_to_entry_m=dist_to_entry_m,
        speed_mps=speed_mps,
        tss=Tss(traj.t_s, front[:, 0].copy(), front[:, 1].copy(), heading),
    )
