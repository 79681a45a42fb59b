"""Checks that turn an untrusted REQUEST into a trajectory on a known route.

Every check raises :class:`RequestError` with a stable reason, so a bad
request is answered with a REJECT and never touches the confirmed set.
"""

from __future__ import annotations

import math

import numpy as np

from dica.ica.core.config import IcaConfig
from dica.ica.core.intersection import Intersection
from dica.ica.core.kernels.validate import Limits, TssRules, TssSamples, request_checks
from dica.ica.core.request import Reason, Request, RequestError
from dica.ica.core.route import Route
from dica.ica.core.trajectory import Trajectory
from dica.ica.core.zones import Shape


def _finite(name: str, x: float) -> None:
    if not isinstance(x, (int, float)) or isinstance(x, bool) or not math.isfinite(x):
        raise RequestError(Reason.NOT_FINITE, f"{name} must be a finite number, got {x!r}")


def check_request(
    req: Request, inter: Intersection, cfg: IcaConfig, now_s: float
) -> tuple[Route, Shape, Trajectory]:
    """Validate ``req``; return its route, planning shape and TSS as a trajectory."""
    if not isinstance(req.vin, str) or not req.vin or len(req.vin) > 64:
        raise RequestError(
            Reason.BAD_STATE, "vin must be a non-empty string of at most 64 characters"
        )
    if not isinstance(req.seq, int) or isinstance(req.seq, bool) or req.seq < 0:
        raise RequestError(Reason.BAD_STATE, f"seq must be a non-negative integer, got {req.seq!r}")
    for name in ("length_m", "width_m", "t0_s", "dist_to_entry_m", "speed_mps"):
        _finite(name, getattr(req, name))
    t_obs = req.t0_s if isinstance(req.t_obs_s, float) and math.isnan(req.t_obs_s) else req.t_obs_s
    _finite("t_obs_s", t_obs)
    if req.length_m <= 0 or req.width_m <= 0:
        raise RequestError(
            Reason.BAD_SIZE, f"vehicle size must be positive, got {req.length_m} x {req.width_m} m"
        )
    if req.length_m > cfg.max_length_m or req.width_m > cfg.max_width_m:
        raise RequestError(
            Reason.TOO_LARGE,
            f"vehicle {req.length_m} x {req.width_m} m exceeds the junction's design envelope "
            f"{cfg.max_length_m} x {cfg.max_width_m} m",
        )
    if req.in_lane not in inter.in_lanes:
        raise RequestError(
            Reason.UNKNOWN_LANE, f"{req.in_lane!r} is not an incoming lane of this junction"
        )
    route = inter.route(req.in_lane, req.out_lane)
    if route is None:
        raise RequestError(
            Reason.UNKNOWN_ROUTE,
            f"no route from {req.in_lane!r} to {req.out_lane!r} through this junction",
        )
    kin = cfg.kinematics
    if route.id in inter.sweeping(req.length_m, req.width_m, kin.stop_gap_m, kin.decel_mps2):
        raise RequestError(
            Reason.TOO_LARGE,
            f"vehicle {req.length_m} x {req.width_m} m on {route.id} would sweep over where "
            "a vehicle waits at another lane's line or stands on another exit lane: the "
            "lines were placed for smaller ones",
        )
    if req.dist_to_entry_m < -cfg.on_route_tol_m or req.dist_to_entry_m > inter.comm_length_m + 1.0:
        raise RequestError(
            Reason.BAD_STATE,
            f"distance to the entry line {req.dist_to_entry_m:.2f} m lies outside the region",
        )
    if req.speed_mps < 0 or req.speed_mps > route.road_mps + cfg.speed_tol_mps:
        raise RequestError(
            Reason.BAD_STATE, f"speed {req.speed_mps:.2f} m/s outside [0, road limit]"
        )
    if t_obs > now_s + cfg.step_s + 1e-9:
        raise RequestError(Reason.BAD_TIME, f"request observed at t={t_obs:.3f} s, in the future")
    if now_s - t_obs > cfg.max_request_age_s:
        raise RequestError(Reason.STALE, f"request is {now_s - t_obs:.3f} s old")
    if req.t0_s < t_obs - 1e-9 or req.t0_s - t_obs > cfg.max_lead_s + 1e-9:
        raise RequestError(
            Reason.BAD_TIME,
            f"plan starts {req.t0_s - t_obs:.3f} s after the observation: outside "
            f"[0, {cfg.max_lead_s:g}] s",
        )
    if req.t0_s < now_s - 1e-9:
        raise RequestError(
            Reason.STALE, f"the plan starts at t={req.t0_s:.3f} s, before now ({now_s:.3f} s)"
        )

    traj = _check_tss(req, route, cfg)
    return route, Shape.of(req.length_m, req.width_m), traj


def _check_tss(req: Request, route: Route, cfg: IcaConfig) -> Trajectory:
    tss = _tss_arrays(req, cfg)
    tol = min(cfg.on_route_tol_m, cfg.margin_m) + 1e-3
    kin = cfg.kinematics
    rules = TssRules(
        step_s=cfg.step_s,
        t0_s=float(req.t0_s),
        off_tol_m=tol,
        dist_to_entry_m=float(req.dist_to_entry_m),
        start_tol_m=cfg.on_route_tol_m,
        s_end_m=route.cross_length_m + req.length_m,
        length_m=float(req.length_m),
        heading_tol_rad=cfg.heading_tol_rad,
    )
    limits = Limits(
        v0_mps=float(req.speed_mps),
        road_mps=route.road_mps + cfg.speed_tol_mps,
        cap_mps=route.speed_cap_mps + cfg.speed_tol_mps,
        accel_mps2=kin.accel_mps2,
        decel_mps2=kin.decel_mps2,
        accel_tol_mps2=cfg.accel_tol_mps2,
        first_slack_mps2=max(kin.accel_mps2, kin.decel_mps2),
    )
    route_xy = np.ascontiguousarray(route.xy, dtype=float)
    stage, failed, value, s = request_checks(
        tuple(tss), route_xy, route.s, tuple(rules), tuple(limits)
    )
    if stage == 1:
        raise _tss_error(failed, value, req, route, cfg, tol)
    if stage == 2:
        raise RequestError(
            Reason.OFF_ROUTE, f"TSS heading deviates from the route by {value:.2f} rad"
        )
    if stage == 3:
        raise _limit_error(failed, value, route)
    return Trajectory(float(tss.t_s[0]), cfg.step_s, s)


def _tss_arrays(req: Request, cfg: IcaConfig) -> TssSamples:
    """The TSS as four float arrays of one length, 2 to ``max_tss_samples``."""
    tss = req.tss
    # in TssSamples' order: t_s, x_m, y_m, heading_rad
    arrays = [np.asarray(a) for a in (tss.t_s, tss.x_m, tss.y_m, tss.heading_rad)]
    n = len(arrays[0])
    if any(a.ndim != 1 or len(a) != n for a in arrays):
        raise RequestError(
            Reason.BAD_STATE, "TSS arrays must be one-dimensional and of equal length"
        )
    if n < 2 or n > cfg.max_tss_samples:
        raise RequestError(
            Reason.BAD_STATE, f"TSS must have 2..{cfg.max_tss_samples} samples, has {n}"
        )
    try:  # contiguous float copies (the request's arrays stay the sender's)
        return TssSamples._make(np.array(a, dtype=float, order="C") for a in arrays)
    except (TypeError, ValueError):
        raise RequestError(Reason.NOT_FINITE, "TSS holds values that are not numbers") from None


def _tss_error(
    failed: int, value: float, req: Request, route: Route, cfg: IcaConfig, tol: float
) -> RequestError:
    """The rejection for a failed :func:`ica.core.kernels.validate.tss_checks` check."""
    if failed == 1:
        return RequestError(Reason.NOT_FINITE, "TSS holds NaN or infinite values")
    if failed == 2:
        return RequestError(Reason.BAD_TIME, "TSS times must increase strictly")
    if failed == 3:
        return RequestError(Reason.BAD_TIME, f"TSS must be sampled every {cfg.step_s} s")
    if failed == 4:
        return RequestError(Reason.BAD_TIME, "TSS must start at the request's state time t0")
    if failed == 5:
        return RequestError(
            Reason.OFF_ROUTE,
            f"TSS leaves route {route.id} by {value:.2f} m (tolerance {tol:.3f} m)",
        )
    if failed == 6:
        return RequestError(
            Reason.BAD_STATE,
            f"TSS starts {-value:.2f} m before the line, state says {req.dist_to_entry_m:.2f} m",
        )
    if failed == 7:
        return RequestError(Reason.BAD_STATE, "TSS moves backwards along the route")
    return RequestError(
        Reason.BAD_STATE, "TSS ends before the vehicle is fully out of the junction"
    )


def _limit_error(failed: int, value: float, route: Route) -> RequestError:
    """The rejection for a failed :func:`ica.core.kernels.validate.limit_checks` check."""
    if failed == 1:
        return RequestError(Reason.LIMITS, f"TSS exceeds the road limit ({value:.2f} m/s)")
    if failed == 2:
        return RequestError(
            Reason.LIMITS,
            f"TSS exceeds the {route.turn.value} cap of {route.speed_cap_mps:.2f} m/s inside",
        )
    return RequestError(Reason.LIMITS, "TSS exceeds the acceleration or deceleration limit")


def _check_tss_reference(req: Request, route: Route, cfg: IcaConfig) -> Trajectory:
    """:func:`_check_tss` in numpy, check for check: the tests' reference."""
    t, x, y, h = _tss_arrays(req, cfg)
    if not all(np.isfinite(a).all() for a in (t, x, y, h)):
        raise RequestError(Reason.NOT_FINITE, "TSS holds NaN or infinite values")
    dt = np.diff(t)
    if np.any(dt <= 0):
        raise RequestError(Reason.BAD_TIME, "TSS times must increase strictly")
    if np.any(np.abs(dt - cfg.step_s) > 1e-6):
        raise RequestError(Reason.BAD_TIME, f"TSS must be sampled every {cfg.step_s} s")
    if abs(t[0] - req.t0_s) > 1e-6:
        raise RequestError(Reason.BAD_TIME, "TSS must start at the request's state time t0")

    s, off = route.project_reference(np.stack([x, y], -1))
    worst = float(off.max())
    # a footprint is drawn on the route itself, so an offset is only safe while the
    # margin around the footprint covers it
    tol = min(cfg.on_route_tol_m, cfg.margin_m) + 1e-3
    if worst > tol:
        raise RequestError(
            Reason.OFF_ROUTE,
            f"TSS leaves route {route.id} by {worst:.2f} m (tolerance {tol:.3f} m)",
        )
    if abs(s[0] + req.dist_to_entry_m) > cfg.on_route_tol_m:
        raise RequestError(
            Reason.BAD_STATE,
            f"TSS starts {-s[0]:.2f} m before the line, state says {req.dist_to_entry_m:.2f} m",
        )
    if np.any(np.diff(s) < -1e-6):
        raise RequestError(Reason.BAD_STATE, "TSS moves backwards along the route")
    s = np.maximum.accumulate(s)
    s_end = route.cross_length_m + req.length_m
    if s[-1] < s_end - 1e-6:
        raise RequestError(
            Reason.BAD_STATE, "TSS ends before the vehicle is fully out of the junction"
        )

    front = route.points(s)
    rear = route.points(s - req.length_m)
    d = front - rear
    expect = np.arctan2(d[:, 1], d[:, 0])
    dh = np.abs((h - expect + np.pi) % (2 * np.pi) - np.pi)
    if float(dh.max()) > cfg.heading_tol_rad:
        raise RequestError(
            Reason.OFF_ROUTE, f"TSS heading deviates from the route by {float(dh.max()):.2f} rad"
        )

    traj = Trajectory(float(t[0]), cfg.step_s, s)
    check_limits(traj, route, cfg, v0_mps=req.speed_mps)
    return traj


def check_limits(
    traj: Trajectory, route: Route, cfg: IcaConfig, v0_mps: float | None = None
) -> None:
    """Speed and acceleration limits on the sampled motion (what the vehicle will fly)."""
    v = traj.speeds()
    kin = cfg.kinematics
    if np.any(v > route.road_mps + cfg.speed_tol_mps):
        raise RequestError(Reason.LIMITS, f"TSS exceeds the road limit ({float(v.max()):.2f} m/s)")
    inside = traj.s_m[:-1] >= 0.0
    if np.any(v[inside] > route.speed_cap_mps + cfg.speed_tol_mps):
        raise RequestError(
            Reason.LIMITS,
            f"TSS exceeds the {route.turn.value} cap of {route.speed_cap_mps:.2f} m/s inside",
        )
    vs = v if v0_mps is None else np.concatenate([[v0_mps], v])
    acc = np.diff(vs) / traj.step_s
    # The first step may deviate by half a step of acceleration from the reported speed.
    slack = np.full(len(acc), cfg.accel_tol_mps2)
    if v0_mps is not None and len(slack):
        slack[0] += max(kin.accel_mps2, kin.decel_mps2)
    if np.any(acc > kin.accel_mps2 + slack) or np.any(acc < -kin.decel_mps2 - slack):
        raise RequestError(Reason.LIMITS, "TSS exceeds the acceleration or deceleration limit")
