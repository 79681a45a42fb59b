"""The packages import downward only, and install under one namespace.

The layers (``docs/architecture.md`` draws them): the decision core and the wire
at the bottom, importing nothing of the project; the deployment's transport on
the wire; the ICA's edges, the vehicles and the simulation above; the
commands on top. Every import is read from the source (module level or inside a
function), so a lazy import cannot hide an upward one.
"""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("ica", "schemas", "deploy", "vehicle_agent", "sim_gateway", "tools")

# what each part may import besides itself, most specific part first
MAY_IMPORT: dict[str, tuple[str, ...]] = {
    "dica.ica.core": (),
    "dica.schemas": (),
    "dica.deploy": ("dica.schemas",),
    "dica.ica.convert": ("dica.ica.core", "dica.schemas"),
    "dica.ica.netfile": ("dica.ica.core",),
    "dica.ica.journal": ("dica.ica.core",),
    "dica.ica": (
        "dica.ica.core",
        "dica.ica.convert",
        "dica.ica.journal",
        "dica.schemas",
        "dica.deploy",
    ),
    "dica.vehicle_agent": ("dica.ica.core", "dica.ica.convert", "dica.schemas", "dica.deploy"),
    "dica.sim_gateway": (
        "dica.ica.core",
        "dica.ica.netfile",
        "dica.vehicle_agent",
        "dica.schemas",
        "dica.deploy",
    ),
    "dica.tools": ("dica",),
}


# within a part, modules that must stay apart: the Zenoh gateway runs the world, not the
# embedded runner (which holds the controller and the vehicles in one process)
APART: dict[str, tuple[str, ...]] = {
    "dica.sim_gateway.gateway": ("dica.sim_gateway.embedded",),
    "dica.sim_gateway.safety": ("dica.ica",),
}


def _within(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def part_of(module: str) -> str:
    """The part of :data:`MAY_IMPORT` a module belongs to."""
    return next(p for p in MAY_IMPORT if _within(module, p))


def upward_imports(module: str, source: str) -> list[str]:
    """The project modules ``module`` imports that its part may not."""
    part = part_of(module)
    allowed = (part, *MAY_IMPORT[part])
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        for name in names:
            if _within(name, "dica") and not any(_within(name, a) for a in allowed):
                out.append(f"{module} imports {name} (line {node.lineno})")
            elif any(_within(name, a) for a in APART.get(module, ())):
                out.append(f"{module} imports {name} (line {node.lineno}), kept apart")
    return out


def modules() -> list[tuple[str, Path]]:
    return [
        (
            ".".join(("dica", *p.relative_to(ROOT).with_suffix("").parts)).removesuffix(
                ".__init__"
            ),
            p,
        )
        for folder in FOLDERS
        for p in sorted((ROOT / folder).rglob("*.py"))
    ]


def test_every_import_runs_downward():
    found = [v for m, p in modules() for v in upward_imports(m, p.read_text())]
    assert not found, "\n".join(found)


@pytest.mark.parametrize(
    ("module", "source"),
    [
        ("dica.ica.core.dtot", "from dica.sim_gateway.world import World"),
        ("dica.ica.core.dica", "def f():\n    import dica.deploy.transport\n"),
        ("dica.schemas.codec", "from dica.ica.core.request import Request"),
        ("dica.deploy.seal", "from dica.ica.service import IcaService"),
        ("dica.vehicle_agent.machine", "from dica.sim_gateway.world import World"),
        ("dica.sim_gateway.gateway", "from dica.tools.options import add"),
        ("dica.sim_gateway.world", "from dica.ica.service import IcaService"),
        ("dica.sim_gateway.gateway", "from dica.sim_gateway.embedded import run"),
        ("dica.sim_gateway.safety", "from dica.ica.core.route import Route"),
    ],
)
def test_an_upward_import_is_caught(module, source):
    assert upward_imports(module, source), f"{module}: {source!r} passed"


def test_the_core_imports_nothing_above_it_even_the_ica_edge():
    assert upward_imports("dica.ica.core.dica", "from dica.ica.netfile import load_intersection")
    assert not upward_imports("dica.ica.service", "from dica.ica.core.dica import Dica")


def test_every_package_installs_under_dica_and_nothing_generic():
    """What `pip install .` puts into site-packages: the explicit package list of
    pyproject.toml, each mapped from its folder. Every package of the tree is in it,
    and nothing but dica.* (no top-level tools or schemas)."""
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(cfg["packages"])
    folders = {k: ROOT / v for k, v in cfg["package-dir"].items()}
    assert set(folders) == {f"dica.{f}" for f in FOLDERS}
    tree = {
        ".".join((top, *init.parent.relative_to(folder).parts))
        for top, folder in folders.items()
        for init in folder.rglob("__init__.py")
        if ".venv" not in init.parts and "__pycache__" not in init.parts
    }
    assert listed == tree, f"missing {tree - listed}, not in the tree {listed - tree}"
    assert all(name.startswith("dica.") for name in listed)
    assert cfg["package-data"]["dica.deploy"], "the Zenoh configs travel with dica.deploy"
