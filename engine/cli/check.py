"""``plantkg check FILE...``: does data really flow from each resource to every broker that must
carry it? (The first paper's last step, done by the machine; engine.check.)

Passive (default): taps subscribe at every broker the plant's flows cross and watch for up to
``--deadline`` seconds; a flow passes when its topic arrives at each of them. ``--probe``: one
marked message per flow is published at its source broker and must arrive at every broker of the
flow; one that arrives twice at a broker means two bridge paths deliver the same messages twice.

Exit codes: 0 every flow passed (flows at a context broker are listed as not checked); 1 a flow
failed (or had no traffic at all); 2 unusable input — a file, an invalid plant (its violations are
printed), an agent that did not answer, a broker that cannot be reached.
"""

from __future__ import annotations

from pathlib import Path

import click

from engine.cli.common import file_argument
from engine.cli.options import agents_option
from kg.errors import EXIT_UNUSABLE

EXIT_PASSED, EXIT_FAILED = 0, 1


@click.command("check")
@file_argument
@agents_option
@click.option("--deadline", type=click.FloatRange(min=0, min_open=True, max=3600), default=10.0,
              show_default=True, metavar="SECONDS",
              help="how long to wait for messages (before that, taps get as long, at least 10 s, to connect)")
@click.option("--probe", is_flag=True,
              help="publish one marked message per flow at its source and require it everywhere "
                   "(real consumers of the topic see it too)")
@click.option("--format", "fmt", type=click.Choice(["text", "json"]), default="text", show_default=True,
              help="text for people, json for programs")
def check_command(files: tuple[str, ...], agents_file: Path | None, deadline: float, probe: bool,
                  fmt: str) -> int:
    """Check that data from each publishing resource of the plant in FILE(s) arrives at every broker
    that must carry it, through every bridge, within the deadline.

    \b
    Example:
      plantkg check ontology/examples/robot-cell.ttl --agents agents.toml --probe
    """
    from engine.check.flows import derive_flows  # noqa: PLC0415 - only when run
    from engine.check.publications import publications  # noqa: PLC0415
    from engine.check.report import render_json, render_text  # noqa: PLC0415
    from engine.check.run import run_check  # noqa: PLC0415
    from engine.cli.reconcile import load_directory, print_violations  # noqa: PLC0415
    from engine.errors import EngineError  # noqa: PLC0415
    from engine.pipeline import run_pipeline  # noqa: PLC0415

    directory = load_directory(agents_file)
    result = run_pipeline(files, directory)  # no cache: the flows are read from the reasoned graph
    if not result.valid:
        print_violations(result, fmt)
        return EXIT_UNUSABLE
    desired, observed = result.desired, result.observed
    assert desired is not None and observed is not None and result.plant is not None
    silent = [host for host in observed.unreachable if host in result.hosts]  # others do not matter here
    if silent:
        raise EngineError("agents that did not answer: " + ", ".join(silent),
                          hint="start them, or check the agents file; `plantkg status` shows the plant")
    bridge_status = {}
    for bridge in desired.bridges:
        have = observed.bridge(bridge.address)
        bridge_status[bridge.address] = have.status.value if have else "absent: no agent runs it"
    flows = derive_flows(desired, publications(result.plant))
    check = run_check(flows, deadline=deadline, probe=probe, bridge_status=bridge_status)
    if fmt == "json":
        click.echo(render_json(check))
    else:
        click.echo(render_text(check, click.style) if flows else "no flows: no resource of the plant publishes")
    return EXIT_PASSED if check.passed else EXIT_FAILED
