"""Short user-facing text: counts with the right plural, and error lines kept to one short line
(a message that quotes a whole file or document must not flood a terminal)."""
from __future__ import annotations

import re

MAX_LINE_CHARS = 300  # one error or warning line, file and element included


def counted(n: int, noun: str, plural: str | None = None) -> str:
    """`3 junctions`, `1 junction`; `plural` for nouns that do not take an -s."""
    return f"{n} {noun if n == 1 else plural or noun + 's'}"


def one_line(text: object, limit: int = MAX_LINE_CHARS) -> str:
    """`text` on one line of at most `limit` characters: whitespace runs become one space, other
    control characters are escaped, and an over-long middle is cut (the start names the file and
    element, the end usually says what was expected)."""
    s = re.sub(r"\s+", " ", str(text)).strip()
    s = "".join(c if c.isprintable() else ascii(c)[1:-1] for c in s)  # no terminal control sequences
    if len(s) <= limit:
        return s
    keep = limit - len(f" ... [{len(s):,} characters cut] ... ")  # at least as long as the real marker
    head, tail = keep * 2 // 3, keep - keep * 2 // 3
    return f"{s[:head]} ... [{len(s) - head - tail:,} characters cut] ... {s[len(s) - tail:]}"
