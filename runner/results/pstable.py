"""ps-style thread tables, byte for byte as procps prints `ps -L -o tid,comm,rtprio,cls,psr`.

Pure: rows in, text out.  Column rules follow procps-ng: TID as wide as the
largest possible PID, COMMAND 15 columns wide and left-aligned (unpadded when last), its
unprintable characters `?` (`printable.for_terminal`) and its width counted in terminal
columns (a CJK character takes two),
RTPRIO `-` for SCHED_OTHER only, NI `-` for policies other than TS and B, every
other column right-aligned, one space apart.  Columns are named as procps names them
(`nvcsw`, `nivcsw`: headers VCSW, IVCSW); `cpus` (the affinity list) is the runner's own.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Optional, Protocol

from runner import units
from runner.errors import UsageError, did_you_mean
from runner.printable import for_terminal, width

CLS = {0: "TS", 1: "FF", 2: "RR", 3: "B", 5: "IDL", 6: "DLN"}


class TableRow(Protocol):
    """What a table reads of a thread: a row read from /proc now (ThreadRow), or one stored in results (document.PsRow)."""

    @property
    def pid(self) -> int: ...
    @property
    def tid(self) -> int: ...
    @property
    def comm(self) -> str: ...
    @property
    def policy(self) -> int: ...
    @property
    def rtprio(self) -> int: ...
    @property
    def nice(self) -> int: ...
    @property
    def psr(self) -> int: ...
    @property
    def prio(self) -> Optional[int]: ...
    @property
    def cpus(self) -> tuple[int, ...]: ...
    @property
    def voluntary(self) -> Optional[int]: ...
    @property
    def involuntary(self) -> Optional[int]: ...
    @property
    def cls(self) -> str: ...


@dataclass(frozen=True)
class ThreadRow:
    """One thread as the kernel reports it (policy numbers as in sched(7)).

    Plain data, so that `runner ps` imports no validation library; results store it as
    `document.PsRow`, which has the same fields.
    """

    pid: int
    tid: int
    comm: str
    policy: int  # sched(7) number; CLS names it as ps does
    rtprio: int
    nice: int
    psr: int
    prio: Optional[int]  # /proc stat field 18 (kernel prio, shifted); None where not recorded (results/1 files)
    cpus: tuple[int, ...] = ()
    voluntary: Optional[int] = None
    involuntary: Optional[int] = None

    @property
    def cls(self) -> str:
        """The policy as ps names it (TS, FF, RR, B, IDL, DLN)."""
        return CLS.get(self.policy, "?")


@dataclass(frozen=True)
class Column:
    header: str
    width: int
    left: bool
    value: Callable[[TableRow], str]


def _rtprio(row: TableRow) -> str:
    return "-" if row.policy == 0 else str(row.rtprio)


def _nice(row: TableRow) -> str:
    return str(row.nice) if row.policy in (0, 3) else "-"


def _opt(value: Optional[int]) -> str:
    return "-" if value is None else str(value)


def columns_for(pid_width: int = 5) -> dict[str, Column]:
    """The known columns; `pid_width` is the digit count of the largest PID (pid_max - 1)."""
    return {
        "tid": Column("TID", max(pid_width, 3), False, lambda r: str(r.tid)),
        "pid": Column("PID", max(pid_width, 3), False, lambda r: str(r.pid)),
        "comm": Column("COMMAND", 15, True, lambda r: for_terminal(r.comm)),
        "rtprio": Column("RTPRIO", 6, False, _rtprio),
        "cls": Column("CLS", 3, False, lambda r: r.cls),
        "psr": Column("PSR", 3, False, lambda r: str(r.psr)),
        "ni": Column("NI", 3, False, _nice),
        "pri": Column("PRI", 3, False, lambda r: "-" if r.prio is None else str(39 - r.prio)),
        "cpus": Column("CPUS", 4, False, lambda r: units.format_cpus(r.cpus) if r.cpus else "-"),
        "nvcsw": Column("VCSW", 5, False, lambda r: _opt(r.voluntary)),
        "nivcsw": Column("IVCSW", 5, False, lambda r: _opt(r.involuntary)),
    }


ALIASES = {"vcsw": "nvcsw", "ivcsw": "nivcsw"}
"""Names this runner documented before it took procps's spelling; still read, never listed."""


DEFAULT_COLUMNS = ("tid", "comm", "rtprio", "cls", "psr")


def parse_columns(spec: str) -> list[str]:
    """`tid,comm,rtprio` -> ['tid', 'comm', 'rtprio']; unknown names are a usage error (with a did-you-mean)."""
    known = columns_for()
    names = [ALIASES.get(n, n) for n in (name.strip().lower() for name in spec.split(",")) if n]
    for name in names:
        if name not in known:
            raise UsageError(f"unknown column {name!r}{did_you_mean(name, known)}; known: {', '.join(known)}")
    return names


def render_ps(rows: Sequence[TableRow], columns: Optional[list[str]] = None, pid_width: int = 5) -> str:
    """The table as procps prints it, header included, one line per row, newline-terminated."""
    known = columns_for(pid_width)
    cols = [known[name] for name in (columns or DEFAULT_COLUMNS)]
    lines = []
    for cells in [[c.header for c in cols]] + [[c.value(r) for c in cols] for r in rows]:
        parts = []
        for i, (col, text) in enumerate(zip(cols, cells)):
            last = i == len(cols) - 1
            gap = " " * (col.width - width(text))
            if col.left:
                parts.append(text if last else text + gap)
            else:
                parts.append(gap + text)
        lines.append(" ".join(parts))
    return "\n".join(lines) + "\n"
