"""Untrusted text made safe to print on a terminal, as procps prints a thread's name.  Pure.

Names the runner reads from the kernel are whatever a process chose: up to 15 bytes of
anything, an escape sequence or a newline included, and not always UTF-8.  Printed raw
they drive the terminal (`\\x1b[2J` clears it) or forge lines of a table.  `for_terminal`
shows them as ps (procps-ng 4.0.2, Debian 12, in a UTF-8 locale) shows a COMMAND: every
character the C library does not call printable (`iswprint`: control characters C0, DEL
and C1, the line and paragraph separators, surrogates and code points Unicode has not
assigned) becomes one `?`, and so does each byte that is not UTF-8 (`decode` reads
those as U+FFFD, one per byte, as procps's mbrtowc loop counts them).  Everything
printable stays as it is, wide and zero-width characters included; `width` says how many
columns it takes, as ps pads its columns.  The one place that differs: a name that
holds U+FFFD itself is shown `?`, where procps prints it.

Newer procps (4.0.4 on) decide byte by byte instead: C0 and DEL, the first byte of a C1
character and each invalid byte become `?`, and unassigned code points are printed.  The
runner follows the procps of the machines it is tested on; both agree on what matters
(escape sequences, newlines and tabs are `?`).

Markdown has its own rule (runner/report/fmt.py, `md_text`); this one is for everything
shown on a terminal, in JUnit XML and in GitHub workflow commands.  Imports nothing
heavy: `runner ps` uses it.
"""

from __future__ import annotations

import codecs
import unicodedata

_UNPRINTABLE = frozenset(("Cc", "Cn", "Cs", "Zl", "Zp"))  # what glibc's iswprint refuses in C.UTF-8 (checked on glibc 2.36)
REPLACED = "\ufffd"  # a byte `decode` could not read


def _bytewise(error: UnicodeError) -> tuple[str, int]:
    """One U+FFFD per byte that is not UTF-8 (Python's "replace" gives one per maximal invalid run)."""
    assert isinstance(error, UnicodeDecodeError)
    return REPLACED * (error.end - error.start), error.end


codecs.register_error("runner.bytewise", _bytewise)


def decode(raw: bytes) -> str:
    """Bytes the kernel holds (a comm, a /proc file) as text: UTF-8, each byte that is not read as U+FFFD."""
    return raw.decode("utf-8", "runner.bytewise")


def for_terminal(text: str) -> str:
    """`text` with every character a terminal must not get raw (and every byte that was not UTF-8) as `?`, as ps does."""
    if text.isascii() and text.isprintable():
        return text  # nearly every name: nothing to look at
    return "".join("?" if ch == REPLACED or unicodedata.category(ch) in _UNPRINTABLE else ch for ch in text)


def width(text: str) -> int:
    """The terminal columns `text` takes once `for_terminal` made it safe (a CJK character two, a joiner none)."""
    if text.isascii():
        return len(text)
    from wcwidth import wcswidth  # here only: its tables take a while to import, and most names are ASCII

    width = wcswidth(text)
    return width if width >= 0 else len(text)


def lines_for_terminal(text: str) -> str:
    """`for_terminal` of each line, the lines joined by newlines again: for messages made of lines, whose parts are names."""
    return "\n".join(for_terminal(line) for line in text.split("\n"))
