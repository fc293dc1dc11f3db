"""What ``plantkg serve`` runs for a command on its control socket: ``apply`` or ``destroy`` of its
own plant.

The same code as the command's own (``engine.cli.reconcile.make_changes``), with three things of
the server's: its warm pipeline (engine.incremental.warm, one session for the server's life: a
command after an edit re-validates and re-reasons what the edit reaches), the lock every apply of
the server holds (the dashboard's, the reconcile loop's), and the command's terminal at the other
end of the socket. Once the command has its exit code, the server asks its agents again (in a
thread of its own: the command does not wait for it), so the dashboard shows the change.
"""

from __future__ import annotations

import logging
import threading
from contextlib import AbstractContextManager
from pathlib import Path
from typing import Any, Protocol

from engine.cli.console import Console
from engine.control.request import Request
from engine.control.server import Handler
from engine.incremental.warm import WarmPipeline
from engine.reconcile_loop import plant_files

log = logging.getLogger(__name__)


class ServedPlant(Protocol):
    """What a command needs of the server's plant (engine.web.plant_state.PlantState has it)."""

    @property
    def paths(self) -> tuple[str, ...]: ...

    @property
    def apply_lock(self) -> AbstractContextManager[Any]: ...

    def refresh(self) -> object: ...


def plant_commands(state: ServedPlant, agents_file: Path | None, owner: str | None) -> Handler:
    """The handler of ``state``'s plant: files, agents file and owner are the server's. The warm
    pipeline starts at once, in a thread of its own (a command that comes first waits for it)."""
    warm = WarmPipeline()

    def start_warm() -> None:  # the session's cold start now, not in the first command
        try:
            warm(tuple(str(p) for p in plant_files(state.paths)), None, observe=False, owner=owner)
        except Exception:  # noqa: BLE001 - the first command starts it again and reports the error
            log.info("control socket: the warm pipeline could not start yet", exc_info=True)

    threading.Thread(target=start_warm, name="plantkg-control-warm", daemon=True).start()

    def handle(request: Request, console: Console) -> int:
        from engine.cli.reconcile import make_changes  # noqa: PLC0415 - imports the CLI's renderers

        files = tuple(str(p) for p in plant_files(state.paths))
        try:
            return make_changes(files, agents_file, yes=request.yes, parallelism=request.parallelism,
                                destroy=request.verb == "destroy", owner=owner, prune=request.prune,
                                fmt=request.fmt, console=console, pipeline=warm, apply_lock=state.apply_lock)
        finally:
            threading.Thread(target=state.refresh, name="plantkg-control-refresh", daemon=True).start()

    return handle
