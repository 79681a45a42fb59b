"""The ICA core imports and decides with transport, SUMO, Rerun and file I/O blocked."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_core_runs_with_io_modules_blocked(ch45_net):
    from dica.ica.netfile import load_intersection

    inter = load_intersection(ch45_net.net_path, ch45_net.junction_id)
    import pickle

    blob = pickle.dumps(inter)
    script = textwrap.dedent(
        """
        import builtins, importlib.abc, io, os, pickle, sys
        BLOCKED = ("zenoh", "libsumo", "traci", "sumolib", "rerun", "msgpack", "dica.sim_gateway",
                   "dica.vehicle_agent", "dica.schemas", "dica.deploy", "dica.tools", "socket",
                   "sqlite3")
        def blocked(name):
            return any(name == b or name.startswith(b + ".") for b in BLOCKED)
        class Block(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path=None, target=None):
                if blocked(name):
                    raise ImportError(f"blocked: {name}")
                return None
        blob = sys.stdin.buffer.read()
        # numba compiles the core's inner loops; like numpy it is a toolchain, not
        # a transport, but its import reaches socket through importlib.metadata
        import numba  # noqa
        preloaded = set(sys.modules)
        sys.meta_path.insert(0, Block())
        import dica.ica.core.dica, dica.ica.core.proposal  # noqa
        def no_io(*a, **k):
            raise OSError("file I/O is not allowed in the core")
        builtins.open = io.open = os.open = no_io
        inter = pickle.loads(blob)
        from dica.ica.core.dica import Dica
        from dica.ica.core.proposal import propose
        ica = Dica(inter)
        r = inter.routes[0]
        ica.detect("a", r.in_lane, 0.0)
        req = propose(r, vin="a", seq=0, t0_s=0.0, dist_to_entry_m=50.0, speed_mps=10.0)
        out = ica.handle(req, 0.0)
        assert type(out).__name__ == "Confirmation", out
        bad = [m for m in sys.modules if blocked(m) and m not in preloaded]
        assert not bad, bad
        print("ok")
        """
    )
    out = subprocess.run(
        [sys.executable, "-c", script], input=blob, capture_output=True, cwd=ROOT, timeout=120
    )
    assert out.returncode == 0, out.stderr.decode()
    assert out.stdout.decode().strip().endswith("ok")
