"""Counts over time and the tables of events: confirmations, rejections (and
withdrawn plans), reorderings for emergency vehicles (and revoked plans that
stood). Each table row is fixed-width text whose columns the view's title names.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import rerun as rr

from dica.sim_gateway.recording.rows import RowBuffer


class Tables:
    """``counts/*`` series and ``tables/*`` text logs."""

    def __init__(self, rows: RowBuffer) -> None:
        self._rows = rows
        self.n_confirmed = 0
        self.n_rejected = 0

    @staticmethod
    def series(rec: rr.RecordingStream) -> None:
        """The counts' names, static."""
        rec.log("counts/vehicles", rr.SeriesLines(names="vehicles in the region"), static=True)
        rec.log("counts/confirmed", rr.SeriesLines(names="confirmed so far"), static=True)
        rec.log("counts/rejected", rr.SeriesLines(names="rejected so far"), static=True)

    def vehicles(self, times: np.ndarray, counts: np.ndarray) -> None:
        """Vehicles in the region at each of ``times``."""
        self._rows.add_many(
            "counts/vehicles",
            rr.Scalars,
            times,
            np.ones(len(times), int),
            scalars=counts.astype(float),
        )

    def confirmed(
        self,
        t_s: float,
        vin: str,
        route_id: str,
        entry_time_s: float,
        exit_time_s: float,
        delay_s: float,
        rounds: int,
    ) -> None:
        """A confirmation: VIN, route, entry and exit [s], delay [s] (or -), getCV rounds."""
        self.n_confirmed += 1
        self._rows.add("counts/confirmed", rr.Scalars, t_s, 1, scalars=np.array([self.n_confirmed]))
        delay = f"{delay_s:6.2f}" if math.isfinite(delay_s) else "     -"
        rounds_txt = f"{rounds:3d}" if rounds >= 0 else "  -"
        self._rows.add(
            "tables/confirmed",
            rr.TextLog,
            t_s,
            1,
            text=[
                f"{vin:<8} {route_id:<15} {entry_time_s:8.2f} {exit_time_s:8.2f} "
                f"{delay} {rounds_txt}"
            ],
        )

    def rejected(self, t_s: float, vin: str, reason: str, detail: str = "") -> None:
        """A rejection or a withdrawn plan: VIN, reason, detail."""
        self.n_rejected += 1
        text = f"{vin:<8} {reason:<17} {detail[:60]}".rstrip()
        self._rows.add("tables/rejected", rr.TextLog, t_s, 1, text=[text])
        self._rows.add("counts/rejected", rr.Scalars, t_s, 1, scalars=np.array([self.n_rejected]))

    def reordered(
        self,
        t_s: float,
        ev: str,
        solver: str,
        order: Sequence[str],
        ev_entry_before_s: float,
        ev_entry_after_s: float,
        revoked: Sequence[str],
        refused: str,
    ) -> None:
        """A reordering: EV, solver, the EV's entry before and after, the new order with
        revoked vehicles starred; or why the present order was kept."""
        star = set(revoked)
        listed = " ".join(f"{v}*" if v in star else v for v in order)
        if refused:
            text = f"{ev:<8} {solver:<10} present order kept: {refused[:80]}"
        else:
            text = (
                f"{ev:<8} {solver:<10} {ev_entry_before_s:7.2f} {ev_entry_after_s:7.2f}  {listed}"
            )
        self._rows.add("tables/reorders", rr.TextLog, t_s, 1, text=[text])

    def kept(self, t_s: float, vin: str, why: str) -> None:
        """A revoked plan that stands after all, and why."""
        self._rows.add("tables/reorders", rr.TextLog, t_s, 1, text=[f"{vin:<8} {why}"])
