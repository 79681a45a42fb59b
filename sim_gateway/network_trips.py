"""Trips through a network, from SUMO's own trip records: travel time and delay from
each vehicle's scheduled departure (waiting to be inserted included), and stops.

SUMO writes a record per vehicle (``--tripinfo-output``, with the unfinished at
the end): its departure and how long it waited to be inserted, its arrival, its
time lost against driving at its ideal speed all the way, and how often it
stood. A vehicle still in the net at the end has no arrival (SUMO 1.28 marks its
record ``vaporized="end"``); one SUMO took out on the way (``vaporized`` with
another reason: a collision, a teleport, TraCI) has none either. Both count as
generated and not finished, as do the vehicles due that were never inserted.
The same records serve every control compared on a network (signal-free or
lights), so the figures differ in the control alone. A vehicle the
insertion hold took out of SUMO is counted from the departure its file
scheduled, not from when it was put back.
"""

from __future__ import annotations

import csv
import math
import xml.etree.ElementTree as ET
from collections.abc import Collection, Mapping
from dataclasses import astuple, dataclass, fields
from pathlib import Path

import numpy as np


@dataclass(frozen=True, slots=True)
class NetTrip:
    vid: str
    scheduled_s: float  # when its file had it depart
    depart_s: float  # when SUMO inserted it
    arrival_s: float  # NaN: still in the net at the end
    travel_s: float  # arrival (or the end) less the scheduled departure
    free_s: float  # the same route at its ideal speed (SUMO's duration less its time loss)
    delay_s: float  # travel_s less free_s
    stops: int  # how often it stood (SUMO's waitingCount)
    route_m: float
    ev: bool = False  # of a vehicle type of SUMO's emergency class
    removed: bool = False  # taken out of SUMO on the way without arriving (not at the end)

    @property
    def finished(self) -> bool:
        return not math.isnan(self.arrival_s)


def read_trips(
    path: Path,
    scheduled: Mapping[str, float],
    end_s: float,
    ev_types: Collection[str] = (),
    waiting: Collection[str] = (),
) -> list[NetTrip]:
    """Each vehicle's trip from SUMO's tripinfo file, finished or not; a vehicle SUMO
    recorded twice (taken back after its first insertion, then put back) by its later
    record. A vehicle of ``waiting`` (due and not in SUMO at the end: held out of it, or
    put back and not inserted again) has no trip here whatever SUMO recorded of its
    first insertion: it is counted as waiting to enter. Those of the vehicle types
    ``ev_types`` are emergency vehicles."""
    last: dict[str, ET.Element] = {}
    for el in ET.parse(path).getroot():
        if el.tag == "tripinfo":
            last[el.get("id", "")] = el
    trips = []
    for vid, el in last.items():
        if vid in waiting:
            continue
        depart = float(el.get("depart", "nan"))
        due = scheduled.get(vid, depart - float(el.get("departDelay", "0")))
        arrival = float(el.get("arrival", "-1"))
        why = el.get("vaporized", "")  # "" arrived, "end" in the net at the end
        done = arrival >= 0.0 and not why
        duration = float(el.get("duration", "nan"))
        loss = float(el.get("timeLoss", "0"))
        travel = (arrival if done else end_s) - due
        free = duration - loss
        trips.append(
            NetTrip(
                vid,
                due,
                depart,
                arrival if done else math.nan,
                travel,
                free,
                travel - free,
                int(el.get("waitingCount", "0")),
                float(el.get("routeLength", "nan")),
                # a type SUMO copied for one vehicle (its own limits set) is "<type>@<id>"
                el.get("vType", "").split("@")[0] in ev_types,
                why not in ("", "end"),
            )
        )
    return trips


def summarize_trips(trips: list[NetTrip], waiting_to_enter: int) -> dict:
    """The network's figures: vehicles (every one generated), finished, mean and p95
    delay and travel time over the finished, stops; the unfinished (in the net at the
    end, taken out of SUMO on the way, or never inserted)."""
    done = [t for t in trips if t.finished]
    removed = sum(t.removed for t in trips)
    generated = len(trips) + waiting_to_enter

    def stat(values: list[float], q: float | None = None) -> float:
        if not values:
            return math.nan
        return float(np.percentile(values, q)) if q is not None else float(np.mean(values))

    delays = [t.delay_s for t in done]
    out = {
        "vehicles": generated,
        "finished": len(done),
        "finished_rate": len(done) / generated if generated else math.nan,
        "unfinished": generated - len(done),
        "in_net_at_end": len(trips) - len(done) - removed,
        "removed_on_the_way": removed,
        "waiting_to_enter_at_end": waiting_to_enter,
        "mean_travel_time_s": stat([t.travel_s for t in done]),
        "mean_delay_s": stat(delays),
        "p95_delay_s": stat(delays, 95.0),
        "max_delay_s": max(delays) if delays else math.nan,
        "mean_stops": stat([float(t.stops) for t in done]),
    }
    evs = [t for t in trips if t.ev]
    if evs:  # the emergency vehicles apart, against their free flow, and everyone else
        ev_done = [t for t in evs if t.finished]
        ratios = [t.travel_s / t.free_s for t in ev_done if t.free_s > 0.0]
        others = [t for t in done if not t.ev]
        out["emergency"] = {
            "vehicles": len(evs),
            "finished": len(ev_done),
            "mean_travel_time_s": stat([t.travel_s for t in ev_done]),
            "mean_free_flow_s": stat([t.free_s for t in ev_done]),
            "mean_delay_s": stat([t.delay_s for t in ev_done]),
            "max_delay_s": max((t.delay_s for t in ev_done), default=math.nan),
            "mean_travel_to_free_flow": stat(ratios),
            "max_travel_to_free_flow": max(ratios, default=math.nan),
            "mean_stops": stat([float(t.stops) for t in ev_done]),
        }
        out["normal"] = {
            "finished": len(others),
            "mean_delay_s": stat([t.delay_s for t in others]),
            "max_travel_time_s": max((t.travel_s for t in others), default=math.nan),
        }
    return out


def write_trips_csv(path: Path, trips: list[NetTrip]) -> None:
    """A row per vehicle (an unfinished one's ``arrival_s`` nan); the ``ev`` column
    only where there are emergency vehicles, the ``removed`` column only where SUMO took
    a vehicle out on the way (the file is as it was without them)."""
    names = [x.name for x in fields(NetTrip)]
    keep = [
        k
        for k, n in enumerate(names)
        if n not in ("ev", "removed") or any(getattr(t, n) for t in trips)
    ]
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow([names[k] for k in keep])
        for t in sorted(trips, key=lambda t: (t.scheduled_s, t.vid)):
            row = [round(x, 3) if isinstance(x, float) else x for x in astuple(t)]
            row = [int(x) if isinstance(x, bool) else x for x in row]
            w.writerow([row[k] for k in keep])
