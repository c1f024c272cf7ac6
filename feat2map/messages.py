"""Short user-facing text: counts with the right plural, and error lines kept to one short line
(a message that quotes a whole file or document must not flood a terminal)."""
from __future__ import annotations

import re
import sys

MAX_LINE_CHARS = 300  # one error or warning line, file and element included


def counted(n: int, noun: str, plural: str | None = None) -> str:
    """`3 junctions`, `1 junction`; `plural` for nouns that do not take an -s."""
    return f"{n} {noun if n == 1 else plural or noun + 's'}"


def printable(text: object) -> str:
    """`text` with every character a terminal would act on (newlines, escapes) written as its
    Python escape: an id read from a corrupt file cannot break a report into lines."""
    return "".join(c if c.isprintable() else ascii(c)[1:-1] for c in str(text))


def one_line(text: object, limit: int = MAX_LINE_CHARS) -> str:
    """`text` on one line of at most `limit` characters: whitespace runs become one space, other
    control characters are escaped, and an over-long middle is cut (the start names the file and
    element, the end usually says what was expected)."""
    s = printable(re.sub(r"\s+", " ", str(text)).strip())  # no terminal control sequences
    if len(s) <= limit:
        return s
    keep = limit - len(f" ... [{len(s):,} characters cut] ... ")  # at least as long as the real marker
    head, tail = keep * 2 // 3, keep - keep * 2 // 3
    return f"{s[:head]} ... [{len(s) - head - tail:,} characters cut] ... {s[len(s) - tail:]}"


def on_terminal() -> bool:
    """Whether stderr is a terminal: progress bars are drawn only there (a log file or a pipe
    would collect every redrawn frame)."""
    try:
        return sys.stderr is not None and sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False
