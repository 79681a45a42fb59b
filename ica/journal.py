"""The ICA's journal: every decision that binds it, on disk before anyone hears of it.

A confirmation promises a vehicle a piece of space and time. If the ICA
crashes and comes back without it, the next vehicle may be promised the same
piece. So each DETECT taken, each confirmation given and each reservation
freed is appended here (and by default synced to disk) before the answer is
sent, and a restarted ICA replays the journal into a fresh core before it
serves again: no confirmation after the restart conflicts with one before.

The file is a stream of msgpack maps. A record cut short by a crash is the
last one and was never answered, so it is dropped on replay. A DETECT keeps
what the detector read (an emergency vehicle, its speed): reactive DICA's
priority rests on it, so a restarted ICA still lets the EV go first. A walker's
slot is kept too: a restarted ICA never confirms a vehicle through it, and so is a
human driver's green (rebuilt at the same time from the same limits) and each
shrinking of its reservations. So is reactive DICA's event each time it changes
(the reordering, the revocations still unanswered): a restarted ICA asks those
vehicles again rather than forget it revoked them. Journals written before the flag
existed replay with every vehicle a normal one.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import msgpack
import numpy as np

from dica.ica.core.controller import Controller
from dica.ica.core.envelope import human_limits
from dica.ica.core.request import Confirmation, RequestError, Tss
from dica.ica.core.walk import WalkSlot


class JournalError(Exception):
    """A journal that cannot be opened or read."""


@dataclass(slots=True)
class Replayed:
    detects: int = 0
    confirmations: int = 0
    cancels: int = 0
    walks: int = 0
    greens: int = 0
    revocations: int = 0  # revocations still unanswered, awaited again (reactive DICA)
    humans: list[str] = field(default_factory=list)  # human drivers' VINs: no agent's
    skipped: int = 0  # records the core refused (a geometry that changed, a bad record)
    truncated: bool = False


class Journal:
    """Append-only record of an ICA's binding decisions (``sync``: fsync each one)."""

    def __init__(self, path: Path, sync: bool = True) -> None:
        self.path = path
        self.sync = sync
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._f = open(path, "ab")  # noqa: SIM115 - held open for the ICA's life
        except OSError as e:
            raise JournalError(f"cannot open the journal {path}: {e}") from None
        self.written = 0

    def close(self) -> None:
        self._f.close()

    def _write(self, rec: dict) -> None:
        self._f.write(msgpack.packb(rec, use_bin_type=True))
        self._f.flush()
        if self.sync:
            os.fsync(self._f.fileno())
        self.written += 1

    def detect(
        self, vin: str, lane: str, t_s: float, ev: bool = False, speed_mps: float | None = None
    ) -> None:
        """``ev``: an emergency vehicle; ``speed_mps``: its speed at the detector (None:
        not measured)."""
        self._write(
            {"k": "detect", "vin": vin, "lane": lane, "t": t_s, "ev": ev, "speed": speed_mps}
        )

    def confirm(self, c: Confirmation, length_m: float, width_m: float, in_lane: str) -> None:
        self._write(
            {
                "k": "confirm",
                "vin": c.vin,
                "seq": c.seq,
                "route": c.route_id,
                "lane": in_lane,
                "length": length_m,
                "width": width_m,
                "t": _f8(c.tss.t_s),
                "x": _f8(c.tss.x_m),
                "y": _f8(c.tss.y_m),
                "h": _f8(c.tss.heading_rad),
                "entry": c.entry_time_s,
                "exit": c.exit_time_s,
                "delay": c.delay_s,
                "iterations": c.iterations,
            }
        )

    def cancel(self, vin: str, seq: int) -> None:
        self._write({"k": "cancel", "vin": vin, "seq": seq})

    def across(self, person: str, crossing: str, t_s: float) -> None:
        """A walker's slot brought forward to ``t_s``: the roadside saw it across."""
        self._write({"k": "across", "person": person, "crossing": crossing, "t": t_s})

    def walk(self, slot: WalkSlot) -> None:
        """A walker's slot, as the core holds it (:class:`ica.core.walk.WalkSlot`)."""
        self._write(
            {"k": "walk", "person": slot.person, "crossing": slot.crossing,
             "start": slot.start_s, "end": slot.end_s, "side": slot.side,
             "near": slot.near_m, "v_lo": slot.v_lo, "v_hi": slot.v_hi, "eta": slot.eta_s,
             "near_lo": slot.near_lo_m, "late": slot.late_s}
        )  # fmt: skip

    def human(self, vin: str) -> None:
        """``vin`` is a human driver: the roadside speaks for it, no agent."""
        self._write({"k": "human", "vin": vin})

    def green(self, lit) -> None:
        """A human driver's green (a :class:`schemas.messages.Lit`)."""
        self._write(
            {"k": "green", "vin": lit.vin, "green": lit.green_s, "asked": lit.asked_s,
             "near": lit.near_m, "length": lit.length_m, "width": lit.width_m,
             "routes": list(lit.routes), "speed": lit.speed_mps}
        )  # fmt: skip

    def unlit(self, vin: str, green_s: float, crossing: str = "") -> None:
        """The roadside dropped ``vin``'s green of ``green_s`` (late): its reservations
        went. With a ``crossing``, ``vin`` is a walker kept at its kerb and ``green_s``
        its slot's start."""
        self._write({"k": "unlit", "vin": vin, "green": green_s, "crossing": crossing})

    def reactive(self, snapshot: dict) -> None:
        """Reactive DICA's event as it now stands (:meth:`ReactiveDica.snapshot`): the
        last one replayed is the one carried on."""
        self._write({"k": "reactive", "state": snapshot})

    def sighting(self, seen) -> None:
        """A human driver's reservations shrunk to where it was seen (a
        :class:`schemas.messages.Sighting`)."""
        self._write(
            {"k": "sighting", "vin": seen.vin, "t": seen.t_s, "lane": seen.lane,
             "s": seen.s_m, "v": seen.speed_mps}
        )  # fmt: skip


def records(path: Path) -> tuple[list[dict], bool]:
    """The journal's records in order, and whether a torn record ended it."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return [], False
    except OSError as e:
        raise JournalError(f"cannot read the journal {path}: {e}") from None
    unpacker = msgpack.Unpacker(raw=False)
    unpacker.feed(data)
    out: list[dict] = []
    try:
        for rec in unpacker:
            if isinstance(rec, dict):
                out.append(rec)
    except (msgpack.ExtraData, msgpack.FormatError, msgpack.StackError, ValueError):
        return out, True
    return out, unpacker.tell() < len(data)


def confirmation_of(rec: dict) -> Confirmation:
    return Confirmation(
        vin=rec["vin"],
        seq=int(rec["seq"]),
        route_id=rec["route"],
        tss=Tss(_arr(rec["t"]), _arr(rec["x"]), _arr(rec["y"]), _arr(rec["h"])),
        entry_time_s=float(rec["entry"]),
        exit_time_s=float(rec["exit"]),
        delay_s=float(rec["delay"]),
        iterations=int(rec["iterations"]),
    )


def replay(path: Path, ica: Controller) -> Replayed:
    """Rebuild the core's state from the journal (before serving again)."""
    out = Replayed()
    recs, out.truncated = records(path)
    cfg = ica.config  # the ICA's own limits, as when it decided
    limits = human_limits(cfg.caps.road_mps, cfg.green_late_s)
    event = None
    for rec in recs:
        try:
            kind = rec.get("k")
            if kind == "detect":
                speed = rec.get("speed")  # absent or None in older journals
                ica.detect(
                    rec["vin"],
                    rec["lane"],
                    float(rec["t"]),
                    emergency=rec.get("ev", False) is True,
                    speed_mps=None if speed is None else float(speed),
                )
                out.detects += 1
            elif kind == "confirm":
                ica.adopt(
                    confirmation_of(rec), float(rec["length"]), float(rec["width"]), rec["lane"]
                )
                out.confirmations += 1
            elif kind == "cancel":
                ica.cancel(rec["vin"], int(rec["seq"]))
                out.cancels += 1
            elif kind == "walk" and getattr(ica, "walks", None) is not None:
                ica.walks.reserve(
                    WalkSlot(
                        str(rec["person"]), str(rec["crossing"]), float(rec["start"]),
                        float(rec["end"]), int(rec["side"]), float(rec["near"]),
                        float(rec["v_lo"]), float(rec["v_hi"]), float(rec["eta"]),
                        float(rec.get("near_lo", 0.0)), float(rec.get("late", 0.0)),
                    )
                )  # fmt: skip
                out.walks += 1
            elif kind == "green" and getattr(ica, "greens", None) is not None:
                ica.relight(
                    str(rec["vin"]), float(rec["green"]), float(rec["asked"]),
                    float(rec["length"]), float(rec["width"]), limits,
                    float(rec["near"]), tuple(str(r) for r in rec["routes"]),
                    float(rec.get("speed", 0.0)),
                )  # fmt: skip
                out.greens += 1
            elif kind == "unlit" and rec.get("crossing"):
                ica.unwalk(str(rec["vin"]), str(rec["crossing"]), float(rec["green"]))
            elif kind == "unlit" and getattr(ica, "greens", None) is not None:
                ica.unlight(str(rec["vin"]), float(rec["green"]))
            elif kind == "sighting" and getattr(ica, "greens", None) is not None:
                ica.tighten(str(rec["vin"]), float(rec["t"]), float(rec["s"]), float(rec["v"]),
                            str(rec["lane"]), limits)  # fmt: skip
            elif kind == "human":
                out.humans.append(str(rec["vin"]))
            elif kind == "reactive" and hasattr(ica, "restore_snapshot"):
                event = rec["state"]
            elif kind == "across" and getattr(ica, "walks", None) is not None:
                ica.walks.across(str(rec["person"]), str(rec["crossing"]), float(rec["t"]))
            else:
                out.skipped += 1
        except (RequestError, KeyError, TypeError, ValueError):
            out.skipped += 1
    if event is not None:  # after every confirmation and cancel it knew of
        try:
            ica.restore_snapshot(event)
            out.revocations = len(ica.pending())
        except (KeyError, TypeError, ValueError):
            out.skipped += 1
    return out


def _f8(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a, dtype="<f8").tobytes()


def _arr(b: bytes) -> np.ndarray:
    return np.frombuffer(b, dtype="<f8").astype(float)
