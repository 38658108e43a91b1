"""Permission checks before anything starts: fail with how to grant the right, or note what degrades.

The kernel is asked, not guessed at: each RT policy or negative nice a cell needs
is tried on a throwaway thread of the runner, memory locking is checked against
CAP_IPC_LOCK and RLIMIT_MEMLOCK, and uclamp against the kernel's own knob for it.
"""

from __future__ import annotations

import dataclasses
import os
import pwd
import resource
import sys
import threading
from dataclasses import dataclass, field

from runner import units
from runner.errors import PermissionProblem, UsageError
from runner.results.document import PermissionsInfo
from runner.run import memcg
from runner.scenario.limits import WATCHDOG_PRIORITY, MachineLimits, memlock_needed, memlock_words
from runner.scenario.model import PhasesWork, Policy, Scenario, ThreadRule
from runner.scenario.plan import Settings, phase_settings, plan_scenario, program_settings, rule_settings

CAP_IPC_LOCK = 14
CAP_SYS_NICE = 23
UCLAMP_KNOB = "/proc/sys/kernel/sched_util_clamp_min"  # present exactly when the kernel has uclamp (CONFIG_UCLAMP_TASK)


@dataclass
class Permissions:
    """What this user may do, as found; recorded in results and reports."""

    user: str
    uid: int
    cap_sys_nice: bool
    cap_ipc_lock: bool
    rlimit_rtprio: int
    rlimit_memlock: int  # bytes; -1 unlimited
    missing: list[str] = field(default_factory=list)

    def record(self) -> PermissionsInfo:
        """As the results file stores it."""
        return PermissionsInfo(**dataclasses.asdict(self))


def _caps() -> int:
    try:
        with open("/proc/self/status") as handle:
            for line in handle:
                if line.startswith("CapEff:"):
                    return int(line.split()[1], 16)
    except OSError:
        pass
    return 0


def _limit(which: int) -> int:
    soft = resource.getrlimit(which)[0]
    return -1 if soft == resource.RLIM_INFINITY else soft


def current_permissions() -> Permissions:
    caps = _caps()
    uid = os.geteuid()
    try:
        user = pwd.getpwuid(uid).pw_name
    except KeyError:
        user = str(uid)
    return Permissions(
        user,
        uid,
        bool(caps >> CAP_SYS_NICE & 1),
        bool(caps >> CAP_IPC_LOCK & 1),
        _limit(resource.RLIMIT_RTPRIO),
        _limit(resource.RLIMIT_MEMLOCK),
    )


def _try_on_thread(action) -> int:  # type: ignore[no-untyped-def]
    """Run `action` on a throwaway thread; return the errno it failed with, 0 if it worked."""
    result = [0]

    def body() -> None:
        try:
            action()
        except OSError as exc:
            result[0] = exc.errno or 1

    thread = threading.Thread(target=body, name="runner-preflight")
    thread.start()
    thread.join()
    return result[0]


def runner_command(executable: str, prefix: str, base_prefix: str) -> str:
    """How to start this runner again as root: `sudo /srv/runner/.venv/bin/runner` from a virtual environment,
    whose bin folder is not on sudo's PATH (its secure_path), else `sudo runner`."""
    if prefix != base_prefix:
        return f"sudo {os.path.join(os.path.dirname(executable), 'runner')}"
    return "sudo runner"


def how_to_grant(user: str, limit: str, value: str, service: str, container: str, sudo: str) -> str:
    """The ways to grant one right, where a user meets it: a login session (limits.d, read by pam_limits at login),
    a systemd service (which pam_limits never sees), a container.  README, "Permissions", says more.

    File capabilities on the interpreter are left out on purpose: `setcap` on a shared python3 would give the right
    to every script it runs.
    """
    return (
        f"grant it with one of: run as root ({sudo} ...); add the line '{user}  -  {limit}  {value}' to a file in "
        f"/etc/security/limits.d/ and log in again; in a systemd service, {service}; in a container, {container} "
        "(README, Permissions)"
    )


def root_advice(cap: str, has_cap: bool, service: str, container: str, refused_anyway: str, limit: str = "", value: str = "") -> str:
    """What to say to a user who is root (euid 0) already: sudo would change nothing, so it is not offered.

    Root without `cap` is what a container gives by default (Docker and Podman grant neither
    CAP_SYS_NICE nor CAP_IPC_LOCK) or what a service's bounding set leaves: the capability is
    what is missing, or root's own resource limit (`limit`, raised to `value`), which binds it
    as any user once the capability is gone.  Root with it and still refused is something else
    (`refused_anyway`: the RT budget of its cgroup, a security policy).
    """
    if not has_cap:
        rlimit = f"add the line 'root  -  {limit}  {value}' to a file in /etc/security/limits.d/ and log in again; " if limit else ""
        return (
            f"this user is root but lacks {cap} (as in a container that does not grant it), so sudo would change nothing; "
            f"grant it, or raise root's own limit, with one of: {rlimit}in a container, {container}; in a systemd service, "
            f"{service} or AmbientCapabilities={cap} (README, Permissions)"
        )
    return f"this user is root and has {cap}, so sudo would change nothing; {refused_anyway} (README, Permissions)"


_REFUSED_ANYWAY = "a security policy (seccomp, SELinux, AppArmor) may be refusing it"


def _sudo() -> str:
    return runner_command(sys.executable, sys.prefix, sys.base_prefix)


def _grant(perm: Permissions, cap: str, limit: str, value: str, service: str, container: str, refused_anyway: str = _REFUSED_ANYWAY) -> str:
    """How to grant one right to this user: the ways for a user, or for root (who needs no sudo) what is missing."""
    if perm.uid == 0:
        has_cap = perm.cap_sys_nice if cap == "CAP_SYS_NICE" else perm.cap_ipc_lock
        return root_advice(cap, has_cap, service, container, refused_anyway, limit, value)
    return how_to_grant(perm.user, limit, value, service, container, _sudo())


def _grant_rt(perm: Permissions, priority: int) -> str:
    value = str(max(priority, 98))
    return _grant(
        perm,
        "CAP_SYS_NICE",
        "rtprio",
        value,
        f"LimitRTPRIO={value}",
        f"--cap-add SYS_NICE --ulimit rtprio={value}",
        "the RT budget of the runner's cgroup may be 0 (a kernel with CONFIG_RT_GROUP_SCHED: cpu.rt_runtime_us; "
        "docker run --cpu-rt-runtime=950000)",
    )


def _refuse_priority_99(where: str, settings: Settings, allowed: bool, start: Settings) -> None:
    """Priority 99 is the watchdog's (and the kernel's own per-CPU threads'): a thread at it could starve them.

    Asked for, or inherited from the runner (`chrt -f 99 runner`, a service's CPUSchedulingPriority=99):
    hogs and background commands without a sched of their own would then spin at the watchdog's priority.
    """
    if allowed or not (settings.policy.is_realtime and settings.priority >= WATCHDOG_PRIORITY):
        return
    if start.policy is settings.policy and start.priority >= WATCHDOG_PRIORITY:
        raise UsageError(
            f"{where} inherits RT priority 99, the runner watchdog's own, from the runner, which runs at "
            f"SCHED_{start.policy.value.upper()} 99 (chrt, or a service's CPUSchedulingPriority=); start the runner at 98 or "
            "less (it needs no RT priority itself), give it a sched of its own, or pass --allow-priority-99 "
            "(the runner may then be unable to stop a runaway thread)"
        )
    raise UsageError(
        f"{where} asks for RT priority 99, the runner watchdog's own; use 98 or less, "
        "or pass --allow-priority-99 (the runner may then be unable to stop a runaway thread)"
    )


@dataclass
class Needs:
    """The rights a run's cells need beyond what the runner's own settings give: found without trying anything."""

    rt: dict[tuple[Policy, int], str] = field(default_factory=dict)  # (policy, priority) -> the first thread asking
    min_nice: tuple[int, str] | None = None  # the lowest nice asked for, and by whom
    lock: tuple[int, str] | None = None  # the RLIMIT_MEMLOCK the locking processes need (the most any one needs), and its words
    uclamp: str | None = None  # a thread that asks for util_min / util_max
    memory_max: str | None = None  # a program with a memory limit


def needs(scenarios: list[Scenario], start: Settings, allow_priority_99: bool, online: set[int]) -> Needs:
    """What the cells ask for that needs a right; refuses (exit 2) priority 99 and CPUs this machine does not allow."""
    out = Needs()
    for sc in scenarios:
        asked = []
        for t in plan_scenario(sc, start):
            asked.append((f"{t.process}/{t.name}", t.settings))
            if isinstance(t.work, PhasesWork):  # each phase applies its own settings as the thread enters it
                named = zip(t.work.phase_names(), phase_settings(t.work, t.settings))
                asked += [(f"{t.process}/{t.name} phase {name}", settings) for name, settings in named if settings is not None]
        for prog in sc.programs:
            asked.append((f"program {prog.name}", program_settings(prog, start)[0]))
            asked += [(f"program {prog.name} rule {rule.match!r}", rule_settings(prog, rule, start)) for rule in prog.threads]
        # the load inherits the runner's settings unless it has its own: at FIFO 99 it would spin at the watchdog's priority
        asked += [(f"background hog {h.name}", start.with_sched(h.sched, h.cpus)) for h in sc.background.hogs]
        asked += [(f"background command {c.name or c.argv[0]}", start) for c in sc.background.commands]
        for where, settings in asked:
            _refuse_priority_99(where, settings, allow_priority_99, start)
            _refuse_cpus(where, settings.cpus, online)
            if settings.policy.is_realtime and (settings.policy != start.policy or settings.priority > start.priority):
                out.rt.setdefault((settings.policy, settings.priority), where)
            if settings.nice < start.nice and (out.min_nice is None or settings.nice < out.min_nice[0]):
                out.min_nice = (settings.nice, where)
        stack = MachineLimits.read_stack()
        for proc in sc.workers:
            needed = memlock_needed(proc, stack) if proc.memory.lock else 0
            if needed and (out.lock is None or needed > out.lock[0]):
                out.lock = (needed, memlock_words(proc, stack))
        out.uclamp = out.uclamp or _asks_uclamp(sc)
        out.memory_max = out.memory_max or next((f"program {prog.name}" for prog in sc.programs if prog.memory_max is not None), None)
    return out


def check_rules(rules: list[ThreadRule], allow_priority_99: bool, online: set[int]) -> None:
    """`runner watch --rule`: refused (exit 2) as a scenario's rules are, priority 99 and CPUs this machine does not allow."""
    for rule in rules:
        where = f"--rule {rule.match!r}"
        _refuse_priority_99(where, Settings().with_sched(rule.sched, rule.cpus), allow_priority_99, Settings())
        _refuse_cpus(where, rule.cpus, online)


def _asks_uclamp(sc: Scenario) -> str | None:
    """The first thread (or phase) whose sched asks for util_min or util_max."""
    for proc in sc.workers:
        scheds = [(f"{proc.name}/{proc.main_name}", proc.main.sched)]
        for spec in proc.threads:
            scheds.append((f"{proc.name}/{spec.name}", spec.sched))
            if isinstance(spec.work, PhasesWork):
                scheds += [(f"{proc.name}/{spec.name} phase {n}", ph.sched) for n, ph in zip(spec.work.phase_names(), spec.work.phases)]
        for where, sched in scheds:
            if sched is not None and (sched.util_min is not None or sched.util_max is not None):
                return where
    return None


def _refuse_cpus(where: str, cpus: tuple[int, ...] | None, online: set[int]) -> None:
    if cpus is not None and not set(cpus) <= online:
        raise UsageError(
            f"{where} asks for CPUs {units.format_cpus(cpus)}, but this machine lets the runner use "
            f"{units.format_cpus(online)}; change the scenario's cpus"
        )


def missing_rights(perm: Permissions, wanted: Needs) -> list[str]:
    """Each right `wanted` that this user lacks, tried on a throwaway thread, with how to grant it."""
    missing: list[str] = []
    for (policy, priority), where in sorted(wanted.rt.items(), key=lambda kv: -kv[0][1]):
        err = _try_on_thread(lambda p=policy, q=priority: os.sched_setscheduler(0, p.kernel_id, os.sched_param(q)))
        if err:
            missing.append(
                f"{where} needs SCHED_{policy.value.upper()} priority {priority}, which this user may not set "
                f"({os.strerror(err)}; CAP_SYS_NICE {'yes' if perm.cap_sys_nice else 'no'}, RLIMIT_RTPRIO {perm.rlimit_rtprio}); "
                + _grant_rt(perm, priority)
            )
            break  # the highest priority refused says it all
    if wanted.min_nice is not None:
        nice, where = wanted.min_nice
        err = _try_on_thread(lambda: os.setpriority(os.PRIO_PROCESS, 0, nice))
        if err:
            missing.append(
                f"{where} needs nice {nice}, which this user may not set ({os.strerror(err)}); "
                + _grant(perm, "CAP_SYS_NICE", "nice", str(nice), f"LimitNICE={nice}", "--cap-add SYS_NICE")
            )
    if wanted.uclamp is not None and not os.path.exists(UCLAMP_KNOB):
        missing.append(
            f"{wanted.uclamp} asks for util_min / util_max (uclamp), which this kernel does not have ({UCLAMP_KNOB} is "
            "absent: it was built without CONFIG_UCLAMP_TASK); remove them, or run on a kernel with uclamp"
        )
    if wanted.memory_max is not None:
        _, why = memcg.hierarchy()
        if why:
            missing.append(
                f"{wanted.memory_max} asks for memory_max, but the runner cannot give it a memory cgroup of its own: {why}; "
                "remove memory_max, or run where the runner may create memory cgroups (root on the host, or a delegated cgroup)"
            )
    memlock = perm.rlimit_memlock
    if wanted.lock is not None and not perm.cap_ipc_lock and memlock != -1 and memlock < wanted.lock[0]:
        # root is bound by RLIMIT_MEMLOCK like anyone once CAP_IPC_LOCK is gone (containers, securebits); whatever the
        # size asked, the missing right is this one (exit 3), with how to grant it
        missing.append(
            f"{wanted.lock[1]}, but RLIMIT_MEMLOCK is {units.format_size(memlock)} and this user has no CAP_IPC_LOCK; "
            + _grant(perm, "CAP_IPC_LOCK", "memlock", "unlimited", "LimitMEMLOCK=infinity", "--cap-add IPC_LOCK or --ulimit memlock=-1")
        )
    return missing


def check(scenarios: list[Scenario], start: Settings, allow_degraded: bool, allow_priority_99: bool) -> Permissions:
    """Raise PermissionProblem (exit 3) for a right the cells need and this user lacks, unless degraded runs are allowed."""
    perm = current_permissions()
    perm.missing = missing_rights(perm, needs(scenarios, start, allow_priority_99, set(os.sched_getaffinity(0))))
    if perm.missing and not allow_degraded:
        raise PermissionProblem(
            "runner: missing permission, nothing was started:\n"
            + "\n".join(f"  - {m}" for m in perm.missing)
            + "\n  (or pass --allow-degraded to run anyway; affected threads are marked degraded)"
        )
    return perm
