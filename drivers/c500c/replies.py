"""What the C500C console says besides data, as pure functions: its questions, the messages
after which it does not do what was asked, its error lines (shell errors and the motion
catalogue) and the point-of-control request (docs/reference/c500c-console.md "Questions", "Errors").
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

from drivers.c500c.texts import (
    ASH_ONLINE_ERROR,
    BLOCKING_MESSAGES,
    ERROR_PREFIX,
    MOTION_ERRORS,
    ONLINE_ERROR_CODE,
    SHELL_ERRORS,
)

# --- questions ---------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Question:
    """A question the console asks and waits for an answer to [firmware]."""

    kind: str
    text: str
    answer: str | None  # what the driver answers deliberately; None: never answer it


#: The questions the firmware can ask (docs/reference/c500c-console.md "Questions"), matched at the
#: end of what the console printed. The driver creates its variables with `new` so "create it?" is
#: not asked; if it is all the same, it answers "no": a variable the driver did not create is an
#: error.
KNOWN_QUESTIONS: tuple[Question, ...] = (
    Question("create-variable", "  -- create it? ", "no"),
    Question("yes-or-no", "Please answer 'yes' or 'no': ", "no"),
    Question("set-valid", "Set the valid flag anyway (y/n) ?", "n"),
    Question("save-first", "Variables have been changed -- save first? ", None),
    Question("exit", "Are you sure you want to exit? ", None),
    Question("application-name", "Application name > ", None),
)
#: How an unknown question ends (ASSUMED 7): a non-empty line without line end, ending so.
_QUESTION_END = re.compile(r"(\? ?|: |> )$")


def pending_line(buffer: bytes) -> str:
    """What follows the last line end of ``buffer``: a question, a prompt, or a line in transit."""
    return buffer[buffer.rfind(b"\n") + 1 :].decode("ascii", errors="replace")


def find_question(buffer: bytes) -> Question | None:
    """The known question ``buffer`` ends with (the console waits for an answer), if any."""
    tail = pending_line(buffer)
    for question in KNOWN_QUESTIONS:
        if tail.rstrip() == question.text.rstrip():
            return question
    return None


def may_be_question(buffer: bytes) -> bool:
    """Whether ``buffer`` ends like an unknown question: the driver treats it as one when
    nothing more comes for a while (a line in transit can end so by chance)."""
    tail = pending_line(buffer)
    return bool(tail.strip()) and _QUESTION_END.search(tail) is not None


def blocking_message(lines: Sequence[str]) -> str | None:
    """The first line saying the console will not do what was asked (BLOCKING_MESSAGES)."""
    for line in lines:
        if any(line.strip().startswith(message) for message in BLOCKING_MESSAGES):
            return line.strip()
    return None


# --- errors ------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class ConsoleError:
    """An error line of the console: a catalogue number (motion errors) and its text."""

    code: int | None
    text: str


def _catalogue_patterns() -> list[tuple[int, re.Pattern[str]]]:
    return [
        (code, re.compile("^" + re.escape(text).replace(re.escape("$1"), r"\d+") + "$"))
        for code, text in MOTION_ERRORS.items()
    ]


_CATALOGUE = _catalogue_patterns()
_LEADING_NUMBER = re.compile(
    r"^(?:sys004[-:. ]?)?(?P<code>\d{1,3})(?:[:.)-]\s*|\s+)(?P<text>\S.*)$"
)


def _known_text(text: str) -> ConsoleError | None:
    if text in SHELL_ERRORS:
        return ConsoleError(None, text)
    if text == ASH_ONLINE_ERROR:
        return ConsoleError(ONLINE_ERROR_CODE, text)
    for code, pattern in _CATALOGUE:
        if pattern.match(text):
            return ConsoleError(code, text)
    return None


def parse_error_line(line: str) -> ConsoleError | None:
    """The error a reply line reports, or ``None`` for an ordinary line (ASSUMED 3).

    Accepted: ``error: <text>`` (any text), a known text alone (shell errors, the motion
    catalogue, `ash`'s online-mode text), and either with a leading catalogue number, which then
    is the error's number."""
    text = line.strip()
    prefixed = text.startswith(ERROR_PREFIX)
    if prefixed:
        text = text[len(ERROR_PREFIX) :].strip()
    numbered = _LEADING_NUMBER.match(text)
    if numbered is not None:
        known = _known_text(numbered["text"])
        if known is not None or prefixed:
            return ConsoleError(int(numbered["code"]), numbered["text"])
    known = _known_text(text)
    if known is not None:
        return known
    return ConsoleError(None, text) if prefixed else None


def format_error(code: int | None, text: str | None = None) -> str:
    """The line the console prints for a motion error ``code`` (or a shell error ``text``)."""
    if code is None:
        assert text is not None
        return ERROR_PREFIX + text
    return ERROR_PREFIX + (text if text is not None else MOTION_ERRORS[code])


def first_error(lines: Sequence[str]) -> ConsoleError | None:
    for line in lines:
        error = parse_error_line(line)
        if error is not None:
            return error
    return None


def needs_point_of_control(text: str | bytes) -> bool:
    """Whether the console printed the PAUSE/CONTINUE request (it now waits for the button)."""
    needle = "PAUSE/CONTINUE"
    return (needle.encode() in text) if isinstance(text, bytes) else (needle in text)
