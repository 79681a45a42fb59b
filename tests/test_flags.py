"""Every command refuses a bad value with one line on stderr and exit status 2.

Checked before anything starts: no SUMO, no Zenoh session (nothing here needs
a router), never a traceback. The commands run in this process (``dica``'s own
entry point), so a bad value that slipped through would show as an exception.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from dica.tools.cli import main as dica

BAD = [
    (["run", "--margin", "-1"], "--margin must be between 0 and 5 m"),
    (["run", "--margin", "9"], "--margin must be between 0 and 5 m"),
    (["run", "--time-pad", "-0.1"], "--time-pad must be between 0 and 5 s"),
    (["run", "--green-late", "5.01"], "--green-late must be between 0 and 5 s, got 5.01"),
    (["run", "--green-late", "-0.01"], "--green-late must be between 0 and 5 s"),
    (["run", "--lead", "11"], "--lead must be between 0 and 9 s"),
    (["run", "--window", "-0.05"], "--window must be between 0 and 5 s"),
    (["run", "--window", "5.05"], "--window must be between 0 and 5 s"),
    (["run", "--window", "0.5", "--algorithm", "fixed"], "fixed does not take it"),
    (["run", "--window", "0.5", "--algorithm", "rdica"], "rdica does not take it"),
    (["run", "--seed", "-3"], "--seed must be between 0"),
    (["run", "--algorithm", "rdica", "--max-added-delay", "-0.01"], "--max-added-delay must be"),
    (["run", "--algorithm", "rdica", "--max-added-delay", "nan"], "--max-added-delay must be"),
    (["run", "--max-added-delay", "2"], "enhanced does not take it"),
    (["run", "--ev-notices"], "--ev-notices applies to rdica only"),
    (["run", "--algorithm", "rdica", "--ev-notices"], "give a network (--junctions)"),
    (["network", "--ev-notices"], "--ev-notices applies to --control dica --algorithm rdica"),
    (["ica", "--algorithm", "rdica", "--max-added-delay", "-1"], "--max-added-delay must be"),
    (["run", "--ramp", "0", "--volume-end", "600"], "--ramp must be between 1"),
    (["run", "--volume", "0.5"], "--volume must be between 1 and 2000 vehicles per 10 min"),
    (["run", "--duration", "-5"], "--duration must be above 0 and at most"),
    (["run", "--tile-size", "0"], "--tile-size must be between"),
    (["run", "--until-left", "0"], "--until-left must be between 1 and 1000000, got 0"),
    (["ica", "--margin", "-1"], "--margin must be between 0 and 5 m, got -1"),
    (["ica", "--time-pad", "7"], "--time-pad must be between 0 and 5 s, got 7"),
    (["ica", "--green-late", "5.01"], "--green-late must be between 0 and 5 s, got 5.01"),
    (["ica", "--max-age", "0"], "--max-age must be above 0 and at most 60 s"),
    (["ica", "--tile-size", "50"], "--tile-size must be between"),
    (["ica", "--idle-exit", "-1"], "--idle-exit must be above 0"),
    (["agent", "--id", "a", "--lead", "-1"], "--lead must be between 0 and 9 s"),
    (["agent", "--id", "a", "--lead", "soon"], "--lead: wants a number of seconds or auto"),
    (["agent", "--id", "a", "--retry", "0"], "--retry must be between"),
    (["agent", "--id", "a", "--margin", "-2"], "--margin must be between 0 and 5 m"),
    (["gateway", "--speed", "0"], "--speed must be above 0 and at most 100"),
    (["gateway", "--resend", "0"], "--resend must be between"),
    (["gateway", "--step-timeout", "0"], "--step-timeout must be between"),
    (["gateway", "--checkpoint-every", "0"], "--checkpoint-every must be between"),
    (["gateway", "--agents", "0"], "--agents must be between 1"),
    (["gateway", "--per-agent", "-1"], "--per-agent must be between 0"),
    (["gateway", "--peers-timeout", "0"], "--peers-timeout must be above 0"),
    (["gateway", "--time-pad", "-1"], "--time-pad must be between 0 and 5 s"),
    (["gateway", "--green-late", "6"], "--green-late must be between 0 and 5 s"),
    (["run", "--algorithm", "enhanced", "--solver", "ga"], "--solver applies to rdica only"),
    (["run", "--revocation", "drop"], "--revocation applies to rdica only"),
    (["run", "--tile-size", "2"], "--tile-size applies to tiles only"),
    (["ica", "--solver", "exhaustive"], "--solver applies to rdica only"),
    (["ica", "--algorithm", "fixd"], "unknown controller 'fixd'"),
    (["run", "--layout", "ch45", "--junction", "ZZZ"], "--junction names a junction of --net"),
    (["run", "--net", "x.net.xml"], "--net needs --junction"),
    (["run", "--out", "/proc/no/such/dir"], "cannot write into /proc/no/such/dir"),
    (["run", "--margin", "abc"], "argument --margin: invalid float value: 'abc'"),
    (["link", "set", "/nonexistent"], "no link emulator spec"),
    (["bench", "timing", "--seeds", "x"], "--seeds wants integers"),
    (["bench", "timing", "--profiles", "storm"], "unknown profile"),
    (["bench", "routes", "--repeat", "0"], "--repeat wants 1 or more runs"),
    (["run", "--sumo-args", '"--fcd-output f.xml'], "No closing quotation"),
    (["experiment", "--out", "/tmp/x", "--extra", '--sumo-args "x'], "No closing quotation"),
    (["bench", "network", "--repeat", "0"], "--repeat wants 1 or more runs"),
    (["run", "--approach-weights", "N_in=inf"], "finite weights of 0 or more"),
    (["run", "--approach-weights", "N_in=-1"], "finite weights of 0 or more"),
    (
        [
            "bench",
            "routes",
            "--net",
            "/no/such.net.xml",
            "--junction",
            "C",
            "--routes",
            "x.rou.xml",
        ],
        "net not found: /no/such.net.xml",
    ),
]


@pytest.mark.parametrize(("args", "says"), BAD, ids=[" ".join(a) for a, _ in BAD])
def test_a_bad_value_is_one_clear_line(args, says, capsys):
    assert dica(args) == 2
    err = capsys.readouterr().err
    assert says in err, err
    assert len(err.strip().splitlines()) == 1, err


def test_experiment_passes_a_lone_option_as_extra():
    """`dica experiment --extra --no-platoon` hands the flag to every run, as a user
    would write it (argparse alone takes an option-like value for an option)."""
    from dica.tools.experiment import parser
    from dica.tools.options import joined as _joined_extra

    argv = ["--out", "x", "--extra", "--no-platoon", "--seeds", "1"]
    assert parser().parse_args(_joined_extra(argv)).extra == "--no-platoon"
    assert _joined_extra(["--extra", "--ev-prob 0.02"]) == ["--extra=--ev-prob 0.02"]


def test_bench_routes_takes_a_user_s_relative_paths_and_says_why_a_file_fails(
    tmp_path, monkeypatch, capsys
):
    """The runs start in the project's directory, so the user's paths are made absolute
    first; a route file the run refuses is one line, not a traceback."""
    from dica.sim_gateway.scenario import default_scenario

    sc = default_scenario("ch45")
    net = tmp_path / "x.net.xml"
    net.write_bytes(Path(sc.net_path).read_bytes())
    (tmp_path / "ok.rou.xml").write_text(
        '<routes><flow id="f" begin="0" end="9" number="2" from="N_in" to="S_out"/></routes>'
    )
    (tmp_path / "bad.rou.xml").write_text(
        '<routes><flow id="f" begin="0" end="9" number="2" from="N_in" to="S_out" '
        'arrivalPos="1"/></routes>'
    )
    monkeypatch.chdir(tmp_path)
    args = ["bench", "routes", "--net", "x.net.xml", "--junction", sc.junction_id,
            "--duration", "20", "--repeat", "1", "--routes"]  # fmt: skip
    assert dica([*args, "ok.rou.xml"]) == 0
    assert "enhanced DICA at" in capsys.readouterr().out
    assert dica([*args, "bad.rou.xml"]) == 2
    err = capsys.readouterr().err
    assert "arrivalPos 1 on S_out" in err and len(err.strip().splitlines()) == 1, err


def test_human_drivers_in_a_network_are_refused_as_such(tmp_path, capsys):
    """A route file's human drivers are served at one junction; across several, one line
    says they are not yet (before anything starts)."""
    from tests.user_nets import ROUTES, make, tool

    net = tmp_path / "grid.net.xml"
    make([tool("netgenerate"), "--grid", "--grid.number", "3", "--grid.length", "200",
          "--no-turnarounds", "true", "-o", str(net)])  # fmt: skip
    routes = tmp_path / "r.rou.xml"
    routes.write_text(ROUTES)
    args = ["run", "--net", str(net), "--junctions", "A1,B1", "--routes", str(routes),
            "--cav-share", "0.5", "--out", str(tmp_path / "o")]  # fmt: skip
    assert dica(args) == 2
    err = capsys.readouterr().err
    assert "several junctions do not serve them yet" in err, err
    assert len(err.strip().splitlines()) == 1, err


def test_sumo_options_are_taken_as_written_after_sumo_args():
    """``--sumo-args --junction-taz``: argparse alone took the lone option-like value for
    an option of its own and said "expected one argument"."""
    from dica.tools.options import joined

    assert joined(["run", "--sumo-args", "--junction-taz", "--seed", "3"]) == [
        "run", "--sumo-args=--junction-taz", "--seed", "3"]  # fmt: skip


def test_link_set_refuses_a_role_the_emulator_has_not(tmp_path, capsys):
    """`dica link set --role agent` (for agents) changed nothing and said nothing."""
    from dica.deploy.linkem import Proxy, write_spec

    write_spec(tmp_path, [Proxy("ica", "ica", 7001, 7447), Proxy("agent-1", "agents", 7002, 7447)])
    assert dica(["link", "set", str(tmp_path), "--role", "agent", "--delay", "5"]) == 2
    err = capsys.readouterr().err
    assert "this emulator's roles are agents, ica, or all" in err, err
    assert dica(["link", "set", str(tmp_path), "--role", "agents", "--delay", "5"]) == 0
