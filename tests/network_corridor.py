"""The built-in corridor and its embedded run, for the network cluster's tests."""

from __future__ import annotations

import re
from pathlib import Path

from tests.dica_cli import DICA, dica_run

ROOT = Path(__file__).resolve().parents[1]
DURATION = "60"
TRUCK = ('  <vType id="truck" vClass="truck" length="12" width="2.55" accel="2.6" decel="4.5" '
         'sigma="0.5" speedFactor="1" speedDev="0"/>')  # fmt: skip


def corridor_and_its_embedded_run(d: Path) -> dict:
    """The built-in corridor (four junctions), 80 s of its demand at 500 an hour per road
    in (one in five a truck), and its embedded run over DURATION: every junction under its
    own ICA core in one process. ``scen``: the options naming it for ``dica run`` and
    ``run_cluster.sh``."""
    from dica.sim_gateway.network_layouts import build_network
    from dica.sim_gateway.od_demand import OdDemand, write_od_routes

    built = build_network("corridor", d / "net")
    routes = d / "od.rou.xml"
    write_od_routes(built.net_path, built.junctions, OdDemand(500, 80, 12), routes)
    # every fifth vehicle a 12 m x 2.55 m truck: one turning right sweeps over the place
    # a vehicle waits in the lane beside it, so those lanes' lines move back, and every
    # role of a cluster must move them alike for its decisions to be the embedded run's
    text = routes.read_text().replace("<routes>\n", f"<routes>\n{TRUCK}\n", 1)
    routes.write_text(re.sub(r'id="v(\d*[05])" type="car"', r'id="v\1" type="truck"', text))
    scen = ["--net", str(built.net_path), "--routes", str(routes), "--junctions", "all"]
    emb = d / "embedded"
    p = dica_run(
        [*DICA, "run", *scen, "--duration", DURATION, "--out", str(emb), "--quiet"],
        capture_output=True, text=True, cwd=ROOT, timeout=300,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert p.stderr.count("lines moved back") == 4  # at each junction
    return {"scen": scen, "embedded": emb, "junctions": built.junctions}
