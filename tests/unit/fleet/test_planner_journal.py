"""The planner's journal: replay gives every task's last state; a torn last line is dropped and
cut off; a damaged line elsewhere is refused; one planner per data directory."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

import fleet.lotlan
from fleet.planner import build
from fleet.planner.errors import JournalError
from fleet.planner.journal import Journal, replay
from fleet.planner.states import TaskState
from tests.unit.fleet.planner_data import JOBS, SITE


def task():
    return build.build_task("j1-first-1", "j1", fleet.lotlan.parse(JOBS, "jobs.tl").task("first"), 1, SITE)


def test_replay_gives_the_last_state_of_each_task_the_events_and_jobs(tmp_path: Path) -> None:
    journal = Journal(tmp_path)
    t = task()
    journal.append("job", job="j1", tasks=["first"], at="t0")
    journal.task(t, "created")
    journal.append("event", event="loaded", value=True, number=1, at="t1")
    journal.task(replace(t, state=TaskState.ACTIVE), "RAW -> ACTIVE")
    journal.close()
    again = replay(tmp_path / "journal.jsonl")
    assert again.tasks == {t.id: replace(t, state=TaskState.ACTIVE)}
    assert again.jobs == {"j1": ["first"]} and [e["event"] for e in again.events] == ["loaded"]
    assert again.seq == 4 and not again.torn


def test_a_torn_last_line_is_dropped_and_cut_off_before_the_next_append(tmp_path: Path) -> None:
    journal = Journal(tmp_path)
    journal.task(task(), "created")
    journal.close()
    with open(tmp_path / "journal.jsonl", "ab") as f:
        f.write(b'{"seq":2,"kind":"task","task":{"id":"j1-fi')  # kill -9 mid-write
    journal = Journal(tmp_path)
    assert journal.state.torn and list(journal.state.tasks) == ["j1-first-1"]
    journal.append("event", event="loaded", value=True, number=1, at="t")
    journal.close()
    lines = (tmp_path / "journal.jsonl").read_text().splitlines()
    assert len(lines) == 2 and '"seq":2' in lines[1] and '"event"' in lines[1]
    assert not replay(tmp_path / "journal.jsonl").torn


def test_a_damaged_line_in_the_middle_is_refused_naming_it(tmp_path: Path) -> None:
    (tmp_path / "journal.jsonl").write_text('{"seq":1,"kind":"job","job":"j1","tasks":[]}\nnot json\n'
                                           '{"seq":3,"kind":"job","job":"j2","tasks":[]}\n')
    with pytest.raises(JournalError, match="line 2 is not a journal record"):
        replay(tmp_path / "journal.jsonl")


def test_one_planner_per_data_directory(tmp_path: Path) -> None:
    first = Journal(tmp_path)
    with pytest.raises(JournalError, match="used by another planner"):
        Journal(tmp_path)
    first.close()
    Journal(tmp_path).close()
