"""What plan, apply, destroy and status share: the --agents option, running the pipeline,
printing an invalid plant's violations, asking for confirmation."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import click

from engine.agents_config import AgentDirectory
from engine.cli.console import TERMINAL, Console
from engine.cli.options import agents_option, owner_option, prune_option, yes_option
from engine.errors import EngineError
from kg.errors import EXIT_VIOLATIONS

if TYPE_CHECKING:
    from contextlib import AbstractContextManager

    from engine.incremental.warm import WarmPipeline
    from engine.pipeline import Pipeline

# The pipeline, apply and the renderers are imported in the functions that use them: `plan` needs
# neither apply nor its progress display. The options live in engine.cli.options (kept here too).
__all__ = ["agents_option", "owner_option", "prune_option", "yes_option", "prepare", "make_changes",
           "print_violations", "load_directory", "confirm", "ConfirmationRequiredError"]


class ConfirmationRequiredError(EngineError):
    """Changes would be made, nobody can be asked, and --yes was not given."""


def load_directory(agents_file: Path | None, console: Console = TERMINAL) -> AgentDirectory:
    """The agents file, its warnings printed to stderr."""
    directory = AgentDirectory.load(agents_file)
    _warn(directory.warnings, console)
    return directory


def _warn(warnings: list[str], console: Console = TERMINAL) -> None:
    for warning in warnings:
        console.echo(click.style("warning: ", fg="yellow", bold=True) + warning, err=True)


def prepare(files: tuple[str, ...], agents_file: Path | None, *, destroy: bool = False,
            observe: bool = True, owner: str | None = None, prune: bool = False,
            pipeline: WarmPipeline | None = None,
            console: Console = TERMINAL) -> tuple[Pipeline, AgentDirectory | None]:
    """Run the pipeline (cold, or ``pipeline``: a long-running process's warm one); the directory
    is None when ``observe`` is False."""
    directory = load_directory(agents_file, console) if observe else None
    seen = len(directory.warnings) if directory else 0
    if pipeline is not None:
        result = pipeline(files, directory, destroy=destroy, observe=observe, owner=owner, prune=prune)
    else:
        from engine.incremental.desired_cache import DesiredCache  # noqa: PLC0415
        from engine.pipeline import run_pipeline  # noqa: PLC0415

        result = run_pipeline(files, directory, destroy=destroy, observe=observe, cache=DesiredCache(),
                              owner=owner, prune=prune)
    if directory is not None:
        _warn(directory.warnings[seen:], console)  # token files read while observing
    return result, directory


def print_violations(result: Pipeline, fmt: str = "text", console: Console = TERMINAL) -> None:
    """An invalid plant's report (stdout, as ``plantkg validate`` prints it) and a note (stderr)."""
    from kg.render import validation_json, validation_text  # noqa: PLC0415

    if fmt == "json":
        console.echo(validation_json(result.report))
    else:
        console.echo(validation_text(result.report, result.plant.prefixes if result.plant else {}))
    console.echo(click.style("error: ", fg="red", bold=True)
                 + "the plant has violations; nothing was planned, started or stopped", err=True)


def confirm(question: str, *, yes: bool, what: str, ask: bool = True, console: Console = TERMINAL) -> None:
    """Go on if ``--yes``; else ask on a terminal (only 'yes' goes on); else refuse.
    ``ask`` False (JSON output): never ask, refuse without ``--yes``."""
    if yes:
        return
    if not ask:
        raise ConfirmationRequiredError(
            f"refusing to {what} without confirmation: --format json never asks",
            hint=f"pass --yes to {what} with --format json")
    if not console.interactive:
        raise ConfirmationRequiredError(
            f"refusing to {what} without confirmation: standard input is not a terminal",
            hint=f"run it in a terminal, or pass --yes to {what} without asking")
    answer = console.prompt(f"\n{question}\n  Only 'yes' will be accepted.")
    if answer.strip() != "yes":
        console.echo("Cancelled: nothing was changed.")
        raise click.Abort()


EXIT_NOT_CONVERGED = 3  # some changes failed or did not take effect: run again once fixed


def make_changes(files: tuple[str, ...], agents_file: Path | None, *, yes: bool, parallelism: int,
                 destroy: bool, owner: str | None = None, prune: bool = False, fmt: str = "text",
                 console: Console = TERMINAL, pipeline: WarmPipeline | None = None,
                 apply_lock: AbstractContextManager[object] | None = None) -> int:
    """What ``apply`` and ``destroy`` share: validate, plan, show, confirm, dispatch, report.

    ``fmt`` "json": no plan text, no progress, no prompt (changes need ``--yes``), and one JSON
    document on stdout at the end (:mod:`engine.render.result`; the violations report for an
    invalid plant, the plan for one that cannot be applied).

    ``console``, ``pipeline`` and ``apply_lock`` are a long-running process's (``plantkg serve``
    running the command for its user, engine.control.server): where the output goes, its warm
    pipeline, and the lock its other applies hold.

    Exit codes: 0 converged, 1 violations (nothing dispatched), 3 some changes failed or did not
    take effect; a plan that cannot be applied raises PlanNotApplicableError (exit 2).
    """
    from contextlib import nullcontext  # noqa: PLC0415

    from engine.apply import PlanNotApplicableError, apply  # noqa: PLC0415
    from engine.cli.progress import result_lines  # noqa: PLC0415
    from engine.render.plan import render_plan  # noqa: PLC0415

    from engine.render import result as render_result  # noqa: PLC0415

    verb = "destroy" if destroy else "apply"
    as_json = fmt == "json"
    held = apply_lock if apply_lock is not None else nullcontext()
    result, directory = prepare(files, agents_file, destroy=destroy, owner=owner, prune=prune,
                                pipeline=pipeline, console=console)
    if not result.valid:
        print_violations(result, fmt="json" if as_json else "text", console=console)
        return EXIT_VIOLATIONS
    plan, desired = result.plan, result.desired
    assert plan is not None and desired is not None and directory is not None
    if as_json and (plan.empty or not plan.applicable):
        if not plan.applicable:
            from engine.render.plan import plan_json  # noqa: PLC0415

            console.echo(plan_json(plan))
            raise PlanNotApplicableError(plan)
        console.echo(render_result.to_json(render_result.nothing_done_dict(plan, verb=verb)))
        return 0
    if destroy and plan.empty and plan.applicable:
        console.echo("Nothing to destroy: no broker of this plant runs.")
        return 0
    if not as_json:
        console.echo(render_plan(plan, color=True))
    if not plan.applicable:
        raise PlanNotApplicableError(plan)
    if plan.empty:
        return 0
    if as_json:
        confirm("", yes=yes, what=verb, ask=False, console=console)
        with held:
            outcome = apply(plan, desired, directory, parallelism=parallelism, destroy=destroy, prune=prune)
        console.echo(render_result.to_json(render_result.result_dict(outcome, verb=verb)))
        return 0 if outcome.ok else EXIT_NOT_CONVERGED
    if destroy:
        confirm("Do you really want to destroy these brokers? Their data is removed.", yes=yes,
                what="destroy", console=console)
    else:
        confirm("Do you want to perform these actions?", yes=yes, what="apply", console=console)
    console.echo("")
    with held, console.progress() as progress:
        outcome = apply(plan, desired, directory, parallelism=parallelism, on_event=progress,
                        destroy=destroy, prune=prune)
    console.echo("")
    for line in result_lines(outcome, verb="Destroy" if destroy else "Apply"):
        console.echo(line)
    return 0 if outcome.ok else EXIT_NOT_CONVERGED
