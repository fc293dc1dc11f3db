"""Command line and link settings of the simulator: bad values refused by name; periodic schedule."""

from __future__ import annotations

import pytest

from fleet.sim import cli
from fleet.sim.vda5050_adapter import LinkConfig, Vda5050Link, _next_due


@pytest.mark.parametrize(
    ("argv", "fragment"),
    [
        (["--count", "51"], "--count 51: map 'hall-1' has only 50 parking spots"),
        (["--serial-prefix", "a#"], "'#' at position 1"),
        (["--manufacturer", "a/b"], "manufacturer 'a/b'"),
        (["--state-interval", "31"], "at most 30.0 s"),
        (["--map", "/nonexistent/map.json"], "cannot read the map"),
    ],
)
def test_unusable_arguments_exit_2_naming_the_value(argv: list[str], fragment: str, capsys) -> None:
    assert cli.main(argv) == 2
    assert fragment in capsys.readouterr().err


@pytest.mark.parametrize("argv", [["--broker", "host"], ["--broker", "h:0"], ["--rate", "0"], ["--count", "x"]])
def test_argparse_refuses(argv: list[str], capsys) -> None:
    with pytest.raises(SystemExit) as caught:
        cli.main(argv)
    assert caught.value.code == 2 and argv[0] in capsys.readouterr().err


def test_build_names_and_places_vehicles() -> None:
    runner = cli.build(cli.parser().parse_args(["--count", "3", "--serial-prefix", "x.", "--broker", "[::1]:1884"]))
    links = runner.links
    assert [link.vehicle.spec.serial for link in links] == ["x.0001", "x.0002", "x.0003"]
    assert len({(link.vehicle.motion.pose.x, link.vehicle.motion.pose.y) for link in links}) == 3
    assert isinstance(links[0], Vda5050Link) and (links[0].config.host, links[0].config.port) == ("::1", 1884)


def test_each_vehicle_logs_in_as_its_own_user_with_the_password_its_reference_points_to(tmp_path) -> None:
    for serial, password in (("x.0001", "pw-one"), ("x.0002", "pw-two")):
        (tmp_path / serial).write_text(password + "\n", encoding="utf-8")
    for interface in ("vda5050", "paper"):
        runner = cli.build(cli.parser().parse_args(
            ["--count", "2", "--serial-prefix", "x.", "--interface", interface,
             "--username", "agv-{serial}", "--secret-ref", f"file:{tmp_path}/{{serial}}"]))
        assert [(link.config.username, link.config.password) for link in runner.links] == [
            ("agv-x.0001", "pw-one"), ("agv-x.0002", "pw-two")]


@pytest.mark.parametrize(("argv", "fragment"), [
    (["--username", "agv-{serial}"], "--username and --secret-ref go together"),
    (["--username", "u", "--secret-ref", "env:PLANTKG_TEST_UNSET_VEHICLE_PASSWORD"],
     "PLANTKG_TEST_UNSET_VEHICLE_PASSWORD is not set"),
    (["--username", "u", "--secret-ref", "hunter2"], "--secret-ref"),
])
def test_a_login_without_a_usable_secret_exits_2_naming_the_option(argv: list[str], fragment: str, capsys) -> None:
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert fragment in err and "hunter2" not in err


def test_periodic_schedule_keeps_its_grid_and_never_bursts() -> None:
    assert _next_due(1.0, 1.04, 0.1, False) == pytest.approx(1.1)  # on the grid despite jitter
    assert _next_due(1.0, 1.5, 0.1, False) == pytest.approx(1.6)  # far behind: restart, no burst
    assert _next_due(1.0, 1.04, 0.1, True) == pytest.approx(1.14)  # after an event-driven state


def test_link_config_refuses_a_state_interval_beyond_the_standard() -> None:
    with pytest.raises(ValueError, match="at most 30"):
        LinkConfig(state_interval=45)
    with pytest.raises(ValueError, match="visualization_interval"):
        LinkConfig(visualization_interval=0)
