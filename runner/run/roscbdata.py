"""What the runner's libtracetools interposer recorded inside a user's ROS 2 program, decoded: typed raw records.

A `command:` program runs with the runner's small native library preloaded
(runner/run/roscb.c, `callbacks:` on by default).  It defines the exported
`ros_trace_*` functions rcl and rclcpp call at every instrumented point, forwards each
call to the real libtracetools, and writes what it saw into a shared-memory file the
runner created for that program: per process a block, per thread a ring of records.
The shell (runner/run/roscb.py) decodes that file into these records; the pure core
(runner/run/callbacks.py) turns them into named callbacks with figures.  This module is
the contract between the two: plain frozen records, integers in ns, handles as the
integers of the program's own pointers (meaningful only within one process, and only
while the object lives: an address can be reused by a later object).

Clocks: every `*_ns` is CLOCK_MONOTONIC, as the rest of the runner; `src_ts` is the
middleware's source timestamp (CLOCK_REALTIME ns), as rmw_publish and rmw_take carry it.
No I/O here.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field


class MetaKind(enum.IntEnum):
    """What a meta record says: one `ros_trace_*` init call, with the handles it links (a, b, c) and its numbers.

    The numbers are the record's `type` in the ring (runner/run/roscb.h mirrors them).
    """

    NODE = 16  # rcl_node_init: a=node, b=rmw node; s1=name, s2=namespace
    PUB = 17  # rcl_publisher_init: a=publisher, b=node, c=rmw publisher, d=queue depth; s1=topic
    SUB = 18  # rcl_subscription_init: a=subscription, b=node, c=rmw subscription, d=queue depth; s1=topic
    SUBOBJ = 19  # rclcpp_subscription_init: a=rcl subscription, b=rclcpp subscription object
    SUBCB = 20  # rclcpp_subscription_callback_added: a=rclcpp subscription object, b=callback handle
    SRV = 21  # rcl_service_init: a=service, b=node, c=rmw service; s1=service name
    SRVCB = 22  # rclcpp_service_callback_added: a=service, b=callback handle
    TIMER = 23  # rcl_timer_init: a=timer, d=period ns, e=first release (CLOCK_MONOTONIC ns; 0: unknown), clock=rcl clock type
    TIMERCB = 24  # rclcpp_timer_callback_added: a=timer, b=callback handle
    TIMERNODE = 25  # rclcpp_timer_link_node: a=timer, b=node
    SYM = 26  # rclcpp_callback_register: a=callback handle; s1=the demangled symbol rclcpp gave ("" when it gave none)


class ClockType(enum.IntEnum):
    """rcl_clock_type_t, as rcl/time.h numbers it: which clock a timer's period runs on."""

    UNKNOWN = 0  # the interposer could not ask rcl (not linked, or the lookup failed)
    ROS = 1  # the node's clock: system time, or simulated time when use_sim_time is on (no release grid then)
    SYSTEM = 2
    STEADY = 3


@dataclass(frozen=True)
class Meta:
    """One init-time call: which objects it links, when (CLOCK_MONOTONIC), on which thread."""

    kind: MetaKind
    tid: int
    t_ns: int
    a: int = 0
    b: int = 0
    c: int = 0
    d: int = 0
    e: int = 0
    clock: ClockType = ClockType.UNKNOWN
    s1: str = ""
    s2: str = ""
    truncated: bool = False  # a string was longer than the interposer keeps, or its arena was full (then s1/s2 are "")


@dataclass(frozen=True)
class CallbackRecord:
    """One callback instance, from `callback_start` to `callback_end`, as its own thread measured it.

    The rusage deltas are `getrusage(RUSAGE_THREAD)` after minus before, as the seed measures them.
    A take on the same thread just before the start (rmw_take with a message) gives the message's
    source timestamp and the middleware subscription it came from.
    """

    tid: int
    cb: int  # the callback handle (rclcpp's &callback_ / &any_callback_)
    seq: int  # per thread, from 0: gaps are records lost to the ring
    start_ns: int
    end_ns: int  # for an unterminated record: when the interposer closed it (a later end of an outer callback)
    cpu_start: int
    cpu_end: int
    nivcsw: int
    nvcsw: int
    minflt: int
    majflt: int
    cpu_ns: int  # user + system time of the thread during the callback
    release_ns: int = 0  # the timer's release this instance served, when the interposer knew it exactly; 0: unknown
    wake_ns: int = 0  # the executor's wake-up before it (wait_for_work → get_next_ready on this thread); 0: unknown
    src_ts: int = 0  # the taken message's source timestamp (CLOCK_REALTIME ns); 0: no take
    age_ns: int = 0  # CLOCK_REALTIME at the start minus src_ts; meaningful only with src_ts
    take_handle: int = 0  # the rmw subscription of that take; 0: none
    intra: bool = False  # callback_start said is_intra_process: no take, no age
    depth: int = 0  # 0: outermost; n: started inside n callbacks of the same thread
    unterminated: bool = False  # its callback_end never came (an outer end or the thread's exit closed it)


@dataclass(frozen=True)
class PublishRecord:
    """One rmw_publish: on which publisher, when, with which source timestamp, inside which callback instance."""

    tid: int
    handle: int  # the rmw publisher (Jazzy and later), or the rcl publisher of the rcl_publish just before (Humble)
    handle_is_rcl: bool
    t_ns: int
    src_ts: int  # CLOCK_REALTIME ns: exactly the subscribers' source timestamp when `exact`, else the hook's own clock
    exact: bool  # the middleware passed its timestamp to the hook (Jazzy and later)
    enclosing_cb: int = 0  # the callback running on this thread when it published; 0: none
    enclosing_seq: int = -1  # that instance's seq on this thread; -1: none


@dataclass(frozen=True)
class RosThread:
    """One thread that reached a hook: its ring's bookkeeping and the callback it was inside at the end, if any."""

    tid: int
    comm: str
    written: int  # records the thread wrote, all told
    lost: int  # records overwritten before the runner read them (a full ring)
    lost_other: int = 0  # records the interposer could not write: callback stack too deep, an end with no start
    open_cb: int = 0  # a callback started and not ended when the file was read; 0: none
    open_since_ns: int = 0
    exited: bool = False


class ProcessFlag(str, enum.Enum):
    """What the interposer learned about a process, in words the report can use."""

    TRACETOOLS = "tracetools"  # the real libtracetools was found (dlsym RTLD_NEXT): calls were forwarded
    ENABLED_API = "enabled_api"  # the real library has ros_trace_enabled_* (Iron and later)
    PUBLISH_TIMESTAMP = "publish_timestamp"  # rmw_publish carries the source timestamp (Jazzy and later)
    SHADOWED = "shadowed"  # another definition of ros_trace_callback_start comes first (`shadowed_by` names it)
    FORKED = "forked"  # a child forked from a process that had already reached a hook


@dataclass(frozen=True)
class RosProcess:
    """One process of the program that reached a hook: everything its threads recorded."""

    pid: int
    ppid: int
    exe: str
    flags: frozenset[ProcessFlag] = frozenset()
    shadowed_by: str = ""  # the object that defines ros_trace_callback_start ahead of the runner's library
    first_hook_ns: int = 0
    strings_dropped: int = 0  # names, topics or symbols its string arena had no room for
    threads: tuple[RosThread, ...] = ()
    metas: tuple[Meta, ...] = ()  # in the order each thread wrote them, threads one after another
    callbacks: tuple[CallbackRecord, ...] = ()
    publishes: tuple[PublishRecord, ...] = ()


@dataclass(frozen=True)
class RosCapture:
    """What one program's shared-memory file held at the end of the cell.

    `processes` is empty for a program that never reached a hook (not a ROS 2 program, a static
    or 32-bit executable the preload could not enter, a node built with TRACETOOLS_DISABLED);
    `loaded` says whether the library was mapped into it at all, from /proc/PID/maps, so the report
    can tell those apart from a ROS program that ran no callback.
    """

    path: str = ""  # the file, while the cell ran (unlinked at its end)
    processes: tuple[RosProcess, ...] = ()
    processes_refused: int = 0  # processes that found every process block taken, or no room in /dev/shm
    threads_refused: int = 0  # threads that found every thread slot taken, or no room in /dev/shm
    error: str = ""  # the file could not be read or had another layout, in words; "" when it was read
    loaded: bool | None = None  # the library was in the program's maps when last read; None: not known
    libraries: tuple[str, ...] = field(default=())  # ROS libraries in its maps (librclcpp.so, libtracetools.so, ...)
    blocked: str = ""  # why the preload cannot enter the program's executable (static, 32-bit, setuid), in words; "": it can
