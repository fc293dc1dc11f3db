"""``plantkg demo [FILE...]``: the robot cell of the first paper, end to end on this machine."""

from __future__ import annotations

from pathlib import Path

import click


@click.command("demo")
@click.argument("files", nargs=-1, type=click.Path(exists=True, dir_okay=False))
@click.option("--duration", type=click.FloatRange(min=1), default=None,
              help="seconds of data before tearing down (default: until Ctrl-C)")
@click.option("--work-dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="where agents keep their state (default: a new temporary folder)")
def demo_command(files: tuple[str, ...], duration: float | None, work_dir: Path | None) -> int:
    """Start local agents, apply the plant, feed it simulated data, then destroy it all.

    Without FILE, the first paper's robot cell (ontology/examples/robot-cell.ttl); the second
    paper's AGV middleware, with its context broker: ontology/examples/agv-middleware.ttl.
    """
    from engine.cli import main  # the same commands a person would type, run in-process
    from engine.demo.run import run_demo
    from kg import resources

    plant = list(files) or [str(resources.examples_dir() / "robot-cell.ttl")]
    return run_demo(plant, main, duration=duration, work_dir=work_dir)
