"""The paper's task state machine (its Fig. 5) as a pure bookkeeper: which items to accept, in what
order the vehicle runs them, and what counts as a finished task.

A task (``task_id``) is a run of motion items followed by a run of action items, each item with a
``sequence`` higher than the one before in that task. A wait action ends the task. Hence, per
received item, in this order:

1. an item id seen before is a duplicate (a notification delivered twice): ignored, not an error;
2. an item of a task that already ended (with a wait action) is refused;
3. an item of another task while one is still open (no wait action yet) is refused: tasks run one
   after the other, and only a wait action ends one;
4. a motion after an action of the same task is refused (the paper: "in a task there cannot be an
   action followed by a movement ... the task must be split in smaller sub-tasks");
5. a sequence not higher than the task's last accepted one is refused (items are run in sequence
   order; we do not reorder, we refuse);
6. more than ``max_pending`` items waiting is refused (a flood cannot grow the queue without end).

Accepted items become :class:`Step` s run one at a time, in arrival order. The vehicle side calls
:meth:`TaskBook.start_next` and :meth:`TaskBook.finish` ; the book keeps ``last_finished_sequence``
and ``finished_task_id`` (set when the task's wait action has finished) for the status channel.
"""

from __future__ import annotations

from collections import OrderedDict, deque
from dataclasses import dataclass

from fleet.paper.messages import ActionItem, ActionKind, MotionItem

MAX_REMEMBERED = 10_000  # item and ended-task ids kept for duplicate detection


@dataclass(frozen=True)
class Step:
    item: MotionItem | ActionItem

    @property
    def task_id(self) -> str:
        return self.item.task_id

    @property
    def item_id(self) -> str:
        return self.item.motion_id if isinstance(self.item, MotionItem) else self.item.action_id

    @property
    def is_motion(self) -> bool:
        return isinstance(self.item, MotionItem)

    @property
    def ends_task(self) -> bool:
        return isinstance(self.item, ActionItem) and self.item.action is ActionKind.WAIT


@dataclass(frozen=True)
class Verdict:
    accepted: bool
    duplicate: bool = False
    reason: str = ""


ACCEPTED = Verdict(True)
DUPLICATE = Verdict(False, duplicate=True)


def _remember(store: OrderedDict[str, None], key: str) -> None:
    store[key] = None
    while len(store) > MAX_REMEMBERED:
        store.popitem(last=False)


class TaskBook:
    def __init__(self, max_pending: int = 200) -> None:
        self.max_pending = max_pending
        self.open_task: str | None = None
        self._phase_actions = False  # the open task has had an action
        self._last_sequence = -1  # of the open task
        self._seen: OrderedDict[str, None] = OrderedDict()
        self._ended: OrderedDict[str, None] = OrderedDict()
        self.pending: deque[Step] = deque()
        self.current: Step | None = None
        self.last_finished_sequence = -1
        self.finished_task_id = ""

    # ------------------------------------------------------------------ receiving
    def offer(self, item: MotionItem | ActionItem) -> Verdict:
        step = Step(item)
        if step.item_id in self._seen:
            return DUPLICATE
        task = item.task_id
        if task in self._ended:
            return Verdict(False, reason=f"task {task} has already ended with a wait action; send a new task id")
        if self.open_task is not None and task != self.open_task:
            return Verdict(False, reason=f"task {self.open_task} is still open: end it with a wait action "
                                         f"before starting task {task}")
        same = self.open_task == task
        if step.is_motion and same and self._phase_actions:
            return Verdict(False, reason=f"a motion after an action in task {task}: a task is its motions, then "
                                         "its actions (Fig. 5 of the paper); split it into two tasks")
        if same and item.sequence <= self._last_sequence:
            return Verdict(False, reason=f"sequence {item.sequence} is not after {self._last_sequence}, the last "
                                         f"accepted item of task {task}; items run in sequence order")
        if len(self.pending) >= self.max_pending:
            return Verdict(False, reason=f"{len(self.pending)} items are already waiting (at most {self.max_pending}); "
                                         "send more when the vehicle has caught up")
        _remember(self._seen, step.item_id)
        if not same:
            self.open_task, self._phase_actions = task, False
        self._last_sequence = item.sequence
        if not step.is_motion:
            self._phase_actions = True
        if step.ends_task:
            _remember(self._ended, task)
            self.open_task = None
        self.pending.append(step)
        return ACCEPTED

    # ------------------------------------------------------------------ executing
    def start_next(self) -> Step | None:
        """The next step to run, once the current one has finished (None: nothing to start)."""
        if self.current is None and self.pending:
            self.current = self.pending.popleft()
            return self.current
        return None

    def finish(self, ok: bool) -> Step:
        """The current step has ended (``ok``: it succeeded); returns it."""
        step = self.current
        assert step is not None, "finish() without a current step"
        self.current = None
        if ok:
            self.last_finished_sequence = step.item.sequence
        if step.ends_task:
            self.finished_task_id = step.task_id
        return step
