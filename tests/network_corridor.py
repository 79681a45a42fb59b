"""The built-in corridor and its embedded run, for the network cluster's tests."""

from __future__ import annotations

from pathlib import Path

from tests.dica_cli import DICA, dica_run

ROOT = Path(__file__).resolve().parents[1]
DURATION = "60"


def corridor_and_its_embedded_run(d: Path) -> dict:
    """The built-in corridor (four junctions), 80 s of its demand at 500 an hour per road
    in, and its embedded run over DURATION: every junction under its own ICA core in one
    process. ``scen``: the options naming it for ``dica run`` and ``run_cluster.sh``."""
    from dica.sim_gateway.network_layouts import build_network
    from dica.sim_gateway.od_demand import OdDemand, write_od_routes

    built = build_network("corridor", d / "net")
    routes = d / "od.rou.xml"
    write_od_routes(built.net_path, built.junctions, OdDemand(500, 80, 12), routes)
    scen = ["--net", str(built.net_path), "--routes", str(routes), "--junctions", "all"]
    emb = d / "embedded"
    p = dica_run(
        [*DICA, "run", *scen, "--duration", DURATION, "--out", str(emb), "--quiet"],
        capture_output=True, text=True, cwd=ROOT, timeout=300,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    return {"scen": scen, "embedded": emb, "junctions": built.junctions}
