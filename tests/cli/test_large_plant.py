"""A 50 MB plant is validated like any other: one clear outcome, not a crash or a hang."""

from __future__ import annotations

import click

from benchmarks import synthetic


def test_fifty_megabyte_plant(plantkg, tmp_path) -> None:
    path = tmp_path / "big.ttl"
    with path.open("w") as fh:
        synthetic.write(150_000, fh)
    size = path.stat().st_size
    assert size > 50 * 1024 * 1024
    run = plantkg("validate", path)
    assert run.code == 0, run.out[-2000:] + run.err[-2000:]
    assert click.unstyle(run.out).startswith(f"valid: {path}")
    # the same plant with one defect: exactly that defect is reported
    broken = tmp_path / "broken.ttl"
    with path.open() as src, broken.open("w") as dst:
        for line in src:
            dst.write(line.replace('pk:port 9092 .', 'pk:port 0 .', 1) if ':broker1 ' in line else line)
    run = plantkg("validate", "--format", "json", broken)
    assert run.code == 1
    assert '"violations": 1' in run.out and '"value": "0"' in run.out
