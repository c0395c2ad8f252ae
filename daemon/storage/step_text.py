"""The steps table as CSV lines and JSON objects, at the storage's speed (issue 30).

Python's ``csv`` module on a cursor of the steps took ~2.8x the time of SQLite's own CSV
output (``sqlite3 -csv``), ``json.dumps`` of a dict per step more (benchmarks/
bench_exports.py), and most of it went to scanning the long JSON text columns character by
character for quoting. Here SQLite does what it does in C while it reads a row: text cells
are quoted (CSV: ``replace`` of quotes, only where Python's ``csv`` would quote) or escaped
(JSON: ``json_quote``), and missing cells are already the empty string or ``null``. What is
left for Python is one ``%`` formatting per row, whose ``%s`` of a float is ``repr``: the
shortest digits that read back as the same double. (SQLite's own text for a REAL has 15
significant digits and does not round-trip; its ``printf('%!.17g')`` does but is slower and
prints ``0.1`` as ``0.10000000000000001``.)

That is :func:`step_text`, kept as the reference. The exports use :func:`csv_lines` and
:func:`json_objects`, which write the same bytes a chunk at a time: only the columns with a
value in the chunk are read, each column's cells become text in one C call where it can
(msgspec prints the numbers in ``repr``'s layout, daemon/storage/float_text.py, and escapes
the JSON strings) and one ``%`` formats the whole chunk (JSON at 1.9x and CSV at 1.8x the
wall time of ``sqlite3 -csv`` for a 24-h run, benchmarks/bench_exports.py).

The text is exactly what ``csv.writer`` (``lineterminator="\\n"``) and ``json.dumps`` of
the step records write, value for value (tests/test_exports.py checks both), with
infinities as ``inf``/``-inf`` in CSV and ``null`` in JSON (SQLite stores NaN as NULL).
The columns are daemon/storage/step_record.py's, in its order: the export contract.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import sqlite3
from collections.abc import Callable, Iterator, Sequence
from functools import cache
from typing import Any

import msgspec

from daemon.storage.float_text import float_text
from daemon.storage.step_record import STEP_COLUMNS, StepRecord, column_type

CSV_HEADER = ",".join(STEP_COLUMNS)
#: beyond the largest finite double: an infinity
_MAX_DOUBLE = "1.7976931348623157e308"
#: Python's csv module (QUOTE_MINIMAL) quotes a field holding any of these
_NEEDS_QUOTES = "'*[,\"' || char(10) || char(13) || ']*'"


def _csv_cell(column: str, sql_type: str) -> str:
    if sql_type == "TEXT":
        return (
            f"CASE WHEN {column} IS NULL THEN '' WHEN {column} GLOB {_NEEDS_QUOTES} "
            f"THEN '\"' || replace({column}, '\"', '\"\"') || '\"' ELSE {column} END"
        )
    return f"COALESCE({column}, '')"  # numbers stay numbers: Python prints them


def _json_value(column: str, sql_type: str) -> str:
    if sql_type == "TEXT":
        return f"json_quote({column})"  # NULL -> null
    if sql_type == "REAL":
        return (
            f"CASE WHEN {column} IS NULL OR abs({column}) > {_MAX_DOUBLE} THEN 'null' "
            f"ELSE {column} END"
        )
    return f"COALESCE({column}, 'null')"


@cache
def _columns() -> tuple[tuple[str, str], ...]:
    return tuple((f.name, column_type(f)) for f in dataclasses.fields(StepRecord))


@cache
def _query(json: bool) -> tuple[str, str]:
    """The SELECT of one step's cells (the step number first) and the row's format."""
    if json:
        cells = [_json_value(name, kind) for name, kind in _columns()]
        row_format = "{" + ",".join(f'"{name}":%s' for name, _ in _columns()) + "}"
    else:
        cells = [_csv_cell(name, kind) for name, kind in _columns()]
        row_format = ",".join("%s" for _ in _columns())
    sql = (
        f"SELECT step, {', '.join(cells)} FROM steps WHERE run_id = ? AND step >= ? "
        "ORDER BY step LIMIT ?"
    )
    return sql, row_format


def step_text(
    db: sqlite3.Connection, run_id: int, start: int, count: int | None, *, json: bool
) -> tuple[str, int, int | None]:
    """Up to ``count`` (None: all) steps of a run from step ``start``: the CSV lines (each
    ending in a line feed, no header) or the JSON objects joined by commas, how many steps,
    and the last step's number (None when there are none)."""
    sql, row_format = _query(json)
    rows = db.execute(sql, (run_id, start, -1 if count is None else count)).fetchall()
    if not rows:
        return "", 0, None
    if json:
        text = ",".join([row_format % row[1:] for row in rows])
    else:
        text = "\n".join([row_format % row[1:] for row in rows]) + "\n"
    return text, len(rows), int(rows[-1][0])


def _csv_column(column: str, sql_type: str) -> str:
    """One column of :func:`csv_lines`' query: text cells quoted as in ``step_text``; a REAL
    stays a number (printed by daemon/storage/float_text.py) unless infinite, where ``repr``'s
    ``inf``/``-inf`` is written here (float_text prints non-finite values as null); integers
    as text."""
    if sql_type == "TEXT":
        return _csv_cell(column, sql_type)
    if sql_type == "REAL":
        return (
            f"CASE WHEN {column} > {_MAX_DOUBLE} THEN 'inf' "
            f"WHEN {column} < -{_MAX_DOUBLE} THEN '-inf' ELSE {column} END"
        )
    return f"COALESCE(CAST({column} AS TEXT), '')"


#: the query's infinities (bytes cells) as msgspec writes bytes: base64 in quotes
_INFINITIES = ((b'"aW5m"', b"inf"), (b'"LWluZg=="', b"-inf"))


def _csv_numbers(column: Sequence[Any]) -> list[bytes]:
    """A REAL column's cells: ``repr`` of each number, empty when missing, ``inf``/``-inf``."""
    text = float_text(column).replace(b"null", b"")  # only numbers are left to hold letters
    if b'"' in text:
        for encoded, infinity in _INFINITIES:
            text = text.replace(encoded, infinity)
    return text.split(b",")


#: a column's cells -> their text in the export (bytes, in order)
ColumnText = Callable[[Sequence[Any]], Sequence[bytes]]

_JSON_ENCODER = msgspec.json.Encoder()


def _as_is(column: Sequence[Any]) -> Sequence[bytes]:
    """Cells SQLite already made text (bytes) in the query."""
    return column


def _json_numbers(column: Sequence[Any]) -> list[bytes]:
    """A number column's JSON values: ``repr`` of each float (``str`` of each integer),
    ``null`` when missing or non-finite (SQLite stores NaN as NULL; infinities are read back
    as floats), printed by one msgspec call for the column (daemon/storage/float_text.py)."""
    return float_text(column).split(b",")


def _json_strings(column: Sequence[Any]) -> list[bytes]:
    """A text column's JSON strings, ``null`` when missing: msgspec's escapes (quote,
    backslash, controls as ``\\n`` or ``\\u00XX``, everything else as UTF-8) are SQLite's
    ``json_quote``'s, code point for code point (tests/test_exports.py), at a fifth of its
    cost."""
    encode = _JSON_ENCODER.encode
    return [encode(cell) for cell in column]


@dataclasses.dataclass(frozen=True, slots=True)
class _Plan:
    """A chunk's query (the step, then the columns with a value in the chunk), one row's
    format (bytes, ``%s`` per selected column, the missing ones written in it), how each
    selected column's cells become text, and whether SQLite hands text over as bytes (else
    as str)."""

    sql: str
    row: bytes
    texts: tuple[ColumnText, ...]
    text_as_bytes: bool


#: Plans kept: one per export format and set of columns a chunk has values in (a run kind
#: fills the same ones, so a handful at most).
PLANS_KEPT = 64


@functools.lru_cache(maxsize=PLANS_KEPT)
def _plan(json: bool, present: tuple[bool, ...]) -> _Plan:
    """The plan of :func:`csv_lines` (``json`` False) or :func:`json_objects` for a chunk
    whose columns with any value are ``present``. CSV: SQLite quotes the text and casts the
    integers, Python prints the REALs. JSON: SQLite only reads (its ``json_quote`` was two
    fifths of a chunk's time); text cells are escaped by msgspec and every number is printed
    by float_text (integers come out as ``str`` prints them). A column missing from the
    whole chunk is not read at all: its ``null`` (CSV: empty cell) is in the row format
    (a two-link run leaves the arm's 25 columns empty: 45 % of the cells)."""
    columns = [(n, k, p) for (n, k), p in zip(_columns(), present, strict=True)]
    if json:
        parts = [f'"{name}":' + ("%s" if p else "null") for name, _, p in columns]
        row = "{" + ",".join(parts) + "},"
        cells = [name for name, _, p in columns if p]
        texts: tuple[ColumnText, ...] = tuple(
            _json_strings if kind == "TEXT" else _json_numbers for _, kind, p in columns if p
        )
    else:
        row = ",".join("%s" if p else "" for _, _, p in columns) + "\n"
        cells = [_csv_column(name, kind) for name, kind, p in columns if p]
        texts = tuple(_csv_numbers if kind == "REAL" else _as_is for _, kind, p in columns if p)
    sql = f"SELECT step, {', '.join(cells)} FROM steps {_RANGE}"
    return _Plan(sql, row.encode(), texts, text_as_bytes=not json)


#: the chunk's rows: from a step, in order, at most a number of them
_RANGE = "WHERE run_id = ? AND step >= ? ORDER BY step LIMIT ?"


@cache
def _count_sql() -> str:
    """The chunk's row count and, per column, how many of its cells have a value."""
    names = [name for name, _ in _columns()]
    counts = ", ".join(f"count({name})" for name in names)
    return f"SELECT count(*), {counts} FROM (SELECT {', '.join(names)} FROM steps {_RANGE})"


@contextlib.contextmanager
def _snapshot(db: sqlite3.Connection) -> Iterator[None]:
    """One read transaction around what is inside (the count and the rows see the same
    steps), unless the caller already holds one."""
    if db.in_transaction:
        yield
        return
    db.execute("BEGIN")
    try:
        yield
    finally:
        db.execute("COMMIT")  # a read: nothing to write


def _encoded(
    db: sqlite3.Connection, run_id: int, start: int, count: int | None, *, json: bool
) -> tuple[bytes, int, int | None]:
    """The chunk's rows in their plan's row format, one after the other; how many; the last
    step's number. SQLite first counts which columns have a value in the chunk (a tenth of
    the time reading them costs) and only those are read; the chunk is then handled column
    by column in C calls (transposed by ``zip``, each number column printed by one msgspec
    call, put back in row order by slice assignment) and formatted by one ``%``."""
    text_factory = db.text_factory
    with _snapshot(db):
        counts = db.execute(_count_sql(), (run_id, start, -1 if count is None else count))
        found, *filled = counts.fetchone()
        if not found:
            return b"", 0, None
        plan = _plan(json, tuple(n > 0 for n in filled))
        db.text_factory = bytes if plan.text_as_bytes else str
        try:
            rows = db.execute(plan.sql, (run_id, start, found)).fetchall()
        finally:
            db.text_factory = text_factory
    columns = zip(*rows, strict=True)
    steps = next(columns)
    width = len(plan.texts)
    cells: list[bytes] = [b""] * (len(rows) * width)
    for index, column in enumerate(columns):
        cells[index::width] = plan.texts[index](column)
    return plan.row * len(rows) % tuple(cells), len(rows), int(steps[-1])


def csv_lines(
    db: sqlite3.Connection, run_id: int, start: int, count: int | None
) -> tuple[bytes, int, int | None]:
    """``step_text(..., json=False)``'s CSV lines, byte for byte, as UTF-8 bytes, with a
    fraction of its CPU (issue 30; benchmarks/bench_exports.py; see :func:`_encoded`).
    ``db`` is only read."""
    return _encoded(db, run_id, start, count, json=False)


def json_objects(
    db: sqlite3.Connection, run_id: int, start: int, count: int | None
) -> tuple[bytes, int, int | None]:
    """``step_text(..., json=True)``'s JSON objects joined by commas, byte for byte, as UTF-8
    bytes, by the CSV's column-at-a-time path (issue 30: a JSON page cost 2x a CSV's rows
    when each row was formatted, and each float printed by ``repr``, on its own).
    ``db`` is only read."""
    text, found, last = _encoded(db, run_id, start, count, json=True)
    return text[:-1], found, last  # without the last object's comma
