"""Hand-built captures of the ROS 2 interposer (runner.run.roscbdata), for the pure tests of callbacks: no native code.

A `Node` writes the metas rcl and rclcpp would emit (in rclcpp's order, or any other), and its
callbacks' instances; `capture` wraps processes into a program's RosCapture.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from runner.run.roscbdata import CallbackRecord, ClockType, Meta, MetaKind, PublishRecord, RosCapture, RosProcess, RosThread

MS = 1_000_000
BASE = 10_000 * MS  # the cell's start gate in these tests (CLOCK_MONOTONIC)
REALTIME = 1_700_000_000_000_000_000  # CLOCK_REALTIME minus CLOCK_MONOTONIC in these tests


@dataclass
class Node:
    """One process's metas and records, written in order by the helpers."""

    pid: int = 100
    tid: int = 100
    metas: list[Meta] = field(default_factory=list)
    callbacks: list[CallbackRecord] = field(default_factory=list)
    publishes: list[PublishRecord] = field(default_factory=list)
    t: int = BASE - 500 * MS
    seq: dict[int, int] = field(default_factory=dict)

    def meta(self, kind: MetaKind, **kw: object) -> Meta:
        self.t += 1000
        m = Meta(kind=kind, tid=self.tid, t_ns=int(kw.pop("t_ns", self.t)), **kw)  # type: ignore[arg-type]
        self.metas.append(m)
        return m

    def node(self, handle: int, name: str, ns: str = "/") -> None:
        self.meta(MetaKind.NODE, a=handle, b=handle + 1, s1=name, s2=ns)

    def timer(self, node: int, timer: int, cb: int, period: int, first: int, symbol: str = "", clock: ClockType = ClockType.STEADY) -> None:
        """rcl_timer_init, rclcpp_timer_callback_added, rclcpp_callback_register, rclcpp_timer_link_node: rclcpp's order."""
        self.meta(MetaKind.TIMER, a=timer, d=period, e=first, clock=clock)
        self.meta(MetaKind.TIMERCB, a=timer, b=cb)
        if symbol is not None:
            self.meta(MetaKind.SYM, a=cb, s1=symbol)
        self.meta(MetaKind.TIMERNODE, a=timer, b=node)

    def subscription(self, node: int, sub: int, rmw: int, obj: int, cb: int, topic: str, symbol: str = "") -> None:
        self.meta(MetaKind.SUB, a=sub, b=node, c=rmw, d=10, s1=topic)
        self.meta(MetaKind.SUBOBJ, a=sub, b=obj)
        self.meta(MetaKind.SUBCB, a=obj, b=cb)
        if symbol:
            self.meta(MetaKind.SYM, a=cb, s1=symbol)

    def publisher(self, node: int, pub: int, rmw: int, topic: str) -> None:
        self.meta(MetaKind.PUB, a=pub, b=node, c=rmw, d=10, s1=topic)

    def run(self, cb: int, start: int, wall: int = MS // 10, tid: int = 0, **kw: object) -> CallbackRecord:
        """One instance of callback `cb` starting at `start` (CLOCK_MONOTONIC), `wall` long."""
        tid = tid or self.tid
        seq = self.seq.get(tid, 0)
        self.seq[tid] = seq + 1
        fields: dict[str, object] = dict(
            tid=tid, cb=cb, seq=seq, start_ns=start, end_ns=start + wall, cpu_start=0, cpu_end=0, nivcsw=0, nvcsw=0
        )
        fields.update(minflt=0, majflt=0, cpu_ns=wall)
        fields.update(kw)
        rec = CallbackRecord(**fields)  # type: ignore[arg-type]
        self.callbacks.append(rec)
        return rec

    def publish(self, rmw: int, inside: CallbackRecord, at: int, exact: bool = True, stamp_delay: int = 0) -> int:
        """A publish on rmw publisher `rmw` inside instance `inside`, at `at`; returns the source timestamp subscribers see."""
        src = at + REALTIME
        self.publishes.append(
            PublishRecord(
                tid=inside.tid, handle=rmw, handle_is_rcl=False, t_ns=at, src_ts=src, exact=exact,
                enclosing_cb=inside.cb, enclosing_seq=inside.seq,
            )
        )  # fmt: skip
        return src + stamp_delay

    def process(self, threads: tuple[RosThread, ...] = (), **kw: object) -> RosProcess:
        tids = sorted({r.tid for r in self.callbacks} | {self.tid})
        threads = threads or tuple(RosThread(tid=t, comm=f"thread{t}", written=0, lost=0) for t in tids)
        return RosProcess(
            pid=self.pid,
            ppid=1,
            exe="/opt/ros/bin/node",
            threads=threads,
            metas=tuple(self.metas),
            callbacks=tuple(self.callbacks),
            publishes=tuple(self.publishes),
            **kw,  # type: ignore[arg-type]
        )


def capture(*processes: RosProcess, **kw: object) -> RosCapture:
    kw.setdefault("loaded", True)
    kw.setdefault("libraries", ("librclcpp.so", "libtracetools.so"))
    return RosCapture(processes=processes, **kw)  # type: ignore[arg-type]


def shuffled(p: RosProcess) -> RosProcess:
    """The process with its metas in reverse order: the runner must not depend on the order they were written in."""
    return replace(p, metas=tuple(reversed(p.metas)))
