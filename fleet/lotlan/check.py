"""Semantic checks of a parsed LoTLan file, and the checked :class:`~fleet.lotlan.model.Program`.

Every check runs and every problem becomes a :class:`~fleet.lotlan.errors.Diagnostic` that names
the place and what to change; a program is built only when there are none. The checks are those
of the authors' implementation (lotlan-scheduler's SemanticValidator: instance attributes, step
locations, unknown tasks in OnDone, OnDone with Repeat, parameter counts, conditions that are not
booleans) plus stricter ones the task planner needs (a task must have a Transport and a step a
Location, From differs from To, Repeat is a positive count, no OnDone cycle that never ends,
names unknown to an expression are errors). docs/fleet-manager.md lists the differences.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass

from fleet.lotlan import cycles
from fleet.lotlan.errors import Diagnostic
from fleet.lotlan.expressions import ExprChecker
from fleet.lotlan.model import (
    Constraint,
    Event,
    Location,
    Pos,
    Program,
    StepUse,
    Task,
    Time,
    TransportOrderStep,
)
from fleet.lotlan.syntax import (
    Decl,
    InstanceDecl,
    Name,
    Parsed,
    Statement,
    StepDecl,
    StepRef,
    TaskDecl,
    TemplateDecl,
)

# The four primitives and their attributes, as lotlan-scheduler defines them (defines.py).
PRIMITIVES: dict[str, tuple[str, ...]] = {
    "Location": ("name", "type"),
    "Event": ("name", "type"),
    "Time": ("timing",),
    "Constraint": ("type",),
}
_ONCE_IN_STEP = ("Location", "TriggeredBy", "FinishedBy", "OnDone", "Parameters")
_ONCE_IN_TASK = ("Transport", "TriggeredBy", "FinishedBy", "OnDone", "Repeat", "Constraints")


@dataclass
class _Checker:
    file: str
    parsed: Parsed

    def __post_init__(self) -> None:
        self.found: list[Diagnostic] = []
        self.templates: dict[str, TemplateDecl] = {}
        self.instances: dict[str, InstanceDecl] = {}
        self.steps: dict[str, StepDecl] = {}
        self.tasks: dict[str, TaskDecl] = {}

    def error(self, at: Pos, message: str) -> None:
        self.found.append(Diagnostic(self.file, at.line, at.column, message))

    def broken(self, kind: str, name: str) -> bool:
        return (kind, name) in self.parsed.broken

    # ---- names ---------------------------------------------------------------------------------

    def register(self) -> None:
        tables = {TemplateDecl: (self.templates, "template"), InstanceDecl: (self.instances, "instance"),
                  StepDecl: (self.steps, "TransportOrderStep"), TaskDecl: (self.tasks, "task")}
        for decl in self.parsed.decls:
            table, word = tables[type(decl)]
            name = decl.name
            if name.text in table:
                first = table[name.text].name.at
                self.error(name.at, f"{word} '{name.text}' is defined twice (first at line {first.line}): "
                           "rename or remove one of them")
                continue
            table[name.text] = decl
            self._check_case(decl, word)

    def _check_case(self, decl: Decl, word: str) -> None:
        name = decl.name.text
        if isinstance(decl, TemplateDecl):
            if not name[0].isupper():
                self.error(decl.name.at, f"template names start with an uppercase letter: rename '{name}' "
                           f"to '{name[0].upper() + name[1:]}'")
        elif not name[0].islower():
            self.error(decl.name.at, f"{word} names start with a lowercase letter (as the LoTLan authors "
                       f"require): rename '{name}' to '{name[0].lower() + name[1:]}'")

    # ---- templates and instances ---------------------------------------------------------------

    def check_templates(self) -> None:
        for template in self.templates.values():
            names = self._members_once(template.members, f"template '{template.name.text}'")
            if not template.members:
                self.error(template.name.at, f"template '{template.name.text}' declares no attribute: "
                           'add at least one line like    name = ""')
            expected = PRIMITIVES.get(template.name.text)
            if expected is not None and set(names) != set(expected):
                self.error(template.name.at, f"template '{template.name.text}' redefines a LoTLan primitive "
                           f"with other attributes: it has {_words(expected)}; remove this template or "
                           "declare exactly those")

    def check_instances(self) -> dict[str, object]:
        """Check every instance; return the usable ones as model objects by name."""
        built: dict[str, object] = {}
        for instance in self.instances.values():
            template = instance.template.text
            label = f"{template} '{instance.name.text}'"
            names = self._members_once(instance.members, label)
            for member in instance.members:
                if not member.value.quoted:
                    self.error(member.value.at, f"value of '{member.name.text}' in {label} is not quoted: "
                               f'write {member.name.text} = "{member.value.value}"')
            if template not in PRIMITIVES:
                if template in self.templates or self.broken("template", template):
                    self.error(instance.template.at, f"{label}: instances of the user-defined template "
                               f"'{template}' cannot be used (lotlan-scheduler refuses them too): make it "
                               "a Location, Event, Time or Constraint")
                else:
                    self.error(instance.template.at, f"{label}: unknown template '{template}': "
                               f"use Location, Event, Time or Constraint{_suggest(template, PRIMITIVES)}")
                continue
            expected = PRIMITIVES[template]
            for member in instance.members:
                if member.name.text not in expected:
                    self.error(member.name.at, f"{label} has no attribute '{member.name.text}': "
                               f"a {template} has {_words(expected)}")
            missing = [a for a in expected if a not in names]
            if missing:
                self.error(instance.name.at, f"{label} lacks {_words(missing)}: add "
                           + ", ".join(f'{a} = "..."' for a in missing))
            values = {m.name.text: str(m.value.value) for m in instance.members}
            built[instance.name.text] = _instance(template, instance, values)
        return built

    def _members_once(self, members: tuple, label: str) -> list[str]:
        seen: list[str] = []
        for member in members:
            if member.name.text in seen:
                self.error(member.name.at, f"'{member.name.text}' is set twice in {label}: keep one")
            else:
                seen.append(member.name.text)
        return seen

    # ---- statements ----------------------------------------------------------------------------

    def statements_once(self, decl: StepDecl | TaskDecl, allowed: tuple[str, ...]) -> dict[str, Statement]:
        kind = "TransportOrderStep" if isinstance(decl, StepDecl) else "Task"
        table: dict[str, Statement] = {}
        for statement in decl.statements:
            if statement.keyword not in allowed:
                self.error(statement.at, f"{statement.keyword} cannot be used in a {kind}: a {kind} takes "
                           f"{_words(allowed)}")
            elif statement.keyword in table:
                self.error(statement.at, f"{statement.keyword} is given twice in {kind} '{decl.name.text}' "
                           f"(first at line {table[statement.keyword].at.line}): keep one")
            else:
                table[statement.keyword] = statement
        return table

    def check_on_done(self, statement: Statement | None) -> tuple[str, ...]:
        if statement is None:
            return ()
        names: tuple[Name, ...] = statement.value  # type: ignore[assignment]
        for name in names:
            if name.text not in self.tasks and not self.broken("task", name.text):
                self.error(name.at, f"OnDone names an unknown task '{name.text}': define Task "
                           f"{name.text} or correct the name{_suggest(name.text, self.tasks)}")
        return tuple(n.text for n in names)

    def check_location(self, step: StepDecl, statement: Statement | None,
                       instances: dict[str, object]) -> Location | None:
        if statement is None:
            self.error(step.name.at, f"TransportOrderStep '{step.name.text}' has no Location: add a line "
                       "    Location <name of a Location>")
            return None
        name: Name = statement.value  # type: ignore[assignment]
        found = instances.get(name.text)
        if isinstance(found, Location):
            return found
        if name.text in self.instances:
            self.error(name.at, f"'{name.text}' is {_a(self.instances[name.text].template.text)}, not a "
                       f"Location: name a Location in TransportOrderStep '{step.name.text}'")
        elif not self.broken("instance", name.text):
            self.error(name.at, f"unknown location '{name.text}' in TransportOrderStep '{step.name.text}': "
                       f"define Location {name.text} or correct the name"
                       f"{_suggest(name.text, self.instances)}")
        return None

    def check_repeat(self, task: TaskDecl, statement: Statement | None) -> int:
        if statement is None:
            return 1
        value: Name = statement.value  # type: ignore[assignment]
        text = value.text
        if text.isdigit() and int(text) > 0:
            return int(text)
        if text.isdigit():
            self.error(value.at, f"Repeat {text} in task '{task.name.text}': the LoTLan docs read 0 as "
                       "'forever', which this fleet manager does not run; give the number of runs (1 or more)")
        else:
            self.error(value.at, f"Repeat takes a positive whole number of runs (e.g. Repeat 3), "
                       f"not '{text}'")
        return 1


def check(parsed: Parsed, file: str) -> tuple[Program | None, tuple[Diagnostic, ...]]:
    """Check a parsed file; return the program (None if anything is wrong) and every problem."""
    checker = _Checker(file, parsed)
    checker.register()
    checker.check_templates()
    instances = checker.check_instances()
    exprs = ExprChecker(checker.error, checker.instances, instances, set(checker.tasks),
                        checker.parsed.broken)
    steps: dict[str, TransportOrderStep] = {}
    for decl in checker.steps.values():
        table = checker.statements_once(decl, _ONCE_IN_STEP)
        location = checker.check_location(decl, table.get("Location"), instances)
        triggered = exprs.condition(table.get("TriggeredBy"))
        finished = exprs.condition(table.get("FinishedBy"))
        on_done = checker.check_on_done(table.get("OnDone"))
        parameters = _parameters(checker, table.get("Parameters"))
        if location is not None:
            steps[decl.name.text] = TransportOrderStep(decl.name.text, location, triggered, finished,
                                                       on_done, parameters, decl.name.at)
    tasks: list[Task] = []
    for decl in checker.tasks.values():
        task = _task(checker, exprs, decl, steps)
        if task is not None:
            tasks.append(task)
    cycles.check_on_done_cycles(checker.error, tasks)
    cycles.check_waiting_cycles(checker.error, tasks)
    diagnostics = tuple(sorted(parsed.diagnostics + tuple(checker.found),
                               key=lambda d: (d.line, d.column, d.message)))
    if diagnostics:
        return None, diagnostics
    by_kind = {kind: tuple(v for v in instances.values() if isinstance(v, kind))
               for kind in (Location, Event, Time, Constraint)}
    program = Program(file, by_kind[Location], by_kind[Event], by_kind[Time], by_kind[Constraint],
                      tuple(steps.values()), tuple(tasks))
    return program, ()


def _task(checker: _Checker, exprs: ExprChecker, decl: TaskDecl,
          steps: dict[str, TransportOrderStep]) -> Task | None:
    table = checker.statements_once(decl, _ONCE_IN_TASK)
    triggered = exprs.condition(table.get("TriggeredBy"))
    finished = exprs.condition(table.get("FinishedBy"))
    constraints = exprs.constraints(table.get("Constraints"))
    on_done = checker.check_on_done(table.get("OnDone"))
    repeat = checker.check_repeat(decl, table.get("Repeat"))
    if "Repeat" in table and "OnDone" in table:
        checker.error(table["Repeat"].at, f"task '{decl.name.text}' has both OnDone and Repeat (the LoTLan "
                      "authors allow only one): remove one of them")
    transport = table.get("Transport")
    if transport is None:
        checker.error(decl.name.at, f"task '{decl.name.text}' has no Transport: add the three lines "
                      "    Transport /     From <step> /     To <step>")
        return None
    pickup_ref, delivery_ref = transport.value  # type: ignore[misc]
    pickup = _step_use(checker, pickup_ref, "From", steps)
    delivery = _step_use(checker, delivery_ref, "To", steps)
    if pickup_ref.name.text == delivery_ref.name.text:
        checker.error(delivery_ref.name.at, f"task '{decl.name.text}' transports From and To the same step "
                      f"'{pickup_ref.name.text}': name the step where the load is delivered in To")
        return None
    if pickup is None or delivery is None:
        return None
    return Task(decl.name.text, pickup, delivery, triggered, finished, on_done, repeat, constraints,
                decl.name.at)


def _step_use(checker: _Checker, ref: StepRef, keyword: str,
              steps: dict[str, TransportOrderStep]) -> StepUse | None:
    name = ref.name.text
    if name not in checker.steps:
        if not checker.broken("step", name):
            checker.error(ref.name.at, f"{keyword} names an unknown TransportOrderStep '{name}': define "
                          f"TransportOrderStep {name} or correct the name{_suggest(name, checker.steps)}")
        return None
    step = steps.get(name)
    if step is None:  # the step itself has errors, reported there
        return None
    if len(ref.arguments) != len(step.parameters):
        checker.error(ref.name.at, f"{keyword} {name} passes {len(ref.arguments)} value(s) but the step has "
                      f"{len(step.parameters)} Parameters ({', '.join(step.parameters) or 'none'}): "
                      "pass one value per parameter")
        return None
    return StepUse(step, tuple(v.value for v in ref.arguments), ref.name.at)


def _parameters(checker: _Checker, statement: Statement | None) -> tuple[str, ...]:
    if statement is None:
        return ()
    names: list[str] = []
    for name in statement.value:  # type: ignore[attr-defined]
        if name.text in names:
            checker.error(name.at, f"parameter '{name.text}' is listed twice: keep one")
        names.append(name.text)
    return tuple(names)


def _instance(template: str, decl: InstanceDecl, values: dict[str, str]) -> object:
    name, at = decl.name.text, decl.name.at
    if template == "Location":
        return Location(name, values.get("name", ""), values.get("type", ""), at)
    if template == "Event":
        return Event(name, values.get("name", ""), values.get("type", ""), at)
    if template == "Time":
        return Time(name, values.get("timing", ""), at)
    return Constraint(name, values.get("type", ""), at)


def _words(items) -> str:
    items = list(items)
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def _a(word: str) -> str:
    return ("an " if word[:1] in "AEIOU" else "a ") + word


def _suggest(name: str, known) -> str:
    """A hint naming the closest known name, if one is close (same letters in another case, a typo)."""
    known = list(known)
    close = [k for k in known if k.lower() == name.lower()] or difflib.get_close_matches(name, known, 1, 0.8)
    return f" (did you mean '{close[0]}'?)" if close else ""

