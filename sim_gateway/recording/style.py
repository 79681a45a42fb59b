"""How the recording looks: vehicle states and their colours, the colours of lines
and marks, the legends that name them, and the sizes that ride along with rows.

:data:`STATUS_STYLE` is the one table of vehicle states, their names and
colours, and :func:`vehicle_statuses` the one place that decides a vehicle's
state: a new state (an emergency vehicle) is one row there and one line there.
A legend is built from the same constants as what it names, so the two cannot
drift apart.
"""

from __future__ import annotations

import colorsys
import zlib
from collections.abc import Sequence
from enum import IntEnum
from typing import Any

import numpy as np

RGB = tuple[int, int, int]

REGION_RGB: RGB = (90, 90, 90)  # the junction's outline
LANE_EDGE_RGB: RGB = (170, 170, 170)
ROUTE_RGB: RGB = (205, 205, 205)  # routes through the junction
ENTRY_RGB: RGB = (30, 30, 30)  # entry and exit lines
REGION_START_RGB: RGB = (150, 60, 150)  # where the communication region starts
CROSSING_RGB: RGB = (200, 160, 40)  # pedestrian crossings
TEXT_RGB: RGB = (60, 60, 60)  # names and legends
FRAME_RGB: RGB = (120, 120, 120)  # chart axis labels
GRID_RGB: RGB = (185, 185, 185)  # time ticks
ROW_GRID_RGB: RGB = (225, 225, 225)  # between conflict-point rows
NOW_RGBA = (0, 0, 0, 160)
OVERRUN_RGB: RGB = (220, 30, 30)  # actual holding outside its reserved interval
RESERVED_RGBA = (40, 110, 235, 90)  # the reserved footprint's margin band
PLAN_ALPHA = 100  # plans are the vehicle's colour, translucent
STRIP_RADIUS_M = 0.08  # [m] outline half-width in the top view


class Status(IntEnum):
    """A vehicle's state as drawn."""

    REQUESTING = 1  # in the region, no confirmation yet
    CONFIRMED = 2  # confirmed, front before the entry line
    CROSSING = 3  # front past the entry line, rear not yet past the exit line
    CLEARED = 4  # rear past the exit line
    EMERGENCY = 5  # an emergency vehicle, in the region, whatever its state
    HUMAN = 6  # a human driver (--cav-share), until it has cleared


# The one table of states, names and colours (the top view and its legend).
STATUS_STYLE: dict[Status, tuple[str, RGB]] = {
    Status.REQUESTING: ("requesting", (235, 150, 20)),
    Status.CONFIRMED: ("confirmed", (40, 110, 235)),
    Status.CROSSING: ("crossing", (20, 165, 60)),
    Status.CLEARED: ("cleared", (140, 140, 140)),
    Status.EMERGENCY: ("emergency vehicle", (230, 30, 30)),
    Status.HUMAN: ("human driver", (120, 80, 40)),
}


def rgba(rgb: tuple[int, ...], alpha: int = 255) -> int:
    """A colour packed as 0xRRGGBBAA, as Rerun takes it."""
    r, g, b = rgb[:3]
    return (r << 24) | (g << 16) | (b << 8) | alpha


STATUS_RGBA = np.zeros(max(STATUS_STYLE) + 1, dtype=np.uint32)  # packed colour by state
for _state, (_, _rgb) in STATUS_STYLE.items():
    STATUS_RGBA[_state] = rgba(_rgb)
EMERGENCY_RGBA = rgba(STATUS_STYLE[Status.EMERGENCY][1])
HUMAN_RGBA = rgba(STATUS_STYLE[Status.HUMAN][1])
HEAD_RED_RGB: RGB = (220, 30, 30)  # a human driver's signal head: red, then green
HEAD_GREEN_RGB: RGB = (20, 180, 60)


def vehicle_statuses(
    confirmed: np.ndarray,
    s_m: np.ndarray,
    out_m: np.ndarray,
    emergency: np.ndarray | None = None,
    human: np.ndarray | None = None,
) -> np.ndarray:
    """Status per vehicle from whether it holds a confirmation, its front's distance
    along its route ``s_m`` (NaN: unknown) and the distance at which its rear is out;
    an emergency vehicle is EMERGENCY until it has cleared the junction, a human
    driver HUMAN until it has crossed (it holds no plan: its envelope is reserved)."""
    st = np.full(len(s_m), int(Status.REQUESTING), dtype=np.uint16)
    s = np.nan_to_num(s_m, nan=-np.inf)
    st[confirmed] = Status.CONFIRMED
    st[confirmed & (s > 0.0)] = Status.CROSSING
    st[confirmed & (s >= out_m)] = Status.CLEARED
    if emergency is not None:
        st[emergency & (st != Status.CLEARED)] = Status.EMERGENCY
    if human is not None:
        st[human & ~(s >= out_m)] = Status.HUMAN
    return st


def vehicle_color(vin: str, alpha: int = 0xFF) -> int:
    """A colour (0xRRGGBBAA) fixed by the VIN, so a plan and its progress match; its hue
    keeps 25 degrees away from red, the emergency vehicles' colour in the charts."""
    hue = (25 + zlib.crc32(vin.encode()) % 310) / 360.0
    r, g, b = (round(c * 255) for c in colorsys.hsv_to_rgb(hue, 0.8, 0.85))
    return (r << 24) | (g << 16) | (b << 8) | alpha


class VehicleColours:
    """Each vehicle's colour in the charts: its own by its VIN, or the emergency
    vehicles' red once it is known to be one (remembered, so a batch costs a lookup)."""

    def __init__(self) -> None:
        self._rgba: dict[str, int] = {}
        self.emergency: set[str] = set()  # VINs drawn as emergency vehicles
        self.human: set[str] = set()  # VINs of human drivers

    def mark_emergency(self, vin: str) -> None:
        self.emergency.add(vin)
        self._rgba[vin] = EMERGENCY_RGBA

    def mark_human(self, vin: str) -> None:
        self.human.add(vin)
        self._rgba[vin] = HUMAN_RGBA

    def of(self, vin: str) -> int:
        c = self._rgba.get(vin)
        if c is None:
            c = self._rgba[vin] = vehicle_color(vin)
        return c

    def of_many(self, vins: Sequence[str]) -> np.ndarray:
        return np.fromiter((self.of(v) for v in vins), dtype=np.uint32, count=len(vins))


def top_legend(margin_m: float) -> list[tuple[str, RGB]]:
    """The top view's legend: every state's outline, the band and the two lines."""
    entries = [(f"{name}: outline", rgb) for name, rgb in STATUS_STYLE.values()]
    entries += [
        (f"reserved, with its {margin_m:g} m margin: band", RESERVED_RGBA[:3]),
        ("entry line", ENTRY_RGB),
        ("communication region starts", REGION_START_RGB),
        ("human drivers' signal head: red", HEAD_RED_RGB),
        ("human drivers' signal head: green", HEAD_GREEN_RGB),
    ]
    return entries


LANE_CHART_LEGEND = "line: plan · dots: actual"
ZONE_LEGEND: tuple[tuple[str, RGB], ...] = (
    ("held, as reserved", TEXT_RGB),
    ("held outside its reservation", OVERRUN_RGB),
)


def row_styles(lanes: Sequence[str], margin_m: float) -> dict[str, dict[str, Any]]:
    """Sizes, colours and draw orders that never change, per entity. They ride along
    with each row (one value, which Rerun applies to every instance) rather than as
    a static chunk per entity: every chunk costs the viewer time to load."""
    half_margin = max(margin_m / 2.0, 0.05)
    styles: dict[str, dict[str, Any]] = {
        "junction/vehicles": {"radii": STRIP_RADIUS_M},
        "junction/reserved": {
            "radii": half_margin,
            "colors": rgba(RESERVED_RGBA[:3], RESERVED_RGBA[3]),
            "draw_order": 5.0,
        },
        "junction/names": {"radii": 0.05, "colors": rgba(TEXT_RGB), "show_labels": True},
    }
    for lane in lanes:
        styles[f"charts/data/lanes/{lane}/plans"] = {
            "radii": 0.15,
            "draw_order": 10.0,
            "show_labels": False,
        }
        styles[f"charts/data/lanes/{lane}/reorders"] = {
            "radii": 0.3,
            "draw_order": 25.0,
            "show_labels": True,
        }
        styles[f"charts/data/lanes/{lane}/actual"] = {
            "radii": 0.45,
            "draw_order": 20.0,
            "show_labels": False,
        }
    styles["charts/data/zones/reserved"] = {
        "radii": 0.12,
        "draw_order": 10.0,
        "show_labels": False,
    }
    styles["charts/data/zones/held"] = {"radii": 0.45, "draw_order": 20.0, "show_labels": False}
    return styles


PERSON_WAITING_RGB = (230, 160, 20)  # a person held at the kerb for the ICA's go
PERSON_WALKING_RGB = (40, 110, 220)  # a person walking
