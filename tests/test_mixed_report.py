"""The mixed-traffic grid's report: cells read from a grid's layout on disk, the
rolling share and the crossover worked out from them."""

from __future__ import annotations

import json
from pathlib import Path

from dica.tools import mixed_report


def _cell(root: Path, alg: str, share: float, vol: int, seed: int, delay: float, **h) -> None:
    d = root / "ch45" / alg / f"c{share:g}" / f"v{vol}" / f"s{seed}"
    d.mkdir(parents=True)
    humans = {"count": 10, "entered_on_red": 0, "outside_envelope": 0,
              "mean_wait_for_green_s": 2.0, "max_wait_for_green_s": 5.0, **h}  # fmt: skip
    m = {"mean_system_delay_s": delay, "throughput": 1.0, "collisions": 0,
         "sumo_collisions": 0, "humans": humans, "by_driver": {}}  # fmt: skip
    (d / "metrics.json").write_text(json.dumps(m))


def test_the_report_gives_the_rolling_share_and_the_crossover(tmp_path, capsys):
    for seed, rolled in ((12, 6), (21, 2)):
        _cell(tmp_path, "enhanced", 0, 300, seed, 10.0, rolling_greens=rolled)
        _cell(tmp_path, "enhanced", 0.5, 300, seed, 4.0, rolling_greens=1)
        _cell(tmp_path, "actuated", 0, 300, seed, 6.0)
        _cell(tmp_path, "fixed", 0, 300, seed, 8.0)
        _cell(tmp_path, "allway-stop", 0, 300, seed, 7.0)
    assert mixed_report.main([str(tmp_path)]) == 0
    text = (tmp_path / "mixed.md").read_text()
    row = next(r for r in text.splitlines() if r.startswith("| 300 | 0 |"))
    cols = [c.strip() for c in row.split("|")[1:-1]]
    assert cols[3] == "10.0" and cols[6] == "0.40" and cols[9] == "7.0"  # 8 of 20 rolled
    # 4 s above the better light at share 0, 2 s below at 0.5: crossing at 0.5 * 4 / 6
    assert "| 300 | 0.33 |" in text
    assert (tmp_path / "mixed.png").stat().st_size > 0
    # a line that dips below the light, rises above it and falls again: the crossover is
    # where it stays below, and the dip is said
    for seed in (12, 21):
        _cell(tmp_path, "enhanced", 0, 400, seed, 5.0)
        _cell(tmp_path, "enhanced", 0.5, 400, seed, 9.0)
        _cell(tmp_path, "enhanced", 1, 400, seed, 3.0)
        for share in (0, 0.5, 1):
            _cell(tmp_path, "actuated", share, 400, seed, 6.0)
    assert mixed_report.main([str(tmp_path)]) == 0
    assert "| 400 | 0.75 (below it at 0 as well) |" in (tmp_path / "mixed.md").read_text()
    assert mixed_report.main([str(tmp_path / "none")]) == 2
    assert "not a directory" in capsys.readouterr().err
