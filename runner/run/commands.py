"""A cell's background commands (stress-ng and the like): each one object, from its start to what it wrote.

A command is started in a session of its own and, where the machine lets the runner make one,
in a cgroup of its own it joins before its exec, so that everything it starts (a child that left
its process group too) stops with it, at the cell's end or through the guard should the runner
die.  Its output goes to command-N.log, capped.  The cell run (spawn.py) decides when they start
and end; this module keeps, per command, its process, its cgroup, its log and what it wrote.
"""

from __future__ import annotations

import errno
import os
import shutil
import signal
import subprocess
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Optional

from runner.run import memcg
from runner.run.child import signal_name
from runner.run.guard import Guard
from runner.run.output import CappedOutput
from runner.run.rawcell import BackgroundProcess, OutputCount
from runner.run.workers import exit_code, kill_group_or_process
from runner.scenario import model

# Background commands run this long before the measured start: how long they take to load the machine is theirs to
# know.  Hogs need no head start: woken one per CPU (`gate.start_load`), they spin within a fraction of a millisecond.
COMMAND_HEAD_START_S = 0.1
# A background command's output (command-N.log) is kept up to this, the rest counted and dropped: a load generator
# that logs at full speed for an hour would otherwise fill the disk the results go to (programs: output_limit).
COMMAND_OUTPUT_LIMIT = 64 * 1024 * 1024
# The shell a background command is started through: it joins the cgroup folder given as $0, then becomes the command.
_HELD_SHIM = ("/bin/sh", "-c", 'echo 0 2>/dev/null >"$0/cgroup.procs"; exec "$@"')


@dataclass
class Command:
    """One started background command: as the scenario wrote it, its process, the cgroup holding it, its log."""

    spec: model.Command
    n: int  # its place among the cell's commands: command-N.log
    popen: subprocess.Popen[bytes]
    group: Optional[memcg.MemoryCgroup] = None  # its cgroup, until the cell's end empties and removes it
    output: Optional[CappedOutput] = None  # its command-N.log while it is written
    count: Optional[OutputCount] = None  # what it wrote, once the cell stopped it

    @property
    def pid(self) -> int:
        return self.popen.pid

    @property
    def label(self) -> str:
        return f"command {self.spec.argv[0]}[{self.n}]"

    def background(self) -> BackgroundProcess:
        """The command as the results name it: the argv as the scenario wrote it (without the shell that put it in its cgroup)."""
        argv = tuple(self.spec.argv)
        return BackgroundProcess("command", self.spec.name or argv[0], self.pid, argv, f"command-{self.n}.log", self.count)


class BackgroundCommands:
    """The cell's background commands, in the scenario's order; the guard watches each process and cgroup while it lives."""

    def __init__(self, folder: str, guard: Guard) -> None:
        self.folder, self.guard = folder, guard
        self.started: list[Command] = []

    def __len__(self) -> int:
        return len(self.started)

    def __iter__(self) -> Iterator[Command]:
        return iter(self.started)

    def start(self, specs: list[model.Command]) -> str:
        """Start each of `specs` in turn; why one could not start (the rest are then not started), or ""."""
        for spec in specs:
            n = len(self.started)
            try:
                output = CappedOutput(os.path.join(self.folder, f"command-{n}.log"), COMMAND_OUTPUT_LIMIT)
            except OSError as exc:
                return f"background command {spec.argv[0]!r} could not start: its log: {exc.strerror} ({exc.filename})"
            group: Optional[memcg.MemoryCgroup] = None
            try:
                argv, group = self._held(spec.argv, n)
                popen = subprocess.Popen(
                    argv, stdout=output.write_fd, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True
                )
            except OSError as exc:
                output.finish(0)
                if group is not None:
                    self._remove(group)
                return f"background command {spec.argv[0]!r} could not start: {exc.strerror}"
            finally:
                output.close_write_end()  # the command holds its own copy: its exit ends the pipe
            self.started.append(Command(spec, n, popen, group, output))
            self.guard.watch(popen.pid)
        return ""

    def _held(self, argv: list[str], n: int) -> tuple[list[str], Optional[memcg.MemoryCgroup]]:
        """`argv`, started so that it joins a cgroup of its own before its exec, where the machine lets the runner make one;
        and that cgroup.

        Everything the command starts is in that cgroup, a child that left its process group
        (setsid, a daemon) too, so the cell's end (or the guard, should the runner die) stops
        it all.  The command's own shell joins, then execs it: nothing runs outside first.
        """
        where, _ = memcg.hierarchy(limit=False)
        if where is None:
            return list(argv), None
        if shutil.which(argv[0]) is None:  # as Popen would have said, before the shell would say it less clearly
            raise FileNotFoundError(errno.ENOENT, os.strerror(errno.ENOENT), argv[0])
        try:
            group = memcg.MemoryCgroup.create(where, f"command{n}", None)
        except OSError:
            return list(argv), None  # no cgroup after all: its process group is what holds it, as without cgroups
        self.guard.watch_cgroup(group.folder)
        return [*_HELD_SHIM, group.folder, *argv], group

    def end(self) -> None:
        """SIGTERM each command's group, of those not reaped yet (a reaped one's pid may be another process's by now)."""
        for c in self.started:
            if c.popen.returncode is None:
                kill_group_or_process(c.pid, signal.SIGTERM)

    def incidents(self, at: str) -> Iterator[tuple[str, str]]:
        """(label, what happened) of each command that has exited, `at` saying when it was seen."""
        for c in self.started:
            code = exit_code(c.popen)
            if code is not None:
                how = f"killed by {signal_name(-code)}" if code < 0 else f"exited with code {code}"
                yield c.label, f"background {c.label} (pid {c.pid}) {how} {at}; background load must last the whole cell"

    def remove_groups(self) -> None:
        """Kill what the commands left in their cgroups (a child started outside its group too) and remove the cgroups."""
        for c in self.started:
            if c.group is not None:
                self._remove(c.group)
                c.group = None

    def _remove(self, group: memcg.MemoryCgroup) -> None:
        group.kill_all()
        group.remove()
        self.guard.forget_cgroup(group.folder)

    def finish_outputs(self, finish_by: float) -> None:
        """Stop reading the commands' output once every process that holds it is gone, or at `finish_by`, and count it."""
        for c in self.started:
            if c.output is not None:
                c.count = c.output.finish(finish_by)
                c.output = None
