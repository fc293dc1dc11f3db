"""Parse LoTLan text into declarations (names not yet resolved), collecting every syntax error.

The grammar is ``lotlan.lark`` (lark, LALR with a contextual lexer). A file that parses whole is
turned into one declaration per block. A file that does not is cut into blocks at every line that
starts in column 1 with a letter (a block header) and each block is parsed alone, so one broken
block does not hide the errors of the others, and the blocks that do parse still get their
semantic checks (``fleet.lotlan.check``), with the names of the broken blocks known so that
references to them are not reported as unknown. Lexical rules the grammar leaves out on purpose
(statement indentation) are checked here, with a message that says what to write instead.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass
from importlib import resources
from typing import Union

import lark
from lark import Token, Transformer, v_args

from fleet.lotlan.errors import Diagnostic
from fleet.lotlan.model import (
    And,
    Compare,
    Const,
    Expr,
    Literal,
    Not,
    Or,
    Pos,
    Ref,
    TaskAttribute,
)


@dataclass(frozen=True)
class Name:
    text: str
    at: Pos


@dataclass(frozen=True)
class Value:
    """A value as written: ``"s1_pickup"`` (quoted) or ``5`` (not quoted)."""

    value: Literal
    quoted: bool
    at: Pos


@dataclass(frozen=True)
class Member:
    name: Name
    value: Value


@dataclass(frozen=True)
class StepRef:
    name: Name
    arguments: tuple[Value, ...]


@dataclass(frozen=True)
class Statement:
    """One statement line of a step or task. ``keyword`` as written (``Location``, ``OnDone``...).

    ``value`` is a Name (Location), a tuple of Names (OnDone, Parameters), an Expr (TriggeredBy,
    FinishedBy, Constraints), the raw text of Repeat (a str), or (From, To) StepRefs (Transport).
    """

    keyword: str
    at: Pos
    value: object


@dataclass(frozen=True)
class TemplateDecl:
    name: Name
    members: tuple[Member, ...]
    at: Pos


@dataclass(frozen=True)
class InstanceDecl:
    template: Name
    name: Name
    members: tuple[Member, ...]
    at: Pos


@dataclass(frozen=True)
class StepDecl:
    name: Name
    statements: tuple[Statement, ...]
    at: Pos


@dataclass(frozen=True)
class TaskDecl:
    name: Name
    statements: tuple[Statement, ...]
    at: Pos


Decl = Union[TemplateDecl, InstanceDecl, StepDecl, TaskDecl]


@dataclass(frozen=True)
class Parsed:
    """The declarations that parsed, the syntax errors, and (kind, name) of the broken blocks."""

    decls: tuple[Decl, ...]
    diagnostics: tuple[Diagnostic, ...]
    broken: frozenset[tuple[str, str]]


@functools.lru_cache(maxsize=1)
def grammar_parser() -> lark.Lark:
    """The LALR parser of ``lotlan.lark`` (built once per process)."""
    text = resources.files("fleet.lotlan").joinpath("lotlan.lark").read_text(encoding="utf-8")
    return lark.Lark(text, parser="lalr", lexer="contextual", propagate_positions=True)


def parse_text(text: str, file: str) -> Parsed:
    """Parse a whole LoTLan file; never raises for bad input (problems become diagnostics)."""
    text = text.replace("\r\n", "\n")
    try:
        tree = grammar_parser().parse(text)
    except lark.exceptions.UnexpectedInput as whole_error:
        return _parse_blocks(text, file, whole_error)
    decls = tuple(_ToDecls().transform(tree).children)
    return Parsed(decls, _indentation(text, decls, file), frozenset())


# ---- recovery: block by block --------------------------------------------------------------------

_HEADER = re.compile(r"[A-Za-z]")
_END_LINE = re.compile(r"\s*end\b", re.IGNORECASE)  # "end" too: its error says to write End
_HEADER_WORDS = re.compile(r"(\w+)[ \t]+(\w+)")


def _parse_blocks(text: str, file: str, whole_error: lark.exceptions.UnexpectedInput) -> Parsed:
    lines = text.split("\n")
    starts = [i for i, line in enumerate(lines) if _HEADER.match(line) and not _END_LINE.match(line)]
    if not starts or starts[0] != 0:
        starts.insert(0, 0)
    decls: list[Decl] = []
    diagnostics: list[Diagnostic] = []
    broken: set[tuple[str, str]] = set()
    for first, stop in zip(starts, starts[1:] + [len(lines)]):
        segment = "\n" * first + "\n".join(lines[first:stop])
        try:
            tree = grammar_parser().parse(segment)
        except lark.exceptions.UnexpectedInput as error:
            diagnostics.append(_syntax_diagnostic(error, file, lines, first, stop))
            broken.add(_header_kind(lines[first]))
            continue
        decls.extend(_ToDecls().transform(tree).children)
    if not diagnostics:  # the blocks parse alone but not together: report the whole-file error
        diagnostics.append(_syntax_diagnostic(whole_error, file, lines, 0, len(lines)))
    decls_t = tuple(decls)
    return Parsed(decls_t, tuple(diagnostics) + _indentation(text, decls_t, file), frozenset(broken))


def _header_kind(line: str) -> tuple[str, str]:
    match = _HEADER_WORDS.match(line)
    if not match:
        return ("", "")
    first, second = match.groups()
    kind = {"Template": "template", "TransportOrderStep": "step", "Task": "task"}.get(first, "instance")
    return (kind, second)


# ---- syntax error messages -----------------------------------------------------------------------

_TERMINAL_WORDS = {
    "NAME": "a name",
    "_NL": "the end of the line",
    "STRING": 'a quoted value ("...")',
    "INT": "an integer",
    "FLOAT": "a decimal number",
    "COMPARISON": "a comparison (== != < <= > >=)",
    "REPEAT_VALUE": "a count",
    "$END": "the end of the file",
}
_KEYWORDS = ("Template", "TransportOrderStep", "Task", "Location", "OnDone", "Parameters", "Repeat",
             "Constraints", "Transport", "From", "To", "TriggeredBy", "FinishedBy", "End",
             "True", "False", "and", "or")


def _describe_terminal(name: str) -> str:
    if name in _TERMINAL_WORDS:
        return _TERMINAL_WORDS[name]
    try:
        pattern = grammar_parser().get_terminal(name).pattern
    except KeyError:
        return name
    return f"'{pattern.value}'" if pattern.type == "str" else name


def _describe_token(token: Token) -> str:
    if token.type == "_NL":
        return "end of line"
    if token.type == "$END":
        return "end of file"
    return repr(str(token))


def _syntax_diagnostic(error: lark.exceptions.UnexpectedInput, file: str, lines: list[str],
                       first: int, stop: int) -> Diagnostic:
    """Turn a lark error into a message that says what was found, what fits, and a hint."""
    if isinstance(error, lark.exceptions.UnexpectedCharacters):
        char = lines[error.line - 1][error.column - 1: error.column]
        return Diagnostic(file, error.line, error.column,
                          f"character {char!r} cannot be used here: names are letters, digits and _, "
                          'values are written in double quotes ("..."), comments start with #')
    token = getattr(error, "token", None)
    expected = sorted({_describe_terminal(e) for e in getattr(error, "expected", ()) or ()})
    wanted = _join(expected) if expected else "something else"
    if token is None or token.type == "$END":
        last = _last_line(lines, first, stop)
        message = f"unexpected end of file; expected {wanted}"
        if not any(_END_LINE.match(line) for line in lines[first:stop]):
            header = lines[first].split("#")[0].strip()
            message += f"; the block '{header}' (line {first + 1}) has no End: add End after it"
        return Diagnostic(file, last + 1, len(lines[last]) + 1, message)
    message = f"unexpected {_describe_token(token)}; expected {wanted}"
    word = str(token)
    fixed = [k for k in _KEYWORDS if k.lower() == word.lower() and k != word]
    if fixed:
        message += f"; keywords are case-sensitive: write '{fixed[0]}'"
    elif token.type != "_NL" and token.column == 1 and "'End'" in expected:
        message += "; the block before has no End: add End before this line"
    elif word.startswith('"'):
        message += "; close the quote on the same line"
    elif word == "not":
        message += "; negation is written '!'"
    elif word in ("&&", "||"):
        message += "; write 'and' / 'or'"
    return Diagnostic(file, token.line, token.column, message)


def _join(words: list[str]) -> str:
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " or " + words[-1]


def _last_line(lines: list[str], first: int, stop: int) -> int:
    for index in range(stop - 1, first - 1, -1):
        if lines[index].strip():
            return index
    return first


# ---- indentation -----------------------------------------------------------------------------------


def _indentation(text: str, decls: tuple[Decl, ...], file: str) -> tuple[Diagnostic, ...]:
    """Statements inside a block start after exactly four spaces or one tab (as the authors' lexer)."""
    lines = text.split("\n")
    found = []
    for decl in decls:
        firsts = [m.name.at for m in decl.members] if isinstance(decl, (TemplateDecl, InstanceDecl)) \
            else [s.at for s in decl.statements]
        for at in firsts:
            indent = lines[at.line - 1][: at.column - 1]
            if indent not in ("    ", "\t"):
                found.append(Diagnostic(
                    file, at.line, at.column,
                    f"statement indented by {_show_indent(indent)}: indent each statement inside a "
                    "block by exactly four spaces or one tab"))
    return tuple(found)


def _show_indent(indent: str) -> str:
    if not indent:
        return "nothing"
    spaces, tabs = indent.count(" "), indent.count("\t")
    parts = ([f"{spaces} space(s)"] if spaces else []) + ([f"{tabs} tab(s)"] if tabs else [])
    return " and ".join(parts)


# ---- tree to declarations ----------------------------------------------------------------------------


def _pos(token: Token) -> Pos:
    return Pos(token.line, token.column)


def _name(token: Token) -> Name:
    return Name(str(token), _pos(token))


def _value(token: Token) -> Value:
    text = str(token)
    if token.type == "STRING":
        return Value(text[1:-1], True, _pos(token))
    if token.type == "FLOAT":
        return Value(float(text), False, _pos(token))
    return Value(int(text), False, _pos(token))


class _ToDecls(Transformer):
    """lark tree -> declarations and expression trees (positions from the tokens)."""

    # blocks
    def template(self, children: list) -> TemplateDecl:
        name, *members = children
        return TemplateDecl(_name(name), tuple(members), _pos(name))

    def instance(self, children: list) -> InstanceDecl:
        template, name, *members = children
        return InstanceDecl(_name(template), _name(name), tuple(members), _pos(template))

    def member(self, children: list) -> Member:
        name, value = children
        return Member(_name(name), _value(value))

    def step(self, children: list) -> StepDecl:
        name, *statements = children
        return StepDecl(_name(name), tuple(statements), Pos(name.line, 1))

    def task(self, children: list) -> TaskDecl:
        name, *statements = children
        return TaskDecl(_name(name), tuple(statements), Pos(name.line, 1))

    # statements
    def location(self, children: list) -> Statement:
        keyword, name = children
        return Statement(str(keyword), _pos(keyword), _name(name))

    def on_done(self, children: list) -> Statement:
        keyword, *names = children
        return Statement(str(keyword), _pos(keyword), tuple(_name(n) for n in names))

    parameters = on_done

    def triggered_by(self, children: list) -> Statement:
        keyword, expr = children
        return Statement(str(keyword), _pos(keyword), expr)

    finished_by = constraints = triggered_by

    def repeat(self, children: list) -> Statement:
        keyword, value = children
        return Statement(str(keyword), _pos(keyword), Name(str(value), _pos(value)))

    def transport(self, children: list) -> Statement:
        keyword, _from, *rest = children
        source, rest = rest[0], rest[1:]
        source_args: tuple[Value, ...] = ()
        if isinstance(rest[0], tuple):
            source_args, rest = rest[0], rest[1:]
        _to, target, *target_args = rest
        pickup = StepRef(_name(source), source_args)
        delivery = StepRef(_name(target), target_args[0] if target_args else ())
        return Statement(str(keyword), _pos(keyword), (pickup, delivery))

    def arguments(self, children: list) -> tuple[Value, ...]:
        return tuple(_value(t) for t in children)

    # expressions
    def name(self, children: list) -> Expr:
        return Ref(str(children[0]), _pos(children[0]))

    def attribute(self, children: list) -> Expr:
        task, attribute = children
        return TaskAttribute(str(task), str(attribute), _pos(task))

    @v_args(meta=True)
    def true(self, meta: lark.tree.Meta, _children: list) -> Expr:
        return Const(True, Pos(meta.line, meta.column))

    @v_args(meta=True)
    def false(self, meta: lark.tree.Meta, _children: list) -> Expr:
        return Const(False, Pos(meta.line, meta.column))

    def integer(self, children: list) -> Expr:
        return Const(int(children[0]), _pos(children[0]))

    def float(self, children: list) -> Expr:
        return Const(float(children[0]), _pos(children[0]))

    def string(self, children: list) -> Expr:
        return Const(str(children[0])[1:-1], _pos(children[0]))

    @v_args(meta=True)
    def not_(self, meta: lark.tree.Meta, children: list) -> Expr:
        return Not(children[0], Pos(meta.line, meta.column))

    def and_(self, children: list) -> Expr:
        left, right = children
        return And(left, right, left.at)

    def or_(self, children: list) -> Expr:
        left, right = children
        return Or(left, right, left.at)

    def comparison(self, children: list) -> Expr:
        left, op, right = children
        return Compare(str(op), left, right, left.at)
