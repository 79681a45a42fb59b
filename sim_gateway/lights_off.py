"""A junction run signal-free whose net gives it a traffic light: the light goes off.

Connected vehicles fly their plans past any light (speed mode 32), so a light left
running at a signal-free junction changes nothing for them. SUMO's own drivers
(``--cav-share``) and people on foot obey it, though: a human driver given its green by
the ICA, or a walker given its crossing, would stand at the light's red, fall behind
the reservation made for it, and meet the vehicles planned around that reservation
(a netgenerate grid with lights, sidewalks and crossings, 600 people an hour at each
crossing of B1: 1,138 steps of vehicles touching people and 515 of SUMO's person
collisions in 300 s). So where they share the junction, its light is switched off
(SUMO's ``off`` program): they go by the ICA's greens alone.
"""

from __future__ import annotations

from collections.abc import Sequence

from dica.sim_gateway.runconfig import RunError


def switch_off(ls, junction_ids: Sequence[str]) -> list[str]:
    """Switch off every traffic light that controls one of ``junction_ids``; a line saying
    which (none if none). A light that also controls a junction not among them (one
    light over two nearby junctions) is refused in one line: switching it off would
    take that junction's light away too."""
    chosen = set(junction_ids)
    off = []
    for tls in ls.trafficlight.getIDList():
        ruled = tuple(ls.trafficlight.getControlledJunctions(tls))
        mine = sorted(chosen.intersection(ruled))
        if not mine:
            continue
        others = sorted(set(ruled) - chosen)
        if others:
            raise RunError(
                f"junction {mine[0]}'s traffic light {tls} also runs junction {others[0]}: "
                "its human drivers and people on foot would obey it, so the light must go "
                f"off; choose its junctions together (--junctions {','.join(sorted(ruled))}) "
                "or leave them to the light"
            )
        ls.trafficlight.setProgram(tls, "off")
        off.append(tls if mine == [tls] else f"{tls} (junction {', '.join(mine)})")
    if not off:
        return []
    which = f"traffic lights {', '.join(off)} are" if len(off) > 1 else f"traffic light {off[0]} is"
    return [f"{which} off: human drivers and people on foot go by the ICA's greens"]
