"""``python -m fleet.hmi`` / ``plantkg fleet hmi``: unusable input exits 2 with the reason (nothing
served); a started HMI serves its login page on loopback (also while another client stalls mid-request) and
stops on SIGTERM with exit 0."""

from __future__ import annotations

import re
import socket
import sys
import urllib.request
from pathlib import Path

import pytest

from engine import process
from fleet.hmi.__main__ import main
from tests.unit.fleet.planner_data import JOBS

ROOT = Path(__file__).resolve().parents[3]
MAP = '{"mapId": "hall-t", "width": 12, "height": 8, "stations": [{"name": "load-1", "x": 2, "y": 6}, ' \
      '{"name": "unload-1", "x": 10, "y": 6}, {"name": "load-2", "x": 2, "y": 2}, {"name": "unload-2", "x": 10, "y": 2}]}'


def argv(tmp: Path, *extra: str, text: str = JOBS, site: str = MAP, token: str = "t" * 24) -> list[str]:
    (tmp / "jobs.tl").write_text(text, encoding="utf-8")
    (tmp / "map.json").write_text(site, encoding="utf-8")
    (tmp / "token").write_text(token + "\n", encoding="utf-8")
    return ["--lotlan", str(tmp / "jobs.tl"), "--map", str(tmp / "map.json"), "--manager-data-dir", str(tmp / "m"),
            "--planner-data-dir", str(tmp / "p"), "--token-file", str(tmp / "token"), *extra]


CASES = [  # (id, extra arguments, argv keywords, expected in stderr)
    ("a host that is not loopback", ["--host", "0.0.0.0"], {}, "--host 0.0.0.0 is not loopback"),
    ("a host that is no address", ["--host", "plant.example"], {}, "--host 'plant.example' is no IP address"),
    ("bad LoTLan", [], {"text": JOBS.replace("    Transport\n    From atLoad", "    Transprt\n    From atLoad")},
     "jobs.tl:50:5: unexpected 'Transprt'"),
    ("a map that is not JSON", [], {"site": "{"}, "not JSON"),
    ("a location not on the map", [], {"site": MAP.replace('"unload-2"', '"elsewhere"')},
     "jobs.tl:16: Location otherUnload (name 'unload-2') is no station of map 'hall-t'"),
    ("a short token", [], {"token": "short"}, "the token is 5 characters, at least 16"),
    ("a port in use", ["--port", "PORT_IN_USE"], {}, "error:"),
]


@pytest.mark.parametrize(("extra", "kw", "expected"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_unusable_input_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str],
                                kw: dict[str, str], expected: str) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        extra = [str(taken.getsockname()[1]) if e == "PORT_IN_USE" else e for e in extra]
        assert main(argv(tmp_path, *extra, **kw)) == 2
    assert expected in capsys.readouterr().err


def test_a_planner_url_needs_its_token_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = argv(tmp_path)
    at = args.index("--planner-data-dir")
    args[at:at + 2] = ["--planner-url", "http://127.0.0.1:9"]
    assert main(args) == 2 and "--planner-url needs --planner-token-file" in capsys.readouterr().err


def test_a_missing_token_file_is_created_0600(tmp_path: Path) -> None:
    from fleet.hmi.auth import load_or_create_token

    token, created = load_or_create_token(tmp_path / "state" / "web-token")
    assert created and len(token) >= 16 and (tmp_path / "state" / "web-token").stat().st_mode & 0o777 == 0o600
    assert load_or_create_token(tmp_path / "state" / "web-token") == (token, False)


def test_plantkg_fleet_hmi_serves_on_loopback_and_stops_on_sigterm(tmp_path: Path) -> None:
    plantkg = Path(sys.executable).with_name("plantkg")  # the console script of this venv
    child = process.spawn([plantkg, "fleet", "hmi", *argv(tmp_path)], log_dir=tmp_path / "logs", name="hmi", cwd=ROOT)
    try:
        url = process.wait_until(lambda: (m := re.search(r"fleet HMI listening on (http://127\.0\.0\.1:\d+)",
                                                         child.log_tail())) and m.group(1), 30.0, 0.05,
                                 what="the HMI's address", child=child)
        host, port = url.removeprefix("http://").split(":")
        with socket.create_connection((host, int(port)), timeout=5) as slow:  # half a request, then nothing
            slow.sendall(b"GET /login HTTP/1.1\r\nHost: x\r\n")
            with urllib.request.urlopen(url + "/login", timeout=5) as reply:  # another client is served
                assert reply.status == 200 and b'name="token"' in reply.read()
    finally:
        assert process.stop(child, grace=10.0) == 0, child.log_tail()
