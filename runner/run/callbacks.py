"""A ROS 2 program's callbacks, named and measured, from what the runner's interposer recorded inside it.  Pure, no I/O.

The interposer (runner/run/roscb.c) writes raw records (runner/run/roscbdata.py): init-time
metas that link rcl and rclcpp objects by their addresses, one record per callback instance
with its rusage deltas, and every publish.  This module resolves each instance's callback
handle to what it is (notes-38 §4.3, the chain tracetools_analysis and CARET follow):

- timer: `rclcpp_timer_callback_added(T, CB)` → `rcl_timer_init(T, period)` (with the first
  release and clock the hook read from rcl) → `rclcpp_timer_link_node(T, N)` → `rcl_node_init(N)`;
- subscription: `rclcpp_subscription_callback_added(OBJ, CB)` → `rclcpp_subscription_init(S, OBJ)`
  → `rcl_subscription_init(S, N, RMW_S, topic)` → the node;
- service: `rclcpp_service_callback_added(SRV, CB)` → `rcl_service_init(SRV, N, ..., name)`;
- `rclcpp_callback_register(CB, symbol)` names it.

Addresses are the program's own pointers: meaningful within one process, and only while the
object lives, so every link is keyed by (process, address) and taken from the record valid at
the time (the latest one before it; init records may come out of order, intra-process
subscriptions register their callback before the subscription exists: then the first after).

Each instance becomes a `Sample`, so a callback's figures are a thread's (samples.slot_of,
measure.thread_figures): for a timer callback the release grid of rcl's timer (release k at
first + k·period; a late callback skips whole periods, as `rcl_timer_call` does, and the
releases it skipped are missed ones, their latency counted as the runner's own periodic
threads count it), latency from a release to the *start* of the callback that served it, slack
to the next release; for a callback that took a message the message's age at its start.
Messages link callbacks across the cell's processes (a take to the publish of the same topic
and source timestamp: exact where the middleware passes its timestamp to the hook, Jazzy and
later; the nearest publish within 1 ms on Humble, said to be approximate), so a callback
reached from a timer callback's release has chain figures from that release to its end.

What the capture could not see (no ROS 2 library, a node built with TRACETOOLS_DISABLED, a
shadowing definition, records lost to full rings, a callback still running at the end) is said
in words, per program and per callback: never a silent empty table.
"""

from __future__ import annotations

from bisect import bisect_right
from collections import Counter, defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field
from fnmatch import fnmatchcase
from typing import Optional

from runner import figures as fg
from runner import units
from runner.histogram import from_values
from runner.results.document import (
    CallbackInstance,
    CallbackResult,
    CallbackThread,
    RosCaptureInfo,
    ThreadHistograms,
    Verdict,
    callback_label,
)
from runner.results.threadfigures import ThreadFigures
from runner.run.measure import check, spread, thread_figures
from runner.run.roscbdata import CallbackRecord, ClockType, Meta, MetaKind, ProcessFlag, PublishRecord, RosCapture, RosProcess
from runner.run.samples import Sample, slot_of
from runner.scenario.model import Expectation

APPROXIMATE_NS = 1_000_000  # Humble: a take's source timestamp is stamped after the publish hook, within this of it
SLOWEST = 5  # instances kept per callback, slowest first
_HEADER_KINDS = frozenset({MetaKind.TIMERCB, MetaKind.SUBOBJ, MetaKind.SUBCB, MetaKind.SRVCB, MetaKind.SYM})
"""Metas rclcpp emits from its headers, compiled into the user's program: none of them in a program built with
TRACETOOLS_DISABLED, while rcl (a library built as shipped) still reports its nodes and timers."""
_KEYS: dict[MetaKind, tuple[str, ...]] = {  # the handles each kind of meta is looked up by
    MetaKind.NODE: ("a",),
    MetaKind.PUB: ("a", "c"),
    MetaKind.SUB: ("a", "c"),
    MetaKind.SUBOBJ: ("b",),
    MetaKind.SUBCB: ("b",),
    MetaKind.SRV: ("a",),
    MetaKind.SRVCB: ("b",),
    MetaKind.TIMER: ("a",),
    MetaKind.TIMERCB: ("b",),
    MetaKind.TIMERNODE: ("a",),
    MetaKind.SYM: ("a",),
}


class _Metas:
    """One process's metas by (kind, handle field, handle): which record held for a handle at a given time.

    The times of each handle's records are listed once: an address reused thousands of times (a
    one-shot timer made anew in its callback) is looked up at every callback.
    """

    def __init__(self, metas: Sequence[Meta]) -> None:
        self._by: dict[tuple[MetaKind, str, int], list[Meta]] = defaultdict(list)
        for m in sorted(metas, key=lambda m: m.t_ns):
            for name in _KEYS.get(m.kind, ()):
                handle = getattr(m, name)
                if handle:
                    self._by[(m.kind, name, handle)].append(m)
        self._times = {key: [m.t_ns for m in found] for key, found in self._by.items()}

    def at(self, kind: MetaKind, name: str, handle: int, t_ns: int) -> Optional[Meta]:
        """The record of `kind` whose `name` field is `handle`, valid at `t_ns`: the latest before it, else the first after."""
        found = self._by.get((kind, name, handle))
        if not found:
            return None
        i = bisect_right(self._times[(kind, name, handle)], t_ns)
        return found[i - 1] if i else found[0]


@dataclass(frozen=True)
class _Identity:
    """What a callback handle was at a time: its registration (which tells one object from a later one at its address) and names."""

    kind: str  # timer, subscription, service, callback
    registered: Optional[Meta]
    node: str = ""
    symbol: str = ""
    topic: str = ""
    period_ns: int = 0
    first_ns: int = 0
    clock: ClockType = ClockType.UNKNOWN
    truncated: bool = False
    timer_seen: bool = False  # a timer's rcl_timer_init was found (its period may still be 0: always ready)


def node_name(meta: Optional[Meta]) -> str:
    """A node as `namespace/name` without the leading slash (`talker`, `robot/arm/driver`); "" when unknown."""
    if meta is None or not meta.s1:
        return ""
    ns = meta.s2.strip("/")
    return f"{ns}/{meta.s1}" if ns else meta.s1


def inherited(p: RosProcess, by_pid: dict[int, RosProcess]) -> list[Meta]:
    """A process's metas with those a forked child inherited: its parents' from before it reached its first hook.

    A child forked after the set-up runs on its parent's objects at the same addresses (a copy of
    its memory) without their init calls, which its parent made: its own block holds none of them.
    """
    out = list(p.metas)
    seen = {p.pid}
    child = p
    while ProcessFlag.FORKED in child.flags and child.ppid in by_pid and child.ppid not in seen:
        parent = by_pid[child.ppid]
        before = child.first_hook_ns or min((r.start_ns for r in child.callbacks), default=0)
        out += [m for m in parent.metas if not before or m.t_ns <= before]
        seen.add(parent.pid)
        child = parent
    return out


def _latest(found: Sequence[Optional[Meta]], t_ns: int) -> Optional[Meta]:
    """Of the registrations found for one address (of different kinds), the one valid at `t_ns`."""
    metas = [m for m in found if m is not None]
    before = [m for m in metas if m.t_ns <= t_ns]
    if before:
        return max(before, key=lambda m: m.t_ns)
    return min(metas, key=lambda m: m.t_ns, default=None)


def resolve(metas: _Metas, cb: int, t_ns: int) -> _Identity:
    """What callback handle `cb` of one process was at `t_ns`: its kind, node, symbol, topic or timer."""
    reg = _latest([metas.at(k, "b", cb, t_ns) for k in (MetaKind.TIMERCB, MetaKind.SUBCB, MetaKind.SRVCB)], t_ns)
    sym = metas.at(MetaKind.SYM, "a", cb, t_ns)
    symbol = pretty_symbol(sym.s1) if sym is not None else ""
    truncated = sym is not None and sym.truncated
    if reg is None:
        return _Identity("callback", None, symbol=symbol, truncated=truncated)
    t = reg.t_ns
    if reg.kind is MetaKind.TIMERCB:
        timer = metas.at(MetaKind.TIMER, "a", reg.a, t)
        link = metas.at(MetaKind.TIMERNODE, "a", reg.a, t)
        node = metas.at(MetaKind.NODE, "a", link.b, link.t_ns) if link is not None else None
        return _Identity(
            "timer",
            reg,
            node_name(node),
            symbol,
            period_ns=timer.d if timer is not None else 0,
            first_ns=timer.e if timer is not None else 0,
            clock=timer.clock if timer is not None else ClockType.UNKNOWN,
            truncated=truncated or bool(node and node.truncated),
            timer_seen=timer is not None,
        )
    if reg.kind is MetaKind.SUBCB:
        obj = metas.at(MetaKind.SUBOBJ, "b", reg.a, t)
        sub = metas.at(MetaKind.SUB, "a", obj.a, obj.t_ns) if obj is not None else None
        node = metas.at(MetaKind.NODE, "a", sub.b, sub.t_ns) if sub is not None else None
        topic = sub.s1 if sub is not None else ""
        bad = truncated or any(m is not None and m.truncated for m in (sub, node))
        return _Identity("subscription", reg, node_name(node), symbol, topic, truncated=bad)
    srv = metas.at(MetaKind.SRV, "a", reg.a, t)
    node = metas.at(MetaKind.NODE, "a", srv.b, srv.t_ns) if srv is not None else None
    bad = truncated or any(m is not None and m.truncated for m in (srv, node))
    return _Identity("service", reg, node_name(node), symbol, srv.s1 if srv is not None else "", truncated=bad)


# ------------------------------------------------------------------ names


def _closing(text: str, at: int) -> int:
    """The index of the `>` closing the `<` at `at` (len(text) when it never closes)."""
    depth = 0
    for i in range(at, len(text)):
        if text[i] == "<":
            depth += 1
        elif text[i] == ">":
            depth -= 1
            if depth == 0:
                return i
    return len(text)


def _drop_template(text: str, name: str) -> str:
    """`text` without every `, name<...>` (or `name<...>`) template argument: std::allocator's and default_delete's noise."""
    while True:
        at = text.find(name + "<")
        if at < 0:
            return text
        end = _closing(text, at + len(name))
        start = at
        before = text[:start].rstrip()
        if before.endswith(","):
            start = len(before) - 1
        text = text[:start] + text[end + 1 :]


def pretty_symbol(symbol: str) -> str:
    """A callback's symbol as rclcpp gave it, lightly prettified as tracetools_analysis does (`utils/ros2.py` `_prettify`).

    std::allocator and std::default_delete template arguments go; a `std::_Bind<R (C::*(C*,
    placeholders))(args)>` (a `std::bind(&C::m, this, _1)`, which names the class and the
    signature but not the member) becomes `R (C::?)(args)`.  A lambda's name
    (`C::C()::{lambda()#1}`) and a plain function's stay as they are.
    """
    text = symbol.strip()
    for noise in ("std::allocator", "std::default_delete"):
        text = _drop_template(text, noise)
    text = text.replace(" >", ">")  # the old demangler's `> >`, and what a dropped argument left
    bind = "std::_Bind<"
    if text.startswith(bind) and text.endswith(">"):
        inner = text[len(bind) : -1]
        star = inner.find("::*(")
        if star >= 0:
            depth, close = 0, -1
            for i in range(star + 3, len(inner)):  # the `(` of the bound arguments, to its `)`
                depth += inner[i] == "("
                depth -= inner[i] == ")"
                if depth == 0:
                    close = i
                    break
            if close > 0:
                text = inner[:star] + "::?" + inner[close + 1 :]
    return text


def _detail(identity: _Identity, cb: int) -> str:
    """A callback with no symbol, by its kind and detail: `timer 500ms`, `subscription /chatter`, `service /add`."""
    if identity.kind == "timer":
        return f"timer {units.format_duration(identity.period_ns)}" if identity.period_ns else "timer"
    if identity.kind in ("subscription", "service") and identity.topic:
        return f"{identity.kind} {identity.topic}"
    return f"{identity.kind} 0x{cb:x}"


# ------------------------------------------------------------------ instances and chains


@dataclass
class _Instance:
    pid: int
    rec: CallbackRecord
    release_ns: int = 0  # the timer release it served (0: none known)
    missed: int = 0
    period_ns: int = 0
    origin_ns: int = 0  # the release a chain of messages reached it from (0: none)
    chain_from_ns: int = 0  # what its own publishes carry on: its origin, or its release (a timer callback)
    approximate: bool = False


@dataclass
class _Callback:
    program: str
    identity: _Identity
    cb: int
    instances: list[_Instance] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    grid: bool = False
    releases_due: int = 0
    open_at_end: list[tuple[int, int, int]] = field(default_factory=list)  # (pid, tid, since ns): instances still running at the end
    open_overruns: int = 0  # of them, those past their next release by the end


@dataclass
class _Publish:
    pid: int
    program: str
    rec: PublishRecord
    topic: str
    matched: bool = False


def _grid(cb: _Callback, end_ns: int) -> None:
    """A timer callback's release per instance, from the timer's first release and period (rcl's skip rule), and its releases due.

    Release k is first + k·period; an instance served the latest release at or before its start
    (rcl_timer_call steps the next call past the present by whole periods), or the one its record
    knew exactly; the releases between two served ones were skipped: missed.
    """
    ident = cb.identity
    period = ident.period_ns
    exact = [i.rec.release_ns for i in cb.instances if i.rec.release_ns]
    base = ident.first_ns or (min(exact) if exact else 0)
    if cb.identity.kind != "timer" or period <= 0 or not base:
        if cb.identity.kind == "timer":
            cb.notes.append(_no_grid(ident))
        return
    cb.grid = True
    last = -1
    off = 0
    for inst in cb.instances:
        r = inst.rec
        k = (r.release_ns - base + period // 2) // period if r.release_ns else max(0, (r.start_ns - base) // period)
        if k <= last:  # two callbacks in one period of the grid: the timer was reset, or its period changed
            off += 1
            inst.missed = 0
        else:
            inst.missed = k - last - 1
        last = max(last, k)
        inst.release_ns = r.release_ns or base + k * period
        inst.period_ns = period
        inst.chain_from_ns = inst.release_ns
    # Releases after the last callback are not counted as missed: no tracepoint says when a timer is cancelled (a
    # one-shot timer cancels itself in its callback), so the end of a timer's callbacks is the end of its releases.
    # Unless an instance was still running at the end: then its timer was not cancelled, it could not be served, and
    # every release to the end that no callback ended for is missed (and that instance overran, once past its next).
    cb.releases_due = last + 1
    due_to_end = (end_ns - base + period - 1) // period if end_ns > base else 0
    after = due_to_end - cb.releases_due
    if cb.open_at_end:
        cb.releases_due = max(cb.releases_due, due_to_end)
        cb.open_overruns = sum(1 for _, _, since in cb.open_at_end if end_ns > base + ((since - base) // period + 1) * period)
    elif after > 2:
        cb.notes.append(
            f"its last callback served its timer's release {last + 1:,}; the {after:,} releases after it to the end of the cell "
            "had no callback (the timer was cancelled, or its executor stopped serving it): not counted as missed"
        )
    if off:
        cb.notes.append(
            f"{off:,} callback{'s' if off != 1 else ''} ran twice within one period of the timer's grid (the timer was reset, "
            "or its period changed): their latency counts from the release before them"
        )


def _no_grid(ident: _Identity) -> str:
    if ident.clock is ClockType.ROS:
        return "a timer on ROS time with no release grid (simulated time, use_sim_time): no latency, missed releases or slack"
    if ident.timer_seen and ident.period_ns <= 0:
        return (
            "its timer's period is 0 (always ready: it runs at every turn of its executor): no release grid, "
            "so no latency, missed releases or slack"
        )
    if not ident.period_ns:
        return "its timer's period is unknown (rcl_timer_init was not seen): no latency, missed releases or slack"
    return "its timer's first release is unknown (the interposer could not ask rcl): no latency, missed releases or slack"


def _topic_of_publish(metas: _Metas, rec: PublishRecord) -> str:
    pub = metas.at(MetaKind.PUB, "a" if rec.handle_is_rcl else "c", rec.handle, rec.t_ns)
    return pub.s1 if pub is not None else ""


def _link(instances: list[_Instance], publishes: list[_Publish], take_topics: dict[int, str]) -> None:
    """Each take to the publish it came from, and each instance a chain reached to that chain's origin (notes-38 §4.3).

    In order of start: a publish happens inside an instance that started before the take's.
    `take_topics`: the topic of each instance's take (by id of the instance).
    """
    exact: dict[tuple[str, int], _Publish] = {}
    near: dict[str, list[_Publish]] = defaultdict(list)
    for p in publishes:
        if p.rec.exact:
            exact.setdefault((p.topic, p.rec.src_ts), p)
        else:
            near[p.topic].append(p)
    for group in near.values():
        group.sort(key=lambda p: p.rec.src_ts)
    stamps = {topic: [p.rec.src_ts for p in group] for topic, group in near.items()}
    by_instance = {(i.pid, i.rec.tid, i.rec.seq): i for i in instances}
    taken_by: dict[tuple[int, int], set[int]] = defaultdict(set)  # per subscription (process, rmw handle): the publishes it took
    for inst in sorted(instances, key=lambda i: i.rec.start_ns):
        topic = take_topics.get(id(inst), "")
        src = inst.rec.src_ts
        if not topic or not src:
            continue
        pub = exact.get((topic, src))
        approximate = False
        if pub is None and topic in near:
            taken = taken_by[(inst.pid, inst.rec.take_handle)]
            pub = _nearest(near[topic], stamps[topic], src, taken)
            if pub is not None:
                taken.add(id(pub))
            approximate = True
        if pub is None:
            continue
        pub.matched = True
        source = by_instance.get((pub.pid, pub.rec.tid, pub.rec.enclosing_seq)) if pub.rec.enclosing_seq >= 0 else None
        if source is not None and source.chain_from_ns:
            inst.origin_ns = source.chain_from_ns
            inst.chain_from_ns = source.chain_from_ns
            inst.approximate = approximate or source.approximate


def _nearest(publishes: list[_Publish], stamps: list[int], src: int, taken: set[int]) -> Optional[_Publish]:
    """The publish whose hook's clock is nearest a take's source timestamp, within APPROXIMATE_NS either side, of those
    the same subscription has not taken already (`taken`: their ids); None when none is.

    On Humble the middleware stamps a message itself, a few microseconds after the publish hook
    (cyclonedds' dds_write, Fast DDS' write), so the stamp is just after the hook's clock; a
    middleware (or a stand-in) that stamps before calling the hook puts it just before: either way
    the nearest publish of the topic is the message's, unless two publishes of one topic come
    closer together than that gap (then one subscription takes each once, nearest first).
    """
    lo, hi = bisect_right(stamps, src - APPROXIMATE_NS), bisect_right(stamps, src + APPROXIMATE_NS - 1)
    near = sorted(range(lo, hi), key=lambda k: (abs(src - stamps[k]), stamps[k]))
    return next((publishes[k] for k in near if id(publishes[k]) not in taken), None)


def _sample(inst: _Instance) -> Sample:
    r = inst.rec
    grid = inst.period_ns > 0
    return Sample(
        scheduled_ns=inst.release_ns if grid else r.start_ns,
        wake_ns=r.start_ns,
        end_ns=r.end_ns,
        burn_wall_ns=max(0, r.end_ns - r.start_ns),
        seq=r.seq,
        nivcsw=r.nivcsw,
        nvcsw=r.nvcsw,
        minflt=r.minflt,
        majflt=r.majflt,
        cpu_start=r.cpu_start,
        cpu_end=r.cpu_end,
        missed=inst.missed,
        origin_ns=inst.origin_ns,
        period_ns=inst.period_ns,
        next_ns=inst.release_ns + inst.period_ns if grid else 0,
    )


def _figures(cb: _Callback) -> tuple[ThreadFigures, ThreadHistograms]:
    """A callback's figures as a thread's over its instances, with message ages and chains."""
    samples = [_sample(i) for i in cb.instances]
    sums = tuple(sum(getattr(s, f) for s in samples) for f in ("nivcsw", "nvcsw", "minflt", "majflt"))
    slot = slot_of(samples, end_ru=(sums[0], sums[1], sums[2], sums[3]))
    figs = thread_figures(slot, cb.grid, cb.releases_due, None, released=not cb.grid)
    ages = [i.rec.age_ns for i in cb.instances if i.rec.src_ts and not i.rec.intra]
    age_hist = from_values(ages)
    chains = [c for c in (s.chain_ns() for s in samples) if c is not None]
    chain_hist = from_values(chains)
    update: dict[str, object] = {
        "message_age_ns": spread(age_hist, *_moments(ages)) if ages else None,
        "chain_ns": spread(chain_hist, *_moments(chains)) if chains else None,
    }
    if not cb.grid:  # no release said when it was due: no latency, slack, overruns or misses to speak of
        update.update(latency_ns=None, slack_ns=None, overruns=None, missed_consecutive_max=None, releases=0, missed_releases=0)
    if cb.grid and cb.open_overruns:
        update["overruns"] = (figs.overruns or 0) + cb.open_overruns
    figs = figs.model_copy(update=update)
    st = slot.stats
    hists = ThreadHistograms(
        latency=st.latency if cb.grid else None, slack=st.slack if cb.grid else None, callback_wall=st.wall, message_age=age_hist
    )
    return figs, hists


def _moments(values: list[int]) -> tuple[float, float, int]:
    n = len(values)
    mean = sum(values) / n
    return mean, sum((v - mean) ** 2 for v in values), n


def _instance_notes(cb: _Callback) -> list[str]:
    out = []
    unterminated = sum(1 for i in cb.instances if i.rec.unterminated)
    if unterminated:
        out.append(
            f"{unterminated:,} instance{'s' if unterminated != 1 else ''} never ended (no callback_end came: an outer callback's "
            "end or its thread's exit closed it): their duration runs to that"
        )
    intra = sum(1 for i in cb.instances if i.rec.intra)
    if intra:
        out.append(f"{intra:,} instance{'s' if intra != 1 else ''} took intra-process messages: no message age for those")
    negative = sum(1 for i in cb.instances if i.rec.src_ts and not i.rec.intra and i.rec.age_ns < 0)
    if negative:
        out.append(
            f"{negative:,} message{'s' if negative != 1 else ''} had a source timestamp after the callback's start "
            "(a publisher on another host with a clock ahead): their ages are below 0"
        )
    approximate = sum(1 for i in cb.instances if i.origin_ns and i.approximate)
    if approximate:
        out.append(
            f"{approximate:,} of its chain links matched a publish approximately (Humble: the middleware stamps the message "
            f"itself, apart from the publish hook; the nearest publish within {units.format_duration(APPROXIMATE_NS)})"
        )
    if cb.identity.truncated:
        out.append("a name, topic or symbol of it was cut short or dropped by the interposer (its string arena was full)")
    return out


# ------------------------------------------------------------------ the capture in words


def capture_words(capture: RosCapture) -> list[str]:
    """Why a program's capture holds no callback, and what it lost, in words (issue 38's cases)."""
    return _none_words(capture) + loss_words(capture)


def _none_words(capture: RosCapture) -> list[str]:
    """Why a program's capture holds no callback; [] when it holds some (or could not be read: loss_words says so)."""
    out = []
    callbacks = sum(len(p.callbacks) for p in capture.processes)
    metas = [m for p in capture.processes for m in p.metas]
    rclcpp = any("librclcpp" in lib for lib in capture.libraries)
    if not capture.processes and not capture.error:
        if capture.loaded is False:
            out.append(
                "no ROS 2 callbacks seen: the runner's library was not loaded into it (a statically linked or 32-bit program, "
                "or a setuid one, which ignores LD_PRELOAD)"
            )
        elif rclcpp:
            out.append(
                "no ROS 2 callbacks seen: it loaded librclcpp but reached no tracing hook (libtracetools absent, or every call "
                "compiled out with TRACETOOLS_DISABLED)"
            )
        elif capture.loaded:
            out.append("no ROS 2 callbacks seen: it loaded no ROS 2 library (not a ROS 2 program)")
        else:
            out.append("no ROS 2 callbacks seen: no process of it reached a tracing hook (not a ROS 2 program, or its hooks never ran)")
    elif capture.processes and not callbacks:
        if metas and not any(m.kind in _HEADER_KINDS for m in metas):
            out.append(
                "no ROS 2 callbacks seen: rcl reported its nodes but rclcpp's callback hooks never came: the program was built "
                "with TRACETOOLS_DISABLED: callbacks compiled out"
            )
        elif not any(p.flags & {ProcessFlag.SHADOWED} for p in capture.processes):
            out.append("no ROS 2 callbacks seen: its nodes ran no callback in the cell")
    return out


def loss_words(capture: RosCapture) -> list[str]:
    """What the capture could not see or keep, in words: the figures of the program's callbacks miss it (warnings of the cell)."""
    out = [f"the callbacks file could not be read: {capture.error}"] if capture.error else []
    for p in capture.processes:
        out += _process_words(p)
    if capture.processes_refused:
        out.append(
            f"{capture.processes_refused:,} process{'es' if capture.processes_refused != 1 else ''} of it found every process "
            "block of the callbacks file taken (or /dev/shm had no room for one): their callbacks were not recorded"
        )
    if capture.threads_refused:
        out.append(
            f"{capture.threads_refused:,} thread{'s' if capture.threads_refused != 1 else ''} of it found every thread slot "
            "taken (or /dev/shm had no room for its ring): their callbacks were not recorded"
        )
    return out


def _process_words(p: RosProcess) -> list[str]:
    out = []
    if ProcessFlag.SHADOWED in p.flags:
        by = p.shadowed_by or "another object"
        out.append(
            f"process {p.pid}: {by} defines ros_trace_callback_start ahead of the runner's library (SHADOWED): its callbacks were not seen"
        )
    if p.strings_dropped:
        out.append(
            f"process {p.pid}: {p.strings_dropped:,} names, topics or symbols did not fit in the interposer's string arena: "
            "callbacks without them are named by kind"
        )
    for t in p.threads:
        if t.lost:
            out.append(
                f"thread {t.comm} ({t.tid}): {t.lost:,} records were overwritten before the runner read them (its ring was full): "
                "the figures miss those callbacks"
            )
        if t.lost_other:
            out.append(
                f"thread {t.comm} ({t.tid}): {t.lost_other:,} records could not be written (callbacks nested too deep, or an end "
                "with no start)"
            )
    return out


# ------------------------------------------------------------------ the cell


@dataclass(frozen=True)
class ProgramCapture:
    """One program's capture, with the instant its callbacks stop counting (the cell's end, or its exit if earlier)."""

    name: str
    capture: RosCapture
    end_ns: int


def cell_callbacks(programs: Sequence[ProgramCapture], start_ns: int) -> tuple[list[CallbackResult], dict[str, RosCaptureInfo]]:
    """Every program's callbacks, named and measured, chains linked across the cell's processes, and what each capture said.

    `start_ns`: the cell's start gate (CLOCK_MONOTONIC), where the slowest instances' times count from.
    """
    callbacks: dict[tuple[str, int, int, int], _Callback] = {}
    publishes: list[_Publish] = []
    take_topics: dict[int, str] = {}
    open_words: dict[str, list[str]] = defaultdict(list)
    comms: dict[tuple[int, int], str] = {}
    for prog in programs:
        by_pid = {p.pid: p for p in prog.capture.processes}
        for p in prog.capture.processes:
            metas = _Metas(inherited(p, by_pid))
            comms.update({(p.pid, t.tid): t.comm for t in p.threads})
            for rec in p.callbacks:
                ident = resolve(metas, rec.cb, rec.start_ns)
                key = (p.pid, rec.cb, ident.registered.t_ns if ident.registered else -1)
                cb = callbacks.setdefault((prog.name, *key), _Callback(prog.name, ident, rec.cb))
                inst = _Instance(p.pid, rec)
                cb.instances.append(inst)
                if rec.take_handle:
                    sub = metas.at(MetaKind.SUB, "c", rec.take_handle, rec.start_ns)
                    take_topics[id(inst)] = sub.s1 if sub is not None else ident.topic
            publishes += [_Publish(p.pid, prog.name, r, _topic_of_publish(metas, r)) for r in p.publishes]
            for t in p.threads:
                if t.open_cb:
                    ident = resolve(metas, t.open_cb, t.open_since_ns)
                    key = (p.pid, t.open_cb, ident.registered.t_ns if ident.registered else -1)
                    callbacks.setdefault((prog.name, *key), _Callback(prog.name, ident, t.open_cb)).open_at_end.append(
                        (p.pid, t.tid, t.open_since_ns)
                    )
                    what = _name(ident, t.open_cb)
                    running = units.human_duration(max(0, prog.end_ns - t.open_since_ns))
                    open_words[prog.name].append(
                        f"callback {what} on thread {t.comm} ({t.tid}) was running for {running} at the end of the cell"
                    )
    ends = {prog.name: prog.end_ns for prog in programs}
    for cb in callbacks.values():
        cb.instances.sort(key=lambda i: i.rec.start_ns)
        _grid(cb, ends[cb.program])
    _link([i for cb in callbacks.values() for i in cb.instances], publishes, take_topics)
    results = _named([_result(cb, comms, start_ns) for cb in callbacks.values()])
    infos = {prog.name: _info(prog, [r for r in results if r.program == prog.name], publishes, open_words[prog.name]) for prog in programs}
    return results, infos


def _name(ident: _Identity, cb: int) -> str:
    detail = ident.symbol or _detail(ident, cb)
    return f"{ident.node}/{detail}" if ident.node else detail


def _result(cb: _Callback, comms: dict[tuple[int, int], str], start_ns: int) -> CallbackResult:
    figs, hists = _figures(cb)
    per_thread = Counter((i.pid, i.rec.tid) for i in cb.instances)
    slowest = sorted(cb.instances, key=lambda i: (i.rec.end_ns - i.rec.start_ns, i.rec.nivcsw), reverse=True)[:SLOWEST]
    ident = cb.identity
    return CallbackResult(
        program=cb.program,
        pids=sorted({i.pid for i in cb.instances} | {pid for pid, _, _ in cb.open_at_end}),
        node=ident.node,
        kind=ident.kind,
        symbol=ident.symbol,
        name=_name(ident, cb.cb),
        topic=ident.topic,
        period_ns=ident.period_ns or None,
        clock=ident.clock.name.lower() if ident.kind == "timer" else "",
        threads=[CallbackThread(tid=tid, comm=comms.get((pid, tid), ""), count=n) for (pid, tid), n in sorted(per_thread.items())],
        figures=figs,
        histograms=hists,
        notes=cb.notes + _instance_notes(cb),
        slowest=[
            CallbackInstance(
                at_ns=i.rec.start_ns - start_ns,
                wall_ns=max(0, i.rec.end_ns - i.rec.start_ns),
                tid=i.rec.tid,
                involuntary=i.rec.nivcsw,
                latency_ns=i.rec.start_ns - i.release_ns if i.period_ns else None,
            )
            for i in slowest
        ],
    )


def _named(results: list[CallbackResult]) -> list[CallbackResult]:
    """Callbacks in a stable order (program, name, first pid), two of one name in a program numbered ` #2`, ` #3`."""
    results.sort(key=lambda r: (r.program, r.name, r.pids))
    seen: Counter[tuple[str, str]] = Counter()
    out = []
    for r in results:
        seen[(r.program, r.name)] += 1
        n = seen[(r.program, r.name)]
        out.append(r if n == 1 else r.model_copy(update={"name": f"{r.name} #{n}"}))
    return out


def _info(prog: ProgramCapture, results: list[CallbackResult], publishes: list[_Publish], opened: list[str]) -> RosCaptureInfo:
    capture = prog.capture
    mine = [p for p in publishes if p.program == prog.name]
    unmatched: Counter[str] = Counter(p.topic or "an unknown topic" for p in mine if not p.matched)
    sent: Counter[str] = Counter(p.topic or "an unknown topic" for p in mine)
    notes = capture_words(capture) + opened
    notes += [
        f"{n:,} of {sent[topic]:,} messages it published on {topic} were taken by no callback of the cell (dropped, or nobody listened)"
        for topic, n in sorted(unmatched.items())
    ]
    return RosCaptureInfo(
        seen=bool(results),
        processes=len(capture.processes),
        callbacks=len(results),
        instances=sum(r.figures.callbacks for r in results),
        lost=sum(t.lost + t.lost_other for p in capture.processes for t in p.threads),
        publishes=len(mine),
        publishes_unmatched=sum(unmatched.values()),
        notes=notes,
    )


def matching(results: Sequence[CallbackResult], pattern: str) -> list[CallbackResult]:
    """The callbacks a `callback:` expectation names: its glob (fnmatch) on the name, or on `program: name`."""
    return [r for r in results if fnmatchcase(r.name, pattern) or fnmatchcase(callback_label(r.program, r.name), pattern)]


# ------------------------------------------------------------------ expectations

_GRID = frozenset({"latency_ns", "slack_ns", "missed_releases", "releases", "missed_consecutive_max", "overruns"})
"""Where the figures measured against a timer's release grid live: a callback without one has none of them (not 0)."""


def _absent(r: CallbackResult, fig: fg.Figure) -> str:
    """Why callback `r` has no value of `fig`, in words: what a verdict that could not be judged says."""
    if fig.path[0] in _GRID:
        if r.kind != "timer":
            return f"{fig.name} is measured against a timer's releases; this is a {r.kind} callback"
        return "its timer has no release grid: " + next((n for n in r.notes if "grid" in n or "unknown" in n), "unknown releases")
    if fig.scope is fg.Scope.ROS:
        return "it took no message from the middleware (a timer callback, or intra-process messages only)"
    if fig.path[0] == "chain_ns":
        return "no message of a timer callback of the cell reached it"
    return "no callbacks"


def judge(exp: Expectation, results: Sequence[CallbackResult], infos: dict[str, RosCaptureInfo]) -> list[Verdict]:
    """A `callback:` expectation on every callback its glob names; failed `not measured`, with words, when it names none
    (which callbacks were seen, or why none were) or when a callback cannot have the figure."""
    named = matching(results, exp.callback)
    fig = fg.figure(exp.metric.value)
    if not named:
        if results:
            seen = ", ".join(r.label for r in results[:8]) + (f" and {len(results) - 8} more" if len(results) > 8 else "")
            why = f"no callback of that name was seen; callbacks: {seen}"
        else:
            said = [n for info in infos.values() for n in info.notes]
            why = "no ROS 2 callback was seen" + (f": {said[0]}" if said else "")
        return [
            Verdict(
                thread=exp.target, metric=fig.name, limit=exp.describe_limit(), measured=None, passed=False, note=f"not measured ({why})"
            )
        ]
    out = []
    for r in named:
        grid = r.kind == "timer" and r.figures.releases > 0
        if fig.path[0] in _GRID and not grid:
            out.append(
                Verdict(
                    thread=r.label, metric=fig.name, limit=exp.describe_limit(), measured=None, passed=False,
                    note=f"not measured ({_absent(r, fig)})",
                )
            )  # fmt: skip
            continue
        out.append(check(exp, r.label, r.figures, _absent(r, fig)))
    return out
