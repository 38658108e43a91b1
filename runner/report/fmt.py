"""How figures and text read in reports: durations (stored in ns) in the unit that reads best, counts with
separators, names from the scenario escaped so they stay text in markdown.  Pure.

Formatting is the only place a figure is scaled: results hold durations as integer ns
(figures.Unit.NS), and `fmt_ns` / `fmt_figure` choose µs, ms or s as they show them.
"""

from __future__ import annotations

import functools
import posixpath
import re
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING

from runner import units
from runner.figures import Figure, Number, Unit, scale

if TYPE_CHECKING:
    import jinja2


def fmt_ns(value: Number | None) -> str:
    """A duration given in nanoseconds, in the unit that reads best: `56.6 µs`, `142 µs`, `6.12 ms`, `1.20 s`, `−3.10 ms`."""
    return "–" if value is None else units.human_duration(value)


def fmt_mean(value: float | None) -> str:
    return "–" if value is None else ("0" if value == 0 else f"{value:.2f}")


def fmt_int(value: int | None) -> str:
    return "–" if value is None else f"{value:,}"


def fmt_bytes(value: int | None) -> str:
    if value is None:
        return "–"
    if value < 0:
        return "unlimited"
    for unit, size in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if value >= size:
            return f"{value / size:.1f} {unit}".replace(".0 ", " ")
    return f"{value} B"


def fmt_figure(value: Number | None, unit: Unit) -> str:
    """A figure alone, in words: a duration (ns) as `fmt_ns` shows it, a count whole, a mean of counts to two decimals."""
    if unit is Unit.NS:
        return fmt_ns(value)
    return scale(unit).number(value)


_SAMPLE_NOUNS = {"wakeup_ns": "wake-up", "latency_ns": "release", "callback_wall_ns": "callback", "message_age_ns": "message"}


def samples_words(figure: Figure, count: int) -> str:
    """How many values a percentile, mean or extreme stands on: `20 wake-ups`, `1 release`, `3 events`."""
    noun = _SAMPLE_NOUNS.get(figure.path[0], "event")
    return f"{count:,} {noun}{'' if count == 1 else 's'}"


# ---------------------------------------------------------------- text from the scenario, as markdown


class Markdown(str):
    """Text that is already markdown, built by the report from escaped parts: shown as it is.

    Anything else that reaches a report (a thread name, a matrix value, a reason) is plain
    text and goes through `md_text` first; the templates do that for every value that is not
    a Markdown, as an HTML template escapes everything not marked safe.
    """


_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f\u2028\u2029\u202a-\u202e\u2066-\u2069]")  # and bidi overrides, isolates
# What GitHub links by itself in text (not in code): @mentions (and emails), #123 and GH-123 issue references
# (owner/repo#123 too), URLs with a scheme and www. addresses.
_LIVE = re.compile(r"@[A-Za-z0-9][\w.\-/]*|#\d+|GH-\d+|\S*://\S*|www\.\S*", re.IGNORECASE)
_ALWAYS = set("\\`*[]~")  # code spans, emphasis, links and images, strikethrough


_PLAIN = re.compile(
    r"[^\x00-\x1f\x7f-\x9f\u2028\u2029\u202a-\u202e\u2066-\u2069\\`*\[\]~|_<&]*"
)  # no character md_text would escape inside a line


def md_text(value: object, in_table: bool = False) -> Markdown:
    """Plain text as inline markdown that renders as that text, on one line, and links nothing.

    Line breaks, control characters and bidi overrides become spaces (a newline must not
    start a heading), outer spaces go (four would start a code block), and every character
    that could start markdown structure is backslash-escaped: code spans, emphasis, links
    and images, HTML and autolinks, entities; in a table cell (`in_table`) `|`, elsewhere
    what would make a block if the text began a line (`#`, `>`, list markers).  Harmless
    uses stay as they read (`<= 2ms`, `minimal_schedul_`), so ordinary names look ordinary
    in the source too.

    What GitHub links after the markdown is rendered (a mention `@name` notifies that user,
    `#1` and `owner/repo#1` reference issue 1, `GH-1` too, `https://...` and `www....` become
    links) is shown in a code span: `@name`.  GitHub links none of these inside code, and
    neither a backslash (`\\@name`, `\\#1`) nor an entity (`&#64;`) stops it: its filters run
    on the rendered text, where those are gone (github/cmark-gfm issues 181 and 389).  A
    zero-width character between `#` and `1` would stop it too, but a name copied out of the
    report would then not be the name.  The runner's own labels are text like any other:
    `ctl/worker #1` (its thread with index 1) shows `#1` as code.
    """
    if isinstance(value, Markdown):
        return value
    return _md_text(str(value), in_table)


@functools.lru_cache(maxsize=1 << 16)
def _md_text(text: str, in_table: bool) -> Markdown:
    """md_text of text, remembered: a report writes the same names and numbers over and over (a 1,000-cell report
    escapes 230,000 values, most of them repeated), and a lookup costs a fraction of the checks."""
    if (
        _PLAIN.fullmatch(text)
        and text == text.strip()
        and (in_table or not (text[:1] in "#>-+=" or text[:1].isdigit() or "#" in text))
        and _LIVE.search(text) is None
    ):
        return Markdown(text)  # most names and numbers: nothing to escape (a 1,000-cell report writes 200,000 of them)
    text = _CONTROL.sub(" ", text).strip()
    spans: list[list[int]] = []  # side by side, two code spans would read as one with a fence of two backticks
    for live in _LIVE.finditer(text):
        if spans and spans[-1][1] == live.start():
            spans[-1][1] = live.end()
        else:
            spans.append([live.start(), live.end()])
    pieces, at = [], 0
    for start, end in spans:
        pieces += [_escaped(text[at:start], in_table), md_code(text[start:end], in_table)]
        at = end
    escaped = "".join(pieces) + _escaped(text[at:], in_table)
    return Markdown(escaped if in_table else _escape_line_start(escaped))


def _escaped(text: str, in_table: bool) -> str:
    """Text with every character that could start markdown structure inside a line backslash-escaped."""
    out = []
    for i, ch in enumerate(text):
        after = text[i + 1] if i + 1 < len(text) else " "
        before = text[i - 1] if i else " "
        if (
            ch in _ALWAYS
            or (ch == "|" and in_table)
            or (ch == "_" and not before.isalnum())  # after a letter or digit `_` cannot open emphasis
            or (ch == "<" and not (after.isspace() or (after == "=" and text[i + 2 : i + 3] in ("", " "))))
            or (ch == "&" and (after.isalnum() or after == "#"))
        ):
            out.append("\\" + ch)
        else:
            out.append(ch)
    return "".join(out)


def _escape_line_start(text: str) -> str:
    """Escape what would make a block if the text began a line: `#`, `>`, list markers, rules, trailing `#`."""
    if not text:
        return text
    first, after = text[0], text[1:2]
    if first in "#>" or (first in "-+=" and (after in ("", " ") or set(text) <= {first, " "})):
        text = "\\" + text
    else:
        digits = re.match(r"\d{1,9}([.)])( |$)", text)
        if digits:
            text = text[: digits.start(1)] + "\\" + text[digits.start(1) :]
    closing = re.search(r"(?<=[ ])#+$", text)  # `## Cell x #`: a closing sequence would vanish from the heading
    if closing:
        text = text[: closing.start()] + "\\" + text[closing.start() :]
    return text


def terminal_text(value: Markdown) -> str:
    """Inline markdown as a terminal shows it: emphasis marks and code ticks dropped, escapes undone."""
    return re.sub(r"\\(.)", r"\1", value.replace("**", "").replace("`", ""))


def md_code(value: object, in_table: bool = False) -> Markdown:
    """Plain text as an inline code span that shows it verbatim (a fence longer than any backtick run in it).

    Inside a table `|` must still be escaped (GFM splits cells before it sees code spans).
    """
    text = _CONTROL.sub(" ", str(value))
    if not text:
        return Markdown("``")
    fence = "`" * (max((len(run) for run in re.findall(r"`+", text)), default=0) + 1)
    pad = " " if text[0] == "`" or text[-1] == "`" or (text[0] == " " and text[-1] == " " and text.strip()) else ""
    if in_table:
        text = text.replace("|", "\\|")
    return Markdown(f"{fence}{pad}{text}{pad}{fence}")


def md_code_block(value: str, info: str = "") -> Markdown:
    """Text as a fenced code block: the fence is longer than any backtick run in it, so no line can close it."""
    fence = "`" * max(3, max((len(run) for run in re.findall(r"`+", value)), default=0) + 1)
    body = value if value.endswith("\n") else value + "\n"
    return Markdown(f"{fence}{info}\n{body}{fence}")


# ---------------------------------------------------------------- tables

LEFT, RIGHT = "left", "right"


def pipe_table(headers: Sequence[object], rows: Iterable[Sequence[object]], align: Sequence[str]) -> Markdown:
    """A GitHub-flavoured markdown table with `:---` / `---:` alignment markers, each cell as long as its text.

    Cells that are not Markdown are text, escaped by `md_text`.  Cells are not padded to their
    column's width: one long cell (a command line, a finding) made every line of its table as
    long, hundreds of characters of spaces in report.md and in a job summary; GitHub ignores the
    padding, and a reader of the source finds a row by its first cell.  Written here rather than
    by tabulate: a 1,000-cell report has 20,000 rows, and this is about four times faster.
    """

    def line(cells: Iterable[object]) -> str:
        return "| " + " | ".join(md_text(c, in_table=True) for c in cells) + " |"

    rule = "|" + "|".join("---:" if a == RIGHT else ":---" for a in align) + "|"
    return Markdown("\n".join([line(headers), rule, *(line(r) for r in rows)]))


_ENV: jinja2.Environment | None = None


def environment() -> jinja2.Environment:
    """The template environment (templates ship inside the package).

    Every `{{ value }}` that is not Markdown is text and goes through `md_text`, as an HTML
    template escapes what is not marked safe: a name from the scenario cannot become a heading,
    a table row, a link or HTML in the report.
    """
    import jinja2  # only the report and the comparison view render templates; the terminal's tables do not

    global _ENV
    if _ENV is None:
        _ENV = jinja2.Environment(
            loader=jinja2.PackageLoader("runner.report", "templates"),
            autoescape=False,
            trim_blocks=True,
            lstrip_blocks=True,
            keep_trailing_newline=True,
            undefined=jinja2.StrictUndefined,
            finalize=md_text,
        )
    return _ENV


# ---------------------------------------------------------------- paths


def relative_path(path: str, cwd: str | None) -> str:
    """`path` as a report shows it: relative to the working directory `cwd` when it lies inside it, else as given.

    A results file keeps the command line as typed; in CI that is the runner machine's checkout
    (`/home/runner/work/repo/repo/scenarios/x.yaml`), which says nothing to a reader and differs
    from host to host.  Pure: `cwd` is given, not read.
    """
    if cwd is None or not path.startswith("/"):
        return path
    root, full = posixpath.normpath(cwd), posixpath.normpath(path)
    if full == root:
        return "."
    return posixpath.relpath(full, root) if posixpath.commonpath([full, root]) == root else path


def relative_command(argv: Sequence[str], cwd: str | None) -> list[str]:
    """A command line with each absolute path inside `cwd` made relative (`--out=/abs/dir` too)."""
    out = []
    for word in argv:
        option, eq, value = word.partition("=")
        if eq and option.startswith("-"):
            out.append(f"{option}={relative_path(value, cwd)}")
        else:
            out.append(relative_path(word, cwd))
    return out
