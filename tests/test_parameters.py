"""No function of the decision core takes more than 12 parameters.

Values that travel together go as one named bundle (a dataclass, a named
tuple): a call with dozens of positional floats passes numba's type check
and Python's with two of them swapped.
"""

from __future__ import annotations

import ast
from pathlib import Path

CORE = Path(__file__).resolve().parents[1] / "ica" / "core"
MAX_PARAMETERS = 12  # self counted, and *args and **kwargs as one each


def parameter_count(args: ast.arguments) -> int:
    star = (args.vararg is not None) + (args.kwarg is not None)
    return len(args.posonlyargs) + len(args.args) + len(args.kwonlyargs) + star


def too_many(source: str, name: str) -> list[str]:
    """The functions (lambdas too) in ``source`` with more than MAX_PARAMETERS."""
    found = []
    for node in ast.walk(ast.parse(source, name)):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda):
            n = parameter_count(node.args)
            if n > MAX_PARAMETERS:
                label = getattr(node, "name", "lambda")
                found.append(f"{name}:{node.lineno} {label} takes {n}")
    return found


def test_no_function_in_the_core_takes_more_than_12_parameters():
    files = sorted(CORE.rglob("*.py"))
    assert any(p.parent.name == "kernels" for p in files)  # the walk reaches the kernels
    bad = [f for p in files for f in too_many(p.read_text(), str(p.relative_to(CORE)))]
    assert not bad, "\n".join(bad)


def test_the_count_sees_every_kind_of_parameter():
    """The check counts positional-only, keyword-only, star and self parameters, in
    methods, nested functions and lambdas: 12 passes, 13 does not."""
    twelve = ", ".join(f"a{i}" for i in range(12))
    assert too_many(f"def f({twelve}): pass", "x") == []
    for source in (
        f"def f({twelve}, b): pass",
        f"def f({twelve}, /, *, b): pass",
        "def f(a0, a1, a2, a3, a4, a5, a6, a7, a8, a9, a10, *args, **kw): pass",
        f"class C:\n    def m(self, {twelve}): pass",
        f"def outer():\n    def inner({twelve}, b): pass",
        f"g = lambda {twelve}, b: 0",
        f"async def f({twelve}, b): pass",
    ):
        assert len(too_many(source, "x")) == 1, source
