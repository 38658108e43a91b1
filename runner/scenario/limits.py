"""Limits a scenario must stay within: fixed ceilings, and the facts of the machine it would run on.

Two kinds of limit, kept apart so validation stays testable:

* Ceilings (`model.MAX_*`): bounds no real scenario comes near (a 1 h period, a 1 TiB size),
  checked by the model on every machine; `static_check` adds the one that spans a cell
  (its thread count).
* `MachineLimits`: what this machine allows (pid_max, threads-max, RLIMIT_MEMLOCK,
  MemAvailable, the CPUs the runner may use).  `MachineLimits.read()` does the /proc and
  resource I/O; `check()` is pure and takes the limits as an argument, so tests pass fake
  limits (a tiny pid_max) without touching the machine.  Its findings say they are *this
  machine's*: "on this machine (pid_max 32768)".

A file's validity does not depend on the machine: every finding of `check` is a warning of
`runner validate`, `--list` and `import-rtapp`.  What this machine cannot provide (a CPU, threads,
memory, SCHED_DEADLINE bandwidth: `elsewhere`) refuses a run here (exit 2, invalid here); what
this user may not do (RT priorities, negative nice, deadline, locked memory) and priority 99 (a
run option) are `right`s, which a run leaves to its preflight: tried on the kernel, refused with
how to grant them (exit 3; priority 99 without --allow-priority-99, exit 2).
"""

from __future__ import annotations

import os
import resource
from dataclasses import dataclass, field

from runner import units
from runner.scenario.model import HogKind, PeriodicWork, Phase, PhasesWork, Policy, ProcessSpec, ProgramSpec, Scenario, Sched, Work
from runner.scenario.program import admitted_words, asked_words, deadline_asks

Path = tuple[str | int, ...]

MAX_THREADS = 1 << 17  # threads of one cell, hogs included: far above any scenario, below the kernel maximum
RUNNER_THREADS = 8  # the runner's own threads and helpers, counted so a cell at the limit still starts

MEMLOCK_BASE = 64 << 20  # what mlockall pins of a worker beyond prealloc and stacks: the interpreter, its libraries (under 33 MiB measured)
WATCHDOG_PRIORITY = 99  # the runner watchdog's RT priority: refused to scenario threads unless --allow-priority-99

CAP_IPC_LOCK = 14
CAP_SYS_NICE = 23
_CAP_SYS_ADMIN = 21
_CAP_SYS_RESOURCE = 24


@dataclass(frozen=True)
class MachineLimits:
    """What this machine lets a cell use; None where a limit is absent (unlimited) or cannot be read."""

    pid_max: int | None = None  # /proc/sys/kernel/pid_max: thread ids are pids
    threads_max: int | None = None  # /proc/sys/kernel/threads-max: threads system-wide
    threads_running: int = 0  # threads that exist already (/proc/loadavg), they share both limits
    cgroup_pids_max: int | None = None  # pids.max of the runner's cgroup (containers)
    nproc: int | None = None  # RLIMIT_NPROC soft limit; None: unlimited or not enforced (root)
    memlock: int | None = None  # RLIMIT_MEMLOCK soft limit in bytes; None: unlimited or CAP_IPC_LOCK
    cap_ipc_lock: bool = False
    rtprio: int | None = None  # RLIMIT_RTPRIO soft limit; None: unlimited, or CAP_SYS_NICE (any RT priority, deadline, nice)
    nice_limit: int | None = None  # RLIMIT_NICE soft limit (a nice down to 20 - it); None: unlimited, or CAP_SYS_NICE
    cap_sys_nice: bool = True  # False: SCHED_DEADLINE is refused (no limit grants it)
    mem_available: int | None = None  # MemAvailable from /proc/meminfo, bytes
    default_stack: int = 8 << 20  # default thread stack (glibc takes RLIMIT_STACK, 2 MiB if unlimited)
    cpus: tuple[int, ...] | None = None  # CPUs the runner may use (its affinity)
    online: tuple[int, ...] | None = None  # CPUs this machine has online (/sys/devices/system/cpu/online)
    rt_runtime_us: int | None = None  # sched_rt_runtime_us: with the period, what SCHED_DEADLINE may take per CPU (-1: no limit)
    rt_period_us: int | None = None  # sched_rt_period_us

    @classmethod
    def read(cls) -> MachineLimits:
        """Read the limits of this machine and this process (/proc, getrlimit, affinity)."""
        caps = _capabilities()
        root_like = os.geteuid() == 0 or bool(caps >> _CAP_SYS_ADMIN & 1) or bool(caps >> _CAP_SYS_RESOURCE & 1)
        ipc_lock = bool(caps >> CAP_IPC_LOCK & 1)
        sys_nice = bool(caps >> CAP_SYS_NICE & 1)
        nice_limit = _rlimit(resource.RLIMIT_NICE)
        loadavg = _read("/proc/loadavg").split()
        running = loadavg[3].partition("/")[2] if len(loadavg) > 3 else ""
        try:
            cpus: tuple[int, ...] | None = tuple(sorted(os.sched_getaffinity(0)))
        except OSError:
            cpus = None
        try:
            online: tuple[int, ...] | None = units.parse_cpus(_read("/sys/devices/system/cpu/online"))
        except units.UnitError:
            online = None
        return cls(
            pid_max=_read_int("/proc/sys/kernel/pid_max"),
            threads_max=_read_int("/proc/sys/kernel/threads-max"),
            threads_running=int(running) if running.isdigit() else 0,
            cgroup_pids_max=_cgroup_pids_max(),
            nproc=None if root_like else _rlimit(resource.RLIMIT_NPROC),
            memlock=None if ipc_lock else _rlimit(resource.RLIMIT_MEMLOCK),
            cap_ipc_lock=ipc_lock,
            rtprio=None if sys_nice else _rlimit(resource.RLIMIT_RTPRIO),
            nice_limit=None if sys_nice else nice_limit,
            cap_sys_nice=sys_nice,
            mem_available=_meminfo("MemAvailable"),
            default_stack=cls.read_stack(),
            cpus=cpus,
            online=online,
            rt_runtime_us=_read_int("/proc/sys/kernel/sched_rt_runtime_us"),
            rt_period_us=_read_int("/proc/sys/kernel/sched_rt_period_us"),
        )

    @staticmethod
    def read_stack() -> int:
        """The default thread stack: RLIMIT_STACK, as glibc takes it, or 2 MiB when unlimited."""
        stack = _rlimit(resource.RLIMIT_STACK)
        return stack if stack is not None and stack > 0 else 2 << 20


@dataclass(frozen=True)
class Finding:
    """A limit a cell goes past: where in the scenario, and what to do about it."""

    path: Path
    message: str
    elsewhere: bool = False  # what this machine cannot provide: a warning of validate, --list and imports; a run here exits 2
    right: bool = False  # what this user may not do (or priority 99): a warning of validate, --list and imports; a run's preflight decides


@dataclass
class _Tally:
    """Threads and memory a cell needs, counted once."""

    threads: int = 0
    resident: int = 0
    parts: list[str] = field(default_factory=list)


def cell_threads(scenario: Scenario) -> int:
    """Threads a cell creates: every instance's main thread and threads, and the hogs."""
    total = sum(proc.instances * (1 + sum(t.count for t in proc.threads)) for proc in scenario.workers)
    for hog in scenario.background.hogs:
        total += hog.count if hog.kind is HogKind.PROCESS else 1 + hog.count
    return total + len(scenario.background.commands) + len(scenario.programs)


def locked_bytes(proc: ProcessSpec, default_stack: int) -> int:
    """What mlockall(MCL_CURRENT|MCL_FUTURE) pins in one instance: the preallocated heap and every thread stack."""
    stack = proc.memory.stack_size if proc.memory.stack_size is not None else default_stack
    return proc.memory.prealloc + stack * sum(t.count for t in proc.threads)


def resident_bytes(proc: ProcessSpec, default_stack: int) -> int:
    """Memory one instance keeps resident at its peak: locked memory, or prealloc, plus every callback's alloc
    and every program's buffer and largest alloc (threads a spawn event creates counted at their full count)."""
    held = locked_bytes(proc, default_stack) if proc.memory.lock else proc.memory.prealloc
    works = [(proc.main.work, 1)] + [(t.work, t.count) for t in proc.threads]
    return held + sum(_work_bytes(work) * n for work, n in works)


def _work_bytes(work: object) -> int:
    if isinstance(work, PeriodicWork):
        return work.alloc
    return work.resident_bytes() if isinstance(work, PhasesWork) else 0


def memlock_needed(proc: ProcessSpec, default_stack: int) -> int:
    """RLIMIT_MEMLOCK a locking process needs: what mlockall pins of it (`locked_bytes`) and of the interpreter (MEMLOCK_BASE)."""
    return MEMLOCK_BASE + locked_bytes(proc, default_stack)


def static_check(scenario: Scenario) -> list[Finding]:
    """Ceilings that hold on every machine (no limits needed): the thread count of a cell."""
    threads = cell_threads(scenario)
    if threads > MAX_THREADS:
        return [
            Finding(
                ("processes",),
                f"the cell creates {threads} threads (instances x threads, and hogs); at most {MAX_THREADS} threads in a cell",
            )
        ]
    return []


def check(scenario: Scenario, limits: MachineLimits) -> list[Finding]:
    """Everything in one cell that this machine cannot provide; pure, the limits are given."""
    out = static_check(scenario) or _check_threads(scenario, limits)  # a cell past the ceiling is too large on any machine
    out.extend(_check_memory(scenario, limits))
    out.extend(_check_cpus(scenario, limits))
    out.extend(_check_deadline(scenario, limits))
    out.extend(_check_rights(scenario, limits))
    return out


def written_scheds(scenario: Scenario) -> list[tuple[Path, Sched, str]]:
    """Every `sched` the file writes, where, and whose it is: processes' threads and their phases, programs and
    their rules, hogs.  (A spec with priospread asks its written priority of its first thread, less of the others.)"""
    found: list[tuple[Path, Sched | None, str]] = []
    for i, proc in enumerate(scenario.processes):
        if isinstance(proc, ProgramSpec):
            found.append((("processes", i, "sched"), proc.sched, f"program {proc.name}"))
            found += [
                (("processes", i, "threads", j, "sched"), r.sched, f"program {proc.name} rule {r.match!r}")
                for j, r in enumerate(proc.threads)
            ]
            continue
        for at, sched, work, who in _owners(i, proc):
            found.append((at + ("sched",), sched, who))
            if isinstance(work, PhasesWork):
                found += [(at + ("work", "phases", k, "sched"), ph.sched, f"{who} phase {name}") for k, (name, ph) in _phases(work)]
    found += [
        (("background", "hogs", h, "sched"), hog.sched, f"background hog {hog.name}") for h, hog in enumerate(scenario.background.hogs)
    ]
    return [(path, sched, who) for path, sched, who in found if sched is not None]


def _owners(i: int, proc: ProcessSpec) -> list[tuple[Path, Sched | None, Work, str]]:
    """The main thread and the thread specs of process `i`: where each is written, its sched, its work, its name."""
    out: list[tuple[Path, Sched | None, Work, str]] = [
        (("processes", i, "main"), proc.main.sched, proc.main.work, f"{proc.name}/{proc.main_name}")
    ]
    return out + [(("processes", i, "threads", j), t.sched, t.work, f"{proc.name}/{t.name}") for j, t in enumerate(proc.threads)]


def _phases(work: PhasesWork) -> list[tuple[int, tuple[str, Phase]]]:
    return list(enumerate(zip(work.phase_names(), work.phases)))


def _check_rights(scenario: Scenario, limits: MachineLimits) -> list[Finding]:
    """What this user may not set (RLIMIT_RTPRIO, RLIMIT_NICE, CAP_SYS_NICE), and priority 99, which a run refuses unless
    --allow-priority-99: warnings of validate, --list and imports, each where it is written; a run's preflight decides."""
    out = []
    refused = "a run here is refused (exit 3) unless this user gets the right (README, Permissions) or --allow-degraded"
    for path, sched, who in written_scheds(scenario):
        if sched.policy.is_realtime and sched.rt_priority >= WATCHDOG_PRIORITY:
            why = (
                f"{who} asks for RT priority 99, the runner watchdog's own; a run refuses it unless --allow-priority-99 "
                "(the runner may then be unable to stop a runaway thread); use 98 or less"
            )
            out.append(Finding(path, why, right=True))
        if sched.policy.is_realtime and limits.rtprio is not None and sched.rt_priority > limits.rtprio:
            what = f"{who} asks for {sched.label()}, but on this machine this user has RLIMIT_RTPRIO {limits.rtprio} and no CAP_SYS_NICE"
            out.append(Finding(path, f"{what}; {refused}", right=True))
        elif sched.policy is Policy.DEADLINE and not limits.cap_sys_nice:
            what = f"{who} asks for SCHED_DEADLINE, which needs CAP_SYS_NICE (no limit grants it), and this user has not it"
            out.append(Finding(path, f"{what}; {refused}", right=True))
        elif sched.nice is not None and sched.nice < 0 and limits.nice_limit is not None and 20 - sched.nice > limits.nice_limit:
            what = (
                f"{who} asks for nice {sched.nice}, which needs CAP_SYS_NICE or RLIMIT_NICE {20 - sched.nice}, but on this machine "
                f"this user has RLIMIT_NICE {limits.nice_limit} and no CAP_SYS_NICE"
            )
            out.append(Finding(path, f"{what}; {refused}", right=True))
    return out


def _check_deadline(scenario: Scenario, limits: MachineLimits) -> list[Finding]:
    """SCHED_DEADLINE bandwidth past what the kernel admits on this machine: it would refuse the policy (EBUSY) at the start.

    The kernel admits runtime/period summed over a root domain's deadline threads up to
    sched_rt_runtime_us/sched_rt_period_us per CPU (0.95 by default); the root domain is the
    online CPUs unless exclusive cpusets split them, and other deadline tasks take their share.
    """
    if not limits.online or limits.rt_runtime_us is None or limits.rt_runtime_us < 0 or not limits.rt_period_us:
        return []
    asks = deadline_asks(scenario)
    room = limits.rt_runtime_us / limits.rt_period_us * len(limits.online)
    if sum(b for _, b in asks) <= room + 1e-9:
        return []
    return [
        Finding(
            ("processes",),
            f"the cell's SCHED_DEADLINE threads ask {asked_words(asks)}, but this machine admits "
            f"{admitted_words(limits.rt_runtime_us, limits.rt_period_us, len(limits.online))}; "
            "the kernel would refuse the policy (EBUSY): lower runtime or count",
            elsewhere=True,
        )
    ]


def _check_threads(scenario: Scenario, limits: MachineLimits) -> list[Finding]:
    needed = cell_threads(scenario) + RUNNER_THREADS
    bounds: list[tuple[int, str]] = []
    if limits.pid_max is not None:
        bounds.append((limits.pid_max - limits.threads_running, f"pid_max {limits.pid_max}"))
    if limits.threads_max is not None:
        bounds.append((limits.threads_max - limits.threads_running, f"threads-max {limits.threads_max}"))
    if limits.cgroup_pids_max is not None:
        bounds.append((limits.cgroup_pids_max - limits.threads_running, f"cgroup pids.max {limits.cgroup_pids_max}"))
    if limits.nproc is not None:
        bounds.append((limits.nproc - limits.threads_running, f"RLIMIT_NPROC {limits.nproc}"))
    if not bounds:
        return []
    room, named = min(bounds)
    if needed <= room:
        return []
    return [
        Finding(
            ("processes",),
            (
                f"the cell needs {needed} threads (instances x threads, hogs and the runner's own {RUNNER_THREADS}), "
                f"but on this machine ({named}, {limits.threads_running} threads running) at most {max(room, 0)} can start; "
                "lower count or instances"
            ),
            elsewhere=True,
        )
    ]


def _check_memory(scenario: Scenario, limits: MachineLimits) -> list[Finding]:
    out: list[Finding] = []
    for i, proc in enumerate(scenario.processes):
        if not isinstance(proc, ProcessSpec) or not proc.memory.lock or limits.memlock is None:
            continue
        needed = memlock_needed(proc, limits.default_stack)
        if needed > limits.memlock:
            out.append(
                Finding(
                    ("processes", i, "memory"),
                    (
                        f"{memlock_words(proc, limits.default_stack)}, but on this machine RLIMIT_MEMLOCK is "
                        f"{approx_size(limits.memlock)} and this user has no CAP_IPC_LOCK; a run here is refused (exit 3) "
                        "unless it gets the right ('ulimit -l unlimited', 'memlock unlimited' in /etc/security/limits.d/, "
                        "README, Permissions) or --allow-degraded"
                    ),
                    right=True,
                )
            )
    if limits.mem_available is not None:
        total = sum(proc.instances * resident_bytes(proc, limits.default_stack) for proc in scenario.workers)
        if total > limits.mem_available:
            out.append(
                Finding(
                    ("processes",),
                    (
                        f"the cell keeps {approx_size(total)} resident (prealloc, locked stacks, per-callback alloc, and "
                        "programs' mem buffers and allocs, times instances and counts), but on this machine MemAvailable is "
                        f"{approx_size(limits.mem_available)}; lower prealloc, alloc, mem, count or instances"
                    ),
                    elsewhere=True,
                )
            )
    return out


def memlock_words(proc: ProcessSpec, default_stack: int) -> str:
    """`process app locks its memory: prealloc 128MiB and 6 thread stacks pin about 240MiB with the interpreter`."""
    stacks = sum(t.count for t in proc.threads)
    what = f"prealloc {units.format_size(proc.memory.prealloc)}" + (f" and {stacks} thread stacks" if stacks else "")
    return f"process {proc.name} locks its memory: {what} pin about {approx_size(memlock_needed(proc, default_stack))} with the interpreter"


def _check_cpus(scenario: Scenario, limits: MachineLimits) -> list[Finding]:
    if limits.cpus is None:
        return []
    allowed = set(limits.cpus)
    out: list[Finding] = []
    wanted: list[tuple[Path, tuple[int, ...] | None]] = []
    for i, proc in enumerate(scenario.processes):
        if isinstance(proc, ProgramSpec):
            wanted.append((("processes", i, "cpus"), proc.cpus))
            wanted.extend((("processes", i, "threads", j, "cpus"), r.cpus) for j, r in enumerate(proc.threads))
            continue
        cpus_of = [proc.main.cpus] + [t.cpus for t in proc.threads]
        for (at, _, work, _), cpus in zip(_owners(i, proc), cpus_of):
            wanted.append((at + ("cpus",), cpus))
            if isinstance(work, PhasesWork):
                wanted.extend((at + ("work", "phases", k, "cpus"), ph.cpus) for k, (_, ph) in _phases(work))
    wanted.extend((("background", "hogs", h, "cpus"), hog.cpus) for h, hog in enumerate(scenario.background.hogs))
    online = set(limits.online) if limits.online else None
    for path, cpus in wanted:
        if cpus is None or set(cpus) <= allowed:
            continue
        absent = sorted(set(cpus) - online) if online is not None else []
        outside = sorted(set(cpus) - allowed)
        if absent:
            noun = f"CPU {absent[0]} does" if len(absent) == 1 else f"CPUs {units.format_cpus(absent)} do"
            text = f"{noun} not exist on this machine (CPUs {units.format_cpus(sorted(online or ()))})"
        elif online is not None:
            noun = f"CPU {outside[0]} is" if len(outside) == 1 else f"CPUs {units.format_cpus(outside)} are"
            text = f"{noun} outside the CPUs the runner may use ({units.format_cpus(limits.cpus)}: it runs under taskset or in a cpuset)"
        else:  # which CPUs are online is not known: say what the runner may use
            noun = f"CPU {outside[0]} is" if len(outside) == 1 else f"CPUs {units.format_cpus(outside)} are"
            text = f"{noun} not available on this machine (the runner may use {units.format_cpus(limits.cpus)})"
        out.append(Finding(path, text, elsewhere=True))
    return out


def approx_size(nbytes: int) -> str:
    """A size for a message: exact when it is a whole unit (`8MiB`), else to a tenth (`23.1GiB`)."""
    exact = units.format_size(nbytes)
    if len(exact) <= 8:
        return exact
    for unit in ("TiB", "GiB", "MiB", "KiB"):
        if nbytes >= units.BYTES_PER[unit]:
            return f"{nbytes / units.BYTES_PER[unit]:.1f}{unit}"
    return exact


# ------------------------------------------------------------------------------------- I/O


def _read(path: str) -> str:
    try:
        with open(path, encoding="ascii", errors="replace") as handle:
            return handle.read(65536)
    except OSError:
        return ""


def _read_int(path: str) -> int | None:
    text = _read(path).strip()
    return int(text) if text.isdigit() else None


def _rlimit(which: int) -> int | None:
    try:
        soft = resource.getrlimit(which)[0]
    except (OSError, ValueError):
        return None
    return None if soft == resource.RLIM_INFINITY else soft


def _capabilities() -> int:
    for line in _read("/proc/self/status").splitlines():
        if line.startswith("CapEff:"):
            try:
                return int(line.split()[1], 16)
            except (IndexError, ValueError):
                return 0
    return 0


def _meminfo(key: str) -> int | None:
    for line in _read("/proc/meminfo").splitlines():
        name, _, rest = line.partition(":")
        if name == key:
            number = rest.split()[0] if rest.split() else ""
            return int(number) * 1024 if number.isdigit() else None
    return None


def _cgroup_pids_max() -> int | None:
    """pids.max of this process's cgroup (v2, or the v1 pids controller); None when unlimited or absent."""
    for line in _read("/proc/self/cgroup").splitlines():
        parts = line.split(":", 2)
        if len(parts) != 3:
            continue
        hierarchy, controllers, where = parts
        if hierarchy == "0" and controllers == "":
            candidate = os.path.join("/sys/fs/cgroup", where.lstrip("/"), "pids.max")
        elif "pids" in controllers.split(","):
            candidate = os.path.join("/sys/fs/cgroup/pids", where.lstrip("/"), "pids.max")
        else:
            continue
        value = _read_int(candidate)
        if value is not None:
            return value
    return None
