"""What SUMO says: starting it, and reading each step's vehicles in as few calls as it allows.

A run reads every vehicle's lane, position, speed, road and odometer each
step, and the safety monitor needs the positions and angles of every vehicle
near the junction. Read one call at a time that is most of a step's cost,
so both come from subscriptions: SUMO hands over each step's values in one
call (:class:`Reads` for the vehicles in the region, :class:`Watch` for the
monitor's feed). Nothing here decides anything; the values are SUMO's own.
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
import tempfile
from collections.abc import Collection
from dataclasses import dataclass, field

import numpy as np

from dica.sim_gateway.runconfig import RunConfig, RunError
from dica.sim_gateway.safety import PersonCheck, SafetyMonitor
from dica.sim_gateway.xml_source import xml_source


def import_libsumo():
    """libsumo, without the pyarrow version notice it prints on import.

    libsumo bundles its own arrow, so the notice is harmless (checked on this
    stack), but it would otherwise open every run's output.
    """
    with contextlib.redirect_stdout(io.StringIO()):
        import libsumo
    return libsumo


def sumo_command(net_path: str, step_s: float, extra: tuple[str, ...]) -> list[str]:
    return [
        "sumo",
        "-n",
        net_path,
        "--step-length",
        str(step_s),
        "--no-step-log",
        "true",
        "--collision.check-junctions",
        "true",
        "--collision.action",
        "warn",
        # a collision is bodies touching, not a gap below a driver's preferred minimum
        # (SUMO's default counts any gap under the vehicle type's minGap)
        "--collision.mingap-factor",
        "0",
        # a vehicle that waits long at the line (a lost link, a dead ICA) waits; it is not
        # teleported out of the run
        "--time-to-teleport",
        "-1",
        "--no-warnings",
        "true",
        "--seed",
        "1",
        *extra,
    ]


def _from_junctions(cfg: RunConfig) -> bool:
    """Whether the route file has trips or flows from or to a junction (SUMO reads
    those only with ``--junction-taz``)."""
    src = xml_source(cfg.routes_path)
    tail = b""
    try:
        with open(src, "rb") if isinstance(src, str) else src as fh:
            while chunk := fh.read(1 << 20):  # a megabyte at a time: files can be large
                seen = tail + chunk
                if b"fromJunction=" in seen or b"toJunction=" in seen:
                    return True
                tail = chunk[-16:]  # a word cut at a chunk's end
    except OSError:
        pass  # the route file's own check says what is wrong with it
    return False


def start_sumo(ls, cfg: RunConfig, step_s: float) -> list[str]:
    # the whole file at once: SUMO otherwise reads a route file a few minutes ahead at a
    # time, so the vehicle types a file defines at their first use (duarouter writes them
    # so) are unknown when the run checks them, and an element out of departure order is
    # dropped with only a warning
    demand = (
        ("-r", cfg.routes_path, "--begin", str(cfg.begin_s), "--route-steps", "0")
        if cfg.routes_path
        else ()
    )
    if cfg.routes_path and "--junction-taz" not in cfg.sumo_args and _from_junctions(cfg):
        demand += ("--junction-taz", "true")  # trips from and to junctions need it
    cmd = sumo_command(cfg.net_path, step_s, (*demand, *cfg.sumo_args))
    # SUMO's own words on what it could not load: libsumo raises only "Process Error"
    # and SUMO prints the reason on the process's stderr, so that is kept while it loads
    with tempfile.TemporaryFile() as err:
        saved = os.dup(2)
        os.dup2(err.fileno(), 2)
        try:
            ls.start(cmd)
            failed = None
        except Exception as e:  # libsumo raises its own TraCIException or a plain error
            failed = " ".join(str(e).split())
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        err.seek(0)
        said = err.read().decode(errors="replace")
    if failed is None:
        sys.stderr.write(said)  # what a loading SUMO says is the user's to see
        return cmd
    lines = [ln.removeprefix("Error: ").strip() for ln in said.splitlines() if ln.strip()]
    raise RunError(f"SUMO would not start: {' '.join(lines[:3]) or failed}")


class Reads:
    """This step's lane, position, speed, road and odometer of every vehicle, from one
    SUMO call.

    Each vehicle is subscribed to those values when it departs; a vehicle
    missing from the results (not delivered yet) is read directly.
    """

    __slots__ = ("_ls", "_rows")

    def __init__(self, ls) -> None:
        self._ls = ls
        self._rows = ls.vehicle.getAllSubscriptionResults()

    @staticmethod
    def subscribe(ls, vin: str, xy: bool = False) -> None:
        c = ls.constants
        wanted = [c.VAR_LANE_ID, c.VAR_LANEPOSITION, c.VAR_SPEED, c.VAR_ROAD_ID, c.VAR_DISTANCE]
        ls.vehicle.subscribe(vin, wanted + ([c.VAR_POSITION, c.VAR_ANGLE] if xy else []))

    def _get(self, vin: str, var: int, direct):
        row = self._rows.get(vin)
        return row[var] if row is not None and var in row else direct(vin)

    def getLaneID(self, vin: str) -> str:
        return self._get(vin, self._ls.constants.VAR_LANE_ID, self._ls.vehicle.getLaneID)

    def getLanePosition(self, vin: str) -> float:
        return self._get(vin, self._ls.constants.VAR_LANEPOSITION, self._ls.vehicle.getLanePosition)

    def getSpeed(self, vin: str) -> float:
        return self._get(vin, self._ls.constants.VAR_SPEED, self._ls.vehicle.getSpeed)

    def getDistance(self, vin: str) -> float:
        return self._get(vin, self._ls.constants.VAR_DISTANCE, self._ls.vehicle.getDistance)

    def getRoadID(self, vin: str) -> str:
        return self._get(vin, self._ls.constants.VAR_ROAD_ID, self._ls.vehicle.getRoadID)

    def getPosition(self, vin: str) -> tuple[float, float]:
        return self._get(vin, self._ls.constants.VAR_POSITION, self._ls.vehicle.getPosition)

    def getAngle(self, vin: str) -> float:
        return self._get(vin, self._ls.constants.VAR_ANGLE, self._ls.vehicle.getAngle)


_NONE = (np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(0))


@dataclass(slots=True)
class People:
    """This step's persons as SUMO places them, for a junction's person check."""

    check: PersonCheck
    ids: list[str]
    xy: np.ndarray  # (n, 2) [m]
    radius_m: np.ndarray  # (n,)


@dataclass(slots=True)
class Watch:
    """What the monitor is fed: every vehicle within ``radius_m`` of the junction.

    SUMO hands these over in one call per step (a context subscription on the
    junction), positions and angles as it holds them. The monitor itself only
    checks vehicles touching the junction area plus its margin; the radius is
    well beyond that, so the cut changes no result. Sizes are read once per
    vehicle (they do not change).
    """

    junction_id: str
    radius_m: float
    sizes: dict[str, tuple[float, float]] = field(default_factory=dict)

    def subscribe(self, ls) -> None:
        c = ls.constants
        ls.junction.subscribeContext(
            self.junction_id,
            c.CMD_GET_VEHICLE_VARIABLE,
            self.radius_m,
            [c.VAR_POSITION, c.VAR_ANGLE],
        )

    def feed(
        self,
        ls,
        monitor: SafetyMonitor,
        t: float,
        gone: Collection[str] = (),
        people: People | None = None,
    ) -> None:
        """Hand the monitor this step's vehicles near the junction, sorted by id (but
        those ``gone``: taken out of SUMO since the step); and with ``people``, the same
        vehicles and this step's persons to its person check."""
        c = ls.constants
        near = ls.junction.getContextSubscriptionResults(self.junction_id) or {}
        vins = sorted(v for v in near if v not in gone)
        if not vins:
            monitor.observe(t, [], np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(0))
            if people is not None:
                people.check.observe(t, [], *_NONE, people.ids, people.xy, people.radius_m)
            return
        for v in vins:
            if v not in self.sizes:
                self.sizes[v] = (ls.vehicle.getLength(v), ls.vehicle.getWidth(v))
        xy = np.array([near[v][c.VAR_POSITION] for v in vins], dtype=float)
        ang = np.array([near[v][c.VAR_ANGLE] for v in vins], dtype=float)
        size = np.array([self.sizes[v] for v in vins], dtype=float)
        monitor.observe(t, vins, xy, ang, size[:, 0], size[:, 1])
        if people is not None:
            people.check.observe(
                t, vins, xy, ang, size[:, 0], size[:, 1], people.ids, people.xy, people.radius_m
            )
