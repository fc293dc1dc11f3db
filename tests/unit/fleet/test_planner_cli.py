"""``python -m fleet.planner`` refuses unusable input with exit 2 and the reason (file:line for
LoTLan), before it touches its data directory or connects anywhere."""

from __future__ import annotations

from pathlib import Path

import pytest

from fleet.planner.__main__ import main
from tests.unit.fleet.planner_data import JOBS

ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = ROOT / "ontology" / "examples" / "agv-fleet.ttl"
MAP = '{"mapId": "hall-t", "width": 12, "height": 8, "stations": [{"name": "load-1", "x": 2, "y": 6}, ' \
      '{"name": "unload-1", "x": 10, "y": 6}, {"name": "load-2", "x": 2, "y": 2}, {"name": "unload-2", "x": 10, "y": 2}]}'

CASES = [  # (id, LoTLan text, map text, expected in stderr)
    ("a syntax error", JOBS.replace("    Transport\n    From atLoad", "    Transprt\n    From atLoad"), MAP,
     "jobs.tl:50:5: unexpected 'Transprt'"),
    ("a location not on the map", JOBS, MAP.replace('"unload-2"', '"elsewhere"'),
     "jobs.tl:16: Location otherUnload (name 'unload-2') is no station of map 'hall-t'"),
    ("a map that is not JSON", JOBS, "{", "not JSON"),
]


@pytest.mark.parametrize(("text", "site", "expected"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_unusable_input_exits_2_and_starts_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str,
                                                   site: str, expected: str) -> None:
    (tmp_path / "jobs.tl").write_text(text, encoding="utf-8")
    (tmp_path / "map.json").write_text(site, encoding="utf-8")
    data = tmp_path / "planner-data"
    code = main(["--plant", str(EXAMPLE), "--lotlan", str(tmp_path / "jobs.tl"), "--data-dir", str(data),
                 "--manager-data-dir", str(tmp_path / "no-manager"), "--map", str(tmp_path / "map.json")])
    assert code == 2
    assert expected in capsys.readouterr().err
    assert not data.exists()


def test_a_manager_url_needs_its_token_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "jobs.tl").write_text(JOBS, encoding="utf-8")
    (tmp_path / "map.json").write_text(MAP, encoding="utf-8")
    code = main(["--plant", str(EXAMPLE), "--lotlan", str(tmp_path / "jobs.tl"), "--data-dir", str(tmp_path / "d"),
                 "--manager-url", "http://127.0.0.1:9", "--map", str(tmp_path / "map.json")])
    assert code == 2 and "--manager-url needs --manager-token-file" in capsys.readouterr().err
