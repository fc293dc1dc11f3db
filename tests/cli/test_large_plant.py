"""A 50 MB plant is validated like any other: one clear outcome, not a crash or a hang."""

from __future__ import annotations

import json

from benchmarks import synthetic


def test_fifty_megabyte_plant_with_one_defect(plantkg, tmp_path) -> None:
    path = tmp_path / "big.ttl"
    with path.open("w") as fh:
        for chunk in synthetic.lines(150_000):
            if chunk.startswith(":broker1 a pk:Broker"):
                assert "pk:port 9092 ." in chunk
                chunk = chunk.replace("pk:port 9092 .", "pk:port 0 .")
            fh.write(chunk)
    assert path.stat().st_size > 50 * 1024 * 1024
    run = plantkg("validate", "--format", "json", path)
    assert run.code == 1, run.err[-2000:]
    report = json.loads(run.out)
    # everything else in the plant is valid: exactly the one defect is reported
    assert report["violations"] == 1
    (result,) = report["results"]
    assert result["focus"].endswith("#broker1")
    assert result["path"].endswith("#port") and result["value"] == "0"
    assert result["file"] == str(path)
