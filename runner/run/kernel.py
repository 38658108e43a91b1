"""Read scheduling state back from the kernel: the oracle for everything the runner reports.

Settings come from sched_getscheduler / sched_getparam / getpriority /
sched_getaffinity on the thread id, and the thread table from
/proc/<pid>/task/<tid>/stat, the same sources procps uses.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import TYPE_CHECKING, Optional

from runner.printable import decode
from runner.results.pstable import CLS, ThreadRow

if TYPE_CHECKING:
    from runner.scenario.plan import Settings

RESET_ON_FORK = 0x40000000


def online_cpus() -> tuple[int, ...]:
    """CPUs this process may use (its affinity: cgroup cpusets and taskset included)."""
    return tuple(sorted(os.sched_getaffinity(0)))


def rt_limit() -> tuple[Optional[int], Optional[int]]:
    """(sched_rt_runtime_us, sched_rt_period_us): the share of each CPU real-time and deadline tasks may take; None if unreadable."""
    out: list[Optional[int]] = []
    for name in ("sched_rt_runtime_us", "sched_rt_period_us"):
        try:
            with open(f"/proc/sys/kernel/{name}") as handle:
                out.append(int(handle.read()))
        except (OSError, ValueError):
            out.append(None)
    return out[0], out[1]


def pid_width() -> int:
    """Digits of the largest PID, as procps sizes its PID columns."""
    try:
        with open("/proc/sys/kernel/pid_max") as handle:
            return len(str(int(handle.read()) - 1))
    except (OSError, ValueError):
        return 5


def thread_settings(tid: int, all_cpus: Optional[tuple[int, ...]] = None) -> Settings:
    """A thread's settings as the kernel holds them; cpus None when it may use every CPU in `all_cpus`."""
    from runner.scenario.model import Policy  # here: `runner ps` reads /proc without the scenario model's import
    from runner.scenario.plan import Settings

    policy = os.sched_getscheduler(tid) & ~RESET_ON_FORK
    priority = os.sched_getparam(tid).sched_priority
    nice = os.getpriority(os.PRIO_PROCESS, tid)
    cpus = tuple(sorted(os.sched_getaffinity(tid)))
    every = all_cpus if all_cpus is not None else online_cpus()
    runtime = deadline = period = 0
    if policy == Policy.DEADLINE.kernel_id:  # its parameters only sched_getattr(2) reports
        from runner.run import _probe  # here only: `runner ps` reads /proc without the native core

        _, _, _, _, runtime, deadline, period, _, _ = _probe.sched_getattr(tid)
    return Settings(Policy.from_kernel(policy), priority, nice, None if set(cpus) >= set(every) else cpus, runtime, deadline, period)


def current_settings() -> Settings:
    """The calling thread's settings: what processes the runner starts inherit."""
    return thread_settings(0)


def _read(path: str) -> str:
    """A /proc file as text; a name that is not UTF-8 (comm: any 15 bytes a process chose) is read with one U+FFFD per
    byte that is not, as ps shows one `?` for each (runner.printable)."""
    with open(path, "rb") as handle:
        return decode(handle.read())


def parse_stat(text: str) -> tuple[str, list[str]]:
    """Split a /proc stat line into comm and the fields after it (field 3 onwards)."""
    start, end = text.index("("), text.rindex(")")
    return text[start + 1 : end], text[end + 2 :].split()


def read_thread(pid: int, tid: int) -> Optional[ThreadRow]:
    """One thread's row, or None if it has exited."""
    base = f"/proc/{pid}/task/{tid}"
    try:
        comm, fields = parse_stat(_read(f"{base}/stat"))
        status = _read(f"{base}/status")
        cpus = tuple(sorted(os.sched_getaffinity(tid)))
    except (OSError, ValueError):
        return None
    # fields[0] is stat field 3 (state): field N is fields[N - 3]
    vol = invol = None
    for line in status.splitlines():
        if line.startswith("voluntary_ctxt_switches:"):
            vol = int(line.split()[1])
        elif line.startswith("nonvoluntary_ctxt_switches:"):
            invol = int(line.split()[1])
    return ThreadRow(
        pid=pid,
        tid=tid,
        comm=comm,
        policy=int(fields[41 - 3]),
        rtprio=int(fields[40 - 3]),
        nice=int(fields[19 - 3]),
        psr=int(fields[39 - 3]),
        prio=int(fields[18 - 3]),
        cpus=cpus,
        voluntary=vol,
        involuntary=invol,
    )


def thread_rows(pid: int) -> list[ThreadRow]:
    """Every thread of `pid`, in TID order (as ps lists them)."""
    try:
        tids = sorted(int(t) for t in os.listdir(f"/proc/{pid}/task"))
    except OSError:
        return []
    return [row for tid in tids if (row := read_thread(pid, tid)) is not None]


def find_pids(name: str) -> list[int]:
    """Live PIDs whose COMMAND (comm) is `name`, as `ps -C name` selects them; zombies are dead, so left out (not a
    process whose main thread alone has exited)."""
    out = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                if _read(f"/proc/{entry}/comm").rstrip("\n") == name and process_alive(int(entry)):
                    out.append(int(entry))
            except OSError:
                continue
    return sorted(out)


def process_state(pid: int) -> Optional[str]:
    """The process's state letter from /proc/<pid>/stat (R, S, D, T stopped, t traced, Z, ...); None once it is gone."""
    try:
        stat = _read(f"/proc/{pid}/stat")
    except OSError:
        return None
    return stat[stat.rfind(")") + 2 :][:1] or None


def process_alive(pid: int) -> bool:
    """Whether the process has a thread that lives: its main thread, or another once the main one has exited
    (pthread_exit in main leaves the leader a zombie while the other threads run on)."""
    state = process_state(pid)
    if state is None or state == "X":
        return False
    if state != "Z":
        return True
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return False
    for tid in tasks:
        try:
            if not _zombie(f"{pid}/task/{tid}"):
                return True
        except OSError:
            continue
    return False


def _zombie(pid: str) -> bool:
    stat = _read(f"/proc/{pid}/stat")
    return stat[stat.rfind(")") + 2 :][:1] in ("Z", "X")


@dataclass(frozen=True)
class Counters:
    """A thread's cumulative counters as the kernel keeps them: the figures of a thread the runner does not own."""

    voluntary: int
    involuntary: int
    minor_faults: int
    major_faults: int
    cpu_time_ns: int  # time on a CPU (schedstat), exact to the ns
    migrations: Optional[int]  # se.nr_migrations where the kernel exposes /proc/<tid>/sched (CONFIG_SCHED_DEBUG)
    cpu: int  # the CPU it last ran on

    def minus(self, base: Counters) -> Counters:
        """The counts since `base` (an earlier reading of the same thread).

        The kernel's counters of a thread only grow; one that fell belongs to another thread the
        TID now names (reused after the first exited): no count below 0 is made of it.
        """
        migrations = None if self.migrations is None or base.migrations is None else max(0, self.migrations - base.migrations)
        return Counters(
            max(0, self.voluntary - base.voluntary),
            max(0, self.involuntary - base.involuntary),
            max(0, self.minor_faults - base.minor_faults),
            max(0, self.major_faults - base.major_faults),
            max(0, self.cpu_time_ns - base.cpu_time_ns),
            migrations,
            self.cpu,
        )


ZERO = Counters(0, 0, 0, 0, 0, 0, -1)


def _sched_fields(text: str) -> dict[str, str]:
    out = {}
    for line in text.splitlines():
        key, sep, value = line.partition(":")
        if sep:
            out[key.strip()] = value.strip()
    return out


def thread_counters(pid: int, tid: int) -> Optional[Counters]:
    """One thread's counters from /proc/<pid>/task/<tid>/{stat,status,schedstat,sched}; None once it has exited."""
    base = f"/proc/{pid}/task/{tid}"
    try:
        _, fields = parse_stat(_read(f"{base}/stat"))
        status = _read(f"{base}/status")
        run_ns = int(_read(f"{base}/schedstat").split()[0])
    except (OSError, ValueError, IndexError):
        return None
    switches = {"voluntary_ctxt_switches": 0, "nonvoluntary_ctxt_switches": 0}
    for line in status.splitlines():
        key, _, value = line.partition(":")
        if key in switches:
            switches[key] = int(value)
    try:
        migrations: Optional[int] = int(_sched_fields(_read(f"{base}/sched")).get("se.nr_migrations", ""))
    except (OSError, ValueError):
        migrations = None
    return Counters(
        switches["voluntary_ctxt_switches"],
        switches["nonvoluntary_ctxt_switches"],
        int(fields[10 - 3]),
        int(fields[12 - 3]),
        run_ns,
        migrations,
        int(fields[39 - 3]),
    )


def thread_comm(pid: int, tid: int) -> Optional[str]:
    """A thread's name (comm); None once it has exited."""
    try:
        return _read(f"/proc/{pid}/task/{tid}/comm").rstrip("\n")
    except OSError:
        return None


def task_ids(pid: int) -> list[int]:
    """The TIDs of a process's threads; empty once it has exited."""
    try:
        return [int(t) for t in os.listdir(f"/proc/{pid}/task")]
    except OSError:
        return []


def task_of(tid: int) -> Optional[tuple[int, str]]:
    """(its process, its class as ps writes it) for a live task named by TID; None once it is gone."""
    try:
        status = _read(f"/proc/{tid}/status")
        policy = os.sched_getscheduler(tid) & ~RESET_ON_FORK
    except OSError:
        return None
    tgid = next((int(line.split()[1]) for line in status.splitlines() if line.startswith("Tgid:")), tid)
    return tgid, CLS.get(policy, "?")
