"""Every kind of unusable input gets one clear message, exit code 2, and no traceback."""

from __future__ import annotations

from pathlib import Path

import pytest

PK = "@prefix pk: <https://w3id.org/plantkg/ontology#> .\n@prefix : <urn:test#> .\n"


def _assert_clean_error(run, *fragments: str) -> None:
    assert run.code == 2, (run.code, run.out, run.err)
    assert "Traceback" not in run.err
    assert run.err.startswith("error: ")
    for fragment in fragments:
        assert fragment in run.err, (fragment, run.err)


@pytest.mark.parametrize("command", [["validate"], ["query"]])
def test_missing_file(plantkg, tmp_path: Path, command: list[str]) -> None:
    missing = tmp_path / "nope.ttl"
    extra = ["SELECT * {}"] if command == ["query"] else []
    _assert_clean_error(plantkg(*command, missing, *extra), f"{missing}: no such file")


def test_directory(plantkg, tmp_path: Path) -> None:
    _assert_clean_error(plantkg("validate", tmp_path), f"{tmp_path}: is a directory", "*.ttl")


def test_binary_file(plantkg, write) -> None:
    path = write("plant.ttl", b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR")
    _assert_clean_error(plantkg("validate", path), f"{path}: is a binary file")


def test_unknown_extension(plantkg, write) -> None:
    path = write("plant.txt", PK + ':r a pk:Resource .\n')
    _assert_clean_error(plantkg("validate", path), "unknown file extension '.txt'", ".ttl")


def test_malformed_turtle_names_line_and_column(plantkg, write) -> None:
    path = write("plant.ttl", PK + ':r a pk:Resource ;\n   pk:name "unterminated .\n')
    run = plantkg("validate", path)
    _assert_clean_error(run, f"{path}:4:", "syntax error", 'pk:name "unterminated .')


def test_undefined_prefix(plantkg, write) -> None:
    path = write("plant.ttl", PK + ':r a pk:Resource ;\n    ex:colour "red" .\n')
    _assert_clean_error(plantkg("validate", path), f"{path}:4:5: syntax error", "ex:", "not been declared")


def test_invalid_utf8(plantkg, write) -> None:
    path = write("plant.ttl", PK.encode() + b':r pk:name "caf\xe9" .\n')
    _assert_clean_error(plantkg("validate", path), f"{path}:3:", "UTF-8")


def test_empty_plant(plantkg, write) -> None:
    path = write("plant.ttl", "# nothing here yet\n")
    _assert_clean_error(plantkg("validate", path), f"{path}: holds no triples")


def test_only_prefixes_is_empty(plantkg, write) -> None:
    path = write("plant.ttl", PK)
    _assert_clean_error(plantkg("validate", path), "holds no triples")


def test_plant_that_uses_nothing_of_the_ontology(plantkg, write) -> None:
    path = write("plant.ttl", "@prefix ex: <http://example.org/> .\nex:robot ex:sendsTo ex:broker .\n")
    _assert_clean_error(plantkg("validate", path), "uses no term of the plantkg ontology",
                        "@prefix pk: <https://w3id.org/plantkg/ontology#>")


def test_syntax_error_in_second_file_loads_nothing(plantkg, write) -> None:
    good = write("a.ttl", PK + ':r a pk:Resource ; pk:id "r" ; pk:name "R" .\n')
    bad = write("b.ttl", PK + ":r pk:name .\n")
    run = plantkg("validate", good, bad)
    _assert_clean_error(run, f"{bad}:3:")
    assert str(good) not in run.err


def test_malformed_query(plantkg) -> None:
    plant = Path(__file__).resolve().parents[2] / "ontology" / "examples" / "robot-cell.ttl"
    run = plantkg("query", plant, "SELECT ?x WHERE { ?x ?y }")
    _assert_clean_error(run, "malformed SPARQL query at line 1, column", "SELECT ?x WHERE { ?x ?y }")


def test_update_is_refused(plantkg) -> None:
    plant = Path(__file__).resolve().parents[2] / "ontology" / "examples" / "robot-cell.ttl"
    run = plantkg("query", plant, "INSERT DATA { pk:a pk:b pk:c }")
    _assert_clean_error(run, "SPARQL updates are not allowed")


def test_missing_query_file(plantkg, tmp_path: Path) -> None:
    plant = Path(__file__).resolve().parents[2] / "ontology" / "examples" / "robot-cell.ttl"
    run = plantkg("query", plant, "--file", tmp_path / "q.rq")
    _assert_clean_error(run, "q.rq: no such query file")


def test_bad_binding(plantkg) -> None:
    plant = Path(__file__).resolve().parents[2] / "ontology" / "examples" / "robot-cell.ttl"
    run = plantkg("query", plant, "--bind", "no-equals", "SELECT * {}")
    _assert_clean_error(run, "binding 'no-equals' is not NAME=VALUE")


def test_usage_error_exit_code(plantkg) -> None:
    run = plantkg("validate")
    assert run.code == 2
    assert "Missing argument" in run.err
