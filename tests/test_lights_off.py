"""A junction run signal-free whose net gives it a traffic light, with SUMO's own
drivers or people on foot: they obey a light, so it goes off and they go by the ICA's
greens (connected vehicles fly past any light). Left on, a walker given its crossing
stood at the light's red and stepped off after its slot, into vehicles planned around
it; a human driver given its green stood at the red, far behind its envelope."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.dica_cli import DICA, dica_run
from tests.user_nets import build_nets, make, tool

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def lit(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("lit")
    nets = build_nets(d)
    # a city grid with lights guessed at every junction, sidewalks and crossings
    walk = d / "litwalk.net.xml"
    make([tool("netgenerate"), "--grid", "--grid.number", "3", "--grid.length", "150",
          "--default.lanenumber", "2", "--default.speed", "13.89", "--tls.guess", "true",
          "--sidewalks.guess", "true", "--crossings.guess", "true",
          "--no-turnarounds", "true", "-o", str(walk)])  # fmt: skip
    return {"walk": walk, "joined": nets["joined"], "twins": nets["twins"]}


def _run(tmp_path: Path, name: str, *args: str):
    out = tmp_path / name
    p = dica_run([*DICA, "run", *args, "--out", str(out), "--quiet"],
                 capture_output=True, text=True, cwd=ROOT, timeout=600)  # fmt: skip
    return p, out


def test_people_at_a_lit_junction_cross_by_the_ica_alone(lit, tmp_path):
    p, out = _run(tmp_path, "peds", "--net", str(lit["walk"]), "--junction", "B1",
                  "--peds", "600", "--volume", "200", "--duration", "150")  # fmt: skip
    assert p.returncode == 0, p.stdout + p.stderr
    assert "traffic light B1 is off" in p.stderr
    m = json.loads((out / "metrics.json").read_text())
    w = m["walkers"]
    assert w["crossed"] > 40
    assert w["overran_slot"] == 0  # none stepped off after its slot (a red held them)
    assert w["person_hits"] == 0 and w["sumo_person_collisions"] == 0
    assert m["safety"]["overlaps"] == 0 and m["sumo_collisions"] == 0


def test_human_drivers_at_a_lit_joined_cluster_keep_their_envelopes(lit, tmp_path):
    p, out = _run(tmp_path, "mixed", "--net", str(lit["joined"]), "--junction", "cluster_A_B",
                  "--cav-share", "0.3", "--volume", "350", "--duration", "200")  # fmt: skip
    assert p.returncode == 0, p.stdout + p.stderr
    assert "traffic light cluster_A_B is off" in p.stderr
    m = json.loads((out / "metrics.json").read_text())
    h = m["humans"]
    assert h["given_green"] > 20
    assert h["entered_on_red"] == 0 and h["outside_envelope"] == 0
    assert m["safety"]["overlaps"] == 0 and m["sumo_collisions"] == 0


def test_a_light_over_a_junction_left_to_it_is_not_switched_off(lit, tmp_path):
    """One light runs the twins A and B: switching it off for A would take B's away."""
    p, _ = _run(tmp_path, "twin", "--net", str(lit["twins"]), "--junction", "A",
                "--cav-share", "0.5", "--duration", "30")  # fmt: skip
    assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr
    said = [ln for ln in p.stderr.strip().splitlines() if not ln.startswith("note: ")]
    assert len(said) == 1, p.stderr  # one line (and the notes on the net before it)
    assert "traffic light joinedS_A_B also runs junction B" in p.stderr
    assert "--junctions A,B" in p.stderr
    # connected vehicles alone fly past any light: the light stays, and the run runs
    p, _ = _run(tmp_path, "twin-cav", "--net", str(lit["twins"]), "--junction", "A",
                  "--duration", "60")  # fmt: skip
    assert p.returncode == 0, p.stdout + p.stderr
    assert "is off" not in p.stderr
