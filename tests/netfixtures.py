"""Hand-written test networks (``tests/nets/<name>/``) built with the project's netconvert flags.

They check that the net reader is not tied to the dissertation's layouts:
connections are left to netconvert's guess, junction id is ``J``.
"""

from __future__ import annotations

from pathlib import Path

from dica.sim_gateway.scenario import run_netconvert

NETS_DIR = Path(__file__).resolve().parent / "nets"
FIXTURE_NETS: tuple[str, ...] = ("tee", "skewed")
FIXTURE_JUNCTION_ID = "J"


def build_fixture_net(name: str, out_dir: Path) -> Path:
    """Build ``tests/nets/<name>/`` into ``out_dir/<name>.net.xml`` and return that path."""
    if name not in FIXTURE_NETS:
        raise ValueError(f"unknown fixture net {name!r}; known: {', '.join(FIXTURE_NETS)}")
    src = NETS_DIR / name
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    net = out_dir / f"{name}.net.xml"
    run_netconvert(
        src / f"{name}.nod.xml",
        src / f"{name}.edg.xml",
        net,
        extra_args=["--default.junctions.type", "priority"],
    )
    return net
