"""The runner's edge with the shell and the file system: one line and a documented exit code for anything a user can do.

These need no RT rights and spawn no scenario: the CLI is called in-process, with
paths that cannot be written, folders already in use, and a handler that fails
like a bug would.  The exit codes are written out as numbers, as README documents
them, not taken from the code under test.
"""

from __future__ import annotations

import contextlib
import errno
import io
import os
import signal
import stat
import subprocess
import sys
import threading
import time

import pytest
from conftest import SCENARIOS, run_cli

from runner import cli, outdir
from runner.errors import ExitCode, UsageError, from_os_error
from runner.run import guard

DATA = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data")
POLICY = os.path.join(DATA, "policy_matrix")


def test_a_bug_prints_one_line_saves_the_traceback_and_exits_70(tmp_path, monkeypatch, capsys):
    def broken(argv: list[str]) -> int:
        raise ZeroDivisionError("division by zero")

    monkeypatch.setenv("RUNNER_CRASH_DIR", str(tmp_path))
    code = cli._guarded(broken, [])
    err = capsys.readouterr().err
    assert code == 70
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert "internal error (a bug in the runner" in err and "ZeroDivisionError" in err
    saved = list(tmp_path.glob("runner-bug-*.txt"))
    assert len(saved) == 1 and str(saved[0]) in err
    assert "Traceback (most recent call last)" in saved[0].read_text() and "def broken" not in err


def test_the_crash_report_is_a_new_private_file_never_a_name_planted_in_advance(tmp_path, monkeypatch, capsys):
    """Its name was runner-bug-<second>-<pid>.txt in /tmp: another user could plant that link, and the runner wrote through it."""
    victim = tmp_path / "victim"
    victim.write_text("keep me\n")
    crash = tmp_path / "crash"
    crash.mkdir()
    now = time.time()
    for second in range(-1, 4):
        stamp = time.strftime("%Y%m%dT%H%M%S", time.localtime(now + second))
        (crash / f"runner-bug-{stamp}-{os.getpid()}.txt").symlink_to(victim)
    monkeypatch.setenv("RUNNER_CRASH_DIR", str(crash))

    def broken(argv: list[str]) -> int:
        raise ZeroDivisionError("division by zero")

    mask = os.umask(0)
    try:
        assert cli._guarded(broken, []) == 70
    finally:
        os.umask(mask)
    assert victim.read_text() == "keep me\n"
    saved = [p for p in crash.iterdir() if not p.is_symlink()]
    assert len(saved) == 1 and str(saved[0]) in capsys.readouterr().err
    assert stat.S_IMODE(saved[0].stat().st_mode) == 0o600, "readable by its owner alone, whatever the umask"
    assert "ZeroDivisionError" in saved[0].read_text()


def test_a_bug_under_a_command_line_that_is_not_utf8_still_saves_its_traceback(tmp_path, monkeypatch, capsys):
    def broken(argv: list[str]) -> int:
        raise ZeroDivisionError("division by zero")

    monkeypatch.setenv("RUNNER_CRASH_DIR", str(tmp_path))
    monkeypatch.setattr(sys, "argv", ["runner", os.fsdecode(b"x\xff.yaml")])
    assert cli._guarded(broken, []) == 70
    saved = list(tmp_path.glob("runner-bug-*.txt"))
    assert len(saved) == 1 and "x\\xff.yaml" in saved[0].read_text() and str(saved[0]) in capsys.readouterr().err


@pytest.mark.parametrize("command", [["validate"], ["report"], ["merge", POLICY, "--out"], ["--out"]])
def test_a_path_that_is_not_utf8_is_refused_with_its_bytes_shown(tmp_path, command):
    """Results, reports and JUnit files store their paths in UTF-8: such a path was a traceback when results.json was saved."""
    bad = os.fsdecode(str(tmp_path).encode() + b"/x\xff.yaml")
    fifo80 = os.path.join(SCENARIOS, "fifo80.yaml")
    done = run_cli(*command, bad) if command != ["--out"] else run_cli(fifo80, "--out", bad)
    assert done.code == 2 and "Traceback" not in done.err
    said = "not UTF-8; expected names and paths in UTF-8, as results and reports store them: rename it"
    assert done.err == f"runner: {tmp_path}/x\\xff.yaml: {said}\n"


def test_sigterm_stops_any_command_as_ctrl_c_does(capsys):
    def slow(argv: list[str]) -> int:
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # the signal's handler ends this at once
        return 0

    before = signal.getsignal(signal.SIGTERM)
    began = time.monotonic()
    code = cli._guarded(slow, [])
    assert code == 130 and time.monotonic() - began < 4
    assert capsys.readouterr().err.strip() == "runner: interrupted"
    assert signal.getsignal(signal.SIGTERM) is before, "the handler is the command's only"


@pytest.mark.parametrize(
    "command",
    [["validate", "{fifo}.yaml"], ["{fifo}.yaml", "--list"], ["validate", "{fifo}.json"], ["report", "{fifo}.json", "-o", "-"]]
    + [["report", "/dev/zero", "-o", "-"], ["compare", "/dev/zero", "/dev/zero"], ["import-rtapp", "{fifo}.json"]],
)
def test_a_fifo_or_device_as_an_input_file_is_refused_at_once(tmp_path, command):
    """A FIFO would block the runner until something wrote to it; /dev/zero would be read until memory ran out."""
    fifo = str(tmp_path / "input")
    for ext in (".yaml", ".json"):
        os.mkfifo(fifo + ext)
    done_event = threading.Event()

    def unblock() -> None:  # should a reader block on a FIFO, open its other end after 10 s: the test fails, never hangs
        if not done_event.wait(10):
            for ext in (".yaml", ".json"):
                with contextlib.suppress(OSError):
                    os.close(os.open(fifo + ext, os.O_WRONLY | os.O_NONBLOCK))

    threading.Thread(target=unblock, daemon=True).start()
    began = time.monotonic()
    done = run_cli(*[word.format(fifo=fifo) for word in command])
    done_event.set()
    assert time.monotonic() - began < 5, "a reader blocked on the FIFO"
    assert done.code == 2 and "Traceback" not in done.err, done.err
    assert "is a FIFO, not a file" in done.err or "is a character device, not a file" in done.err, done.err


@pytest.mark.parametrize("argv", [["ps", "²"], ["watch", "²"], ["{fifo80}", "--dma-latency", "²", "--out", "{out}"]])
def test_digits_python_calls_digits_but_int_refuses_are_a_usage_error(argv, tmp_path):
    """`"²".isdigit()` is true and `int("²")` raises: such a check once let a superscript through to a crash (exit 70)."""
    done = run_cli(*[a.format(fifo80=os.path.join(SCENARIOS, "fifo80.yaml"), out=tmp_path / "r") for a in argv])
    assert done.code == 2 and "Traceback" not in done.err and "internal error" not in done.err, done.err
    assert not os.path.exists(tmp_path / "r"), "refused before anything ran"


HUGE = "9" * 5_000  # past the 4,300 digits int() converts: a ValueError, and exit 70, where a number was taken without a bound


def _given(argv: list[str], tmp_path) -> tuple[int, str]:
    """The exit code and stderr of `runner ARGV` (argparse's own refusals included); {fifo80} is the scenario, {run} a results folder."""
    run = ""
    if "{run}" in argv:
        from reportdata import many_threads

        run = str(tmp_path / "run")
        many_threads(run, threads=1, processes=1, callbacks=10)  # a cell with native histograms, as --histogram exports
    words = [a.format(fifo80=os.path.join(SCENARIOS, "fifo80.yaml"), out=tmp_path / "r", run=run) for a in argv]
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            done = run_cli(*words)
        return done.code, done.err
    except SystemExit as exc:
        return int(exc.code or 0), err.getvalue()


NUMBERS = [
    ["ps", "{n}"],
    ["watch", "{n}", "--duration", "100ms", "--out", "{out}"],
    ["{fifo80}", "--list", "--repeat", "{n}"],
    ["{fifo80}", "--list", "--shuffle", "{n}"],
    ["{fifo80}", "--list", "--shard", "1/{n}"],
    ["{fifo80}", "--list", "--dma-latency", "{n}"],
    ["report", "{run}", "--histogram", "-", "--histogram-max", "{n}"],
]


@pytest.mark.parametrize("argv", NUMBERS, ids=lambda a: " ".join(w for w in a if w.startswith("-") or w in ("ps", "watch")))
def test_a_number_of_thousands_of_digits_is_out_of_range_not_a_crash(argv, tmp_path):
    """`runner watch 999...9` (5,000 digits) and --shard, --dma-latency, ps: int() raised, exit 70 with a traceback saved."""
    code, err = _given([w.replace("{n}", HUGE) for w in argv], tmp_path)
    assert code == 2 and "internal error" not in err and "Traceback" not in err, err[:500]
    assert "out of range" in err or "at most" in err or "expected whole microseconds" in err, err[:500]
    assert len(err) < 1_000 and "…" in err  # the number is quoted cut, not 5,000 digits
    assert not os.path.exists(tmp_path / "r")


@pytest.mark.parametrize("argv", NUMBERS, ids=lambda a: " ".join(w for w in a if w.startswith("-") or w in ("ps", "watch")))
def test_digits_of_other_scripts_are_no_numbers(argv, tmp_path):
    """`runner watch ١` watched PID 1 (int() reads Arabic-Indic digits), `--repeat ٣` ran three times: a PID or number is 0-9.

    For ps and watch such a word is a process name, which no process has here.
    """
    code, err = _given([w.replace("{n}", "١" if argv[0] in ("ps", "watch") else "٣") for w in argv], tmp_path)
    assert code == 2 and "internal error" not in err and "Traceback" not in err, err[:500]
    if argv[0] in ("ps", "watch"):
        assert "no live process" in err and "'١'" in err
    assert not os.path.exists(tmp_path / "r")


class _FailingStdout(io.StringIO):
    def __init__(self, error: int):
        super().__init__()
        self.error = error

    def write(self, text: str) -> int:
        raise OSError(self.error, os.strerror(self.error))


@pytest.mark.parametrize(
    ("error", "outcome", "code", "said"),
    [(32, 1, 1, False), (32, 0, 0, False), (28, 0, 4, True), (28, 1, 1, True), (9, 0, 4, True)],
    ids=["closed pipe, failed", "closed pipe, passed", "full disk, passed", "full disk, failed", "no stdout, passed"],
)
def test_output_that_cannot_be_written_never_hides_the_outcome(monkeypatch, capsys, error, outcome, code, said):
    """`runner s.yaml | head -1` once exited 0 on a failed run, with no report; `compare > /dev/full` exited 70."""
    from runner import terminal

    monkeypatch.setattr(terminal, "_LOST", [])
    went_on = []

    def command(argv: list[str]) -> int:
        terminal.say("a table")
        terminal.say("a second line")
        went_on.append(True)  # the command carries on to its report and its outcome
        return outcome

    monkeypatch.setattr(sys, "stdout", _FailingStdout(error))
    assert cli._guarded(command, []) == code and went_on
    err = capsys.readouterr().err
    assert ("cannot write to standard output" in err) is said and "Traceback" not in err


def test_a_full_disk_under_stdout_is_exit_4_with_one_line(tmp_path):
    argv = [sys.executable, "-m", "runner", "compare", POLICY, POLICY]
    with open("/dev/full", "w") as full:  # run from elsewhere than the clone: the installed runner, not the source tree
        done = subprocess.run(argv, stdout=full, stderr=subprocess.PIPE, text=True, timeout=120, cwd=tmp_path)
    assert done.returncode == 4, done.stderr
    assert done.stderr.strip().splitlines()[-1] == "runner: cannot write to standard output: No space left on device"
    assert "Traceback" not in done.stderr and "Exception ignored" not in done.stderr


@pytest.mark.parametrize(
    "argv",
    [
        ["{fifo80}", "--out", "{copy}", "--junit", "{copy}/results.json"],
        ["report", "{copy}", "-o", "{copy}/results.json"],
        ["report", "{copy}", "--json", "{renamed}"],
        ["compare", "{copy}", "{copy}", "-o", "{link}"],
        ["compare", "{copy}", "{copy}", "--junit", "{copy}/cells.jsonl"],
        ["merge", "{copy}", "--out", "{tmp}/merged", "--junit", "{renamed}"],
    ],
)
def test_no_output_option_overwrites_a_results_file(tmp_path, argv):
    """`--junit DIR/results.json` once replaced a run's only copy of its results with XML."""
    import shutil

    copy = tmp_path / "run"
    shutil.copytree(POLICY, copy)
    before = (copy / "results.json").read_bytes()
    renamed = tmp_path / "baseline-of-monday.json"
    renamed.write_bytes(before)
    link = tmp_path / "link.md"
    link.symlink_to(copy / "results.json")
    words = {"fifo80": os.path.join(SCENARIOS, "fifo80.yaml"), "copy": copy, "renamed": renamed, "link": link, "tmp": tmp_path}
    done = run_cli(*[a.format(**words) for a in argv])
    assert done.code == 2 and "that is a results file, which only a run writes" in done.err, done.err
    assert (copy / "results.json").read_bytes() == before and renamed.read_bytes() == before


def test_a_fifo_named_as_an_output_is_checked_without_waiting_on_it(tmp_path):
    fifo = tmp_path / "out.xml"
    os.mkfifo(fifo)
    began = time.monotonic()
    assert outdir.writable_file(str(fifo), "--junit") == str(fifo)
    assert time.monotonic() - began < 2


def test_stdout_and_a_pipe_as_stdin_are_written_and_read_where_they_are(tmp_path):
    """/dev/stdout on a pipe once resolved to /proc/N/fd/pipe:[M], which no file can be made beside."""
    code = "from runner.safefs import write_named; write_named('/dev/stdout', 'through\\n')"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert done.returncode == 0 and done.stdout == "through\n", done.stderr
    log = tmp_path / "log"
    log.write_text("kept\n")
    with open(log, "a") as handle:  # `>> log`: what the file held stays
        subprocess.run([sys.executable, "-c", code], stdout=handle, check=True, timeout=60, cwd=tmp_path)
    assert log.read_text() == "kept\nthrough\n"
    scenario = open(os.path.join(SCENARIOS, "fifo80.yaml"), "rb").read()
    argv = [sys.executable, "-m", "runner", "validate", "/dev/stdin"]
    done = subprocess.run(argv, input=scenario, capture_output=True, timeout=120, cwd=tmp_path)
    assert done.returncode == 0 and b"/dev/stdin: ok (1 cell)" in done.stdout, done.stderr


def test_an_os_error_on_a_path_is_one_line_naming_it(capsys):
    def unwritable(argv: list[str]) -> int:
        raise PermissionError(13, "Permission denied", "/somewhere/results.json")

    code = cli._guarded(unwritable, [])
    err = capsys.readouterr().err
    assert code == 4 and err.count("\n") == 1
    assert "/somewhere/results.json: Permission denied" in err


@pytest.mark.parametrize("out", ["/proc/nope", "/proc/version", "/dev/null/x"])
def test_an_output_folder_that_cannot_be_made_is_invalid_input(out):
    # other.yaml asks for no right: an ordinary user's run reaches the folder too (fifo80's stopped at its rights, exit 3)
    done = run_cli(os.path.join(SCENARIOS, "other.yaml"), "--out", out, "--duration", "1s")
    assert done.code == 2, done.err
    assert "Traceback" not in done.err and out in done.err and len(done.err.strip().splitlines()) == 1


def test_report_to_an_unwritable_file_is_invalid_input(tmp_path):
    done = run_cli("report", POLICY, "-o", "/proc/nope/report.md", "--no-plots")
    assert done.code == 2 and "/proc/nope" in done.err and "Traceback" not in done.err


def test_compare_to_an_unwritable_file_is_invalid_input():
    done = run_cli("compare", POLICY, POLICY, "-o", "/proc/nope.md")
    assert done.code == 2 and "/proc/nope.md" in done.err and "Traceback" not in done.err


def test_an_unwritable_step_summary_is_a_warning_not_a_crash(monkeypatch):
    monkeypatch.setenv("GITHUB_STEP_SUMMARY", "/proc/nope/summary.md")
    done = run_cli("compare", POLICY, POLICY)
    assert done.code == 0, done.err
    assert "warning: cannot append to GITHUB_STEP_SUMMARY /proc/nope/summary.md" in done.err


def test_merge_into_a_folder_holding_results_is_refused(tmp_path):
    target = tmp_path / "merged"
    target.mkdir()
    (target / "results.json").write_text("{}")
    done = run_cli("merge", POLICY, "--out", str(target), "--no-plots")
    assert done.code == 2 and "already holds the results of another run" in done.err
    assert (target / "results.json").read_text() == "{}"


def test_a_folder_is_held_by_one_claim_at_a_time(tmp_path):
    first = outdir.claim(str(tmp_path / "out"))
    with pytest.raises(UsageError, match="in use by another runner"):
        outdir.claim(str(tmp_path / "out"))
    first.release()
    outdir.claim(str(tmp_path / "out")).release()


def test_the_claim_is_the_kernels_lock_so_another_process_sees_it(tmp_path):
    held = outdir.claim(str(tmp_path))
    probe = subprocess.run(
        [sys.executable, "-c", "import sys; from runner import outdir; outdir.claim(sys.argv[1])", str(tmp_path)],
        capture_output=True,
        text=True,
        cwd="/",
    )
    held.release()
    assert probe.returncode != 0 and "in use by another runner" in probe.stderr


def test_a_folder_with_results_is_refused_unless_resumed(tmp_path):
    (tmp_path / "results.json").write_text("{}")
    with pytest.raises(UsageError, match="already holds the results"):
        outdir.claim(str(tmp_path))
    outdir.claim(str(tmp_path), resume=True).release()


def test_a_file_where_the_folder_should_be_is_refused(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(UsageError, match=r"a file stands where a folder is expected|Not a directory"):
        outdir.claim(str(tmp_path / "f"))
    with pytest.raises(UsageError):
        outdir.claim(str(tmp_path / "f" / "sub"))


def test_guard_keeps_the_groups_not_forgotten():
    lines = io.StringIO("+100\n+200\n-100\n+300\nnonsense\n+\n-x\n+400\n-400\n")
    assert guard.serve(lines) == {200, 300}


def test_guard_never_keeps_group_0_or_1():
    """killpg(0) is the guard's own group, killpg(1) init's: no process the runner starts leads either."""
    lines = io.StringIO("+0\n+1\n+00\n+\u0661\u0662\n+12\n")
    assert guard.serve(lines) == {12}


def test_guard_follows_cgroups_beside_process_groups():
    lines = io.StringIO("+100\ncg+/cg/runner-1-prog\ncg+/cg/runner-1-command0\ncg-/cg/runner-1-prog\ncg+\ntrace+/t/instances/runner-1-0\n")
    left = guard.follow(lines)
    assert left.groups == {100} and left.cgroups == {"/cg/runner-1-command0"} and left.instances == {"/t/instances/runner-1-0"}


@pytest.mark.parametrize("killed", ["the owner", "the owner and its guard"])
def test_guard_kills_a_watched_group_when_its_owner_dies(tmp_path, killed):
    """The owner (a process standing in for the runner) dies by SIGKILL; the group it started dies with it.

    Killed beside its guard, the owner's group once lived on: the guard's second does the guard's work then.
    """
    script = (
        "import subprocess, sys, time\n"
        "from runner.run.guard import Guard\n"
        "g = Guard()\n"
        "getattr(g, 'ready', lambda: None)()\n"  # its second started, as before a run's programs and commands
        "p = subprocess.Popen(['sh', '-c', 'sleep 60 & sleep 60'], start_new_session=True)\n"
        "g.watch(p.pid)\n"
        "print(p.pid, g.proc.pid, flush=True)\n"
        "time.sleep(60)\n"
    )
    owner = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True, cwd="/")
    assert owner.stdout is not None
    pgid, guard_pid = map(int, owner.stdout.readline().split())
    time.sleep(0.3)
    assert _group_members(pgid), "the watched group should be running"
    if killed == "the owner and its guard":
        os.kill(guard_pid, signal.SIGKILL)
    owner.kill()
    owner.wait()
    until = time.monotonic() + 5
    while _group_members(pgid) and time.monotonic() < until:
        time.sleep(0.05)
    assert not _group_members(pgid), "the guard should have killed the group of its dead owner"


def _group_members(pgid: int) -> list[int]:
    """Live (not zombie) processes in process group `pgid`, from /proc."""
    out = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as handle:
                    fields = handle.read().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[2]) == pgid and fields[0] not in ("Z", "X"):
                out.append(int(entry))
    return out


def test_a_hog_at_priority_99_obeys_the_threads_rule(write_scenario, tmp_path):
    path = write_scenario(
        "name: hog99\nduration: 1s\nprocesses:\n  - name: p\n    main: {work: {kind: periodic, period: 100ms}}\n"
        "background:\n  hogs:\n    - {count: 1, sched: 'fifo:99'}\n"
    )
    done = run_cli(path, "--out", str(tmp_path / "r"))
    assert done.code == 2, done.err
    assert "background hog hog asks for RT priority 99" in done.err and "--allow-priority-99" in done.err
    assert not (tmp_path / "r").exists()


def test_a_phase_at_priority_99_obeys_the_threads_rule(write_scenario, tmp_path):
    """Issue 40: a program phase's `sched: fifo:99` ran without --allow-priority-99 (and its report said `at OTHER`)."""
    path = write_scenario(
        "name: phase99\nduration: 1s\nprocesses:\n  - name: phased\n    threads:\n      - name: mover\n        work:\n"
        "          kind: phases\n          phases:\n"
        "            - {name: urgent, sched: 'fifo:99', events: [{timer: {period: 10ms}}, {run: 100us}]}\n"
    )
    done = run_cli(path, "--out", str(tmp_path / "r"))
    assert done.code == 2, done.err
    assert "phased/mover phase urgent asks for RT priority 99" in done.err and "--allow-priority-99" in done.err
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize(
    "background, who",
    [
        ({"hogs": [{"count": 2}]}, "background hog hog"),
        ({"commands": [{"argv": ["stress-ng", "--cpu", "2"]}]}, "background command stress-ng"),
    ],
)
def test_load_inheriting_the_runners_priority_99_obeys_the_threads_rule(background, who):
    """Issue 40: `chrt -f 99 runner ...` (or a service at priority 99) gave hogs and background commands without a sched of
    their own the watchdog's priority, spinning on every CPU; the measured threads, asking for their own, were let through."""
    from runner.run import preflight
    from runner.scenario.model import Policy, Scenario
    from runner.scenario.plan import Settings

    scenario = Scenario.parse({"name": "x", "processes": [{"name": "p", "main": {"sched": "fifo:50"}}], "background": background})
    at_99 = Settings(Policy.FIFO, 99)
    with pytest.raises(UsageError) as refused:
        preflight.needs([scenario], at_99, False, {0, 1})
    words = str(refused.value)
    assert words.startswith(f"{who} inherits RT priority 99, the runner watchdog's own, from the runner, which runs at SCHED_FIFO 99")
    assert "start the runner at 98 or less" in words and "--allow-priority-99" in words
    preflight.needs([scenario], at_99, True, {0, 1})  # allowed
    preflight.needs([scenario], Settings(Policy.FIFO, 98), False, {0, 1})  # the runner at 98: its load at 98, below the watchdog


def test_a_folder_with_a_report_of_no_run_is_refused(tmp_path):
    """`--out docs` once replaced the user's own docs/report.md with the run's."""
    (tmp_path / "report.md").write_text("# my notes\n")
    with pytest.raises(UsageError, match=r"holds a report\.md of no run"):
        outdir.claim(str(tmp_path))
    assert (tmp_path / "report.md").read_text() == "# my notes\n"
    (tmp_path / "results.json").write_text("{}")
    outdir.claim(str(tmp_path), resume=True).release()  # a run's own report, beside its results: resumed over


def test_watch_refuses_a_priority_99_rule_before_it_touches_the_process(tmp_path):
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        done = run_cli("watch", str(sleeper.pid), "--rule", "*=fifo:99", "--duration", "100ms", "--out", str(tmp_path / "w"))
        assert done.code == 2 and "asks for RT priority 99" in done.err and "--allow-priority-99" in done.err
        assert os.sched_getscheduler(sleeper.pid) == os.SCHED_OTHER and not (tmp_path / "w").exists()
    finally:
        sleeper.kill()
        sleeper.wait()


def test_a_report_into_a_folder_yet_to_be_made_is_written_and_one_ending_in_a_slash_is_refused(tmp_path):
    deep = tmp_path / "new dir ü" / "sub" / "r.md"
    done = run_cli("report", POLICY, "-o", str(deep), "--no-plots")
    assert done.code == 0 and deep.read_text().startswith("#"), done.err
    done = run_cli("report", POLICY, "-o", str(tmp_path / "nodir") + "/", "--no-plots")
    assert done.code == 2 and "names a folder (it ends in /); expected a file" in done.err
    assert not (tmp_path / "nodir").exists()


@pytest.mark.parametrize(
    "argv",
    [
        ["report", POLICY, "--no-plots"],
        ["merge", POLICY, "--out", "{out}", "--no-plots"],
        [os.path.join(SCENARIOS, "fifo80.yaml"), "--out", "{out}"],
    ],
)
def test_a_threshold_without_a_baseline_is_refused_not_ignored(tmp_path, argv):
    done = run_cli(*[a.format(out=tmp_path / "out") for a in argv], "--threshold", "latency.p99=+5%")
    assert done.code == 2 and "--threshold latency.p99=+5% sets a limit of a comparison; give --baseline RESULTS" in done.err
    assert not (tmp_path / "out").exists()


def test_merge_with_a_baseline_that_cannot_be_read_makes_no_folder(tmp_path):
    done = run_cli("merge", POLICY, "--out", str(tmp_path / "m"), "--baseline", str(tmp_path / "nope"), "--no-plots")
    assert done.code == 2 and "cannot read results" in done.err, done.err
    assert not (tmp_path / "m").exists(), "a rerun of the fixed command would be refused: the folder holds results"


@pytest.mark.parametrize("error", [errno.ENOSPC, errno.EDQUOT, errno.EIO])
@pytest.mark.parametrize("before_run", [True, False])
def test_a_full_disk_is_a_run_error_whenever_it_comes(error, before_run):
    """Not invalid input: the command and its paths were right, and run again once there is room."""
    made = from_os_error(OSError(error, os.strerror(error), "/r/results.json"), "cannot write the results file", before_run)
    assert made.exit_code == ExitCode.RUN_ERROR
    assert str(made).startswith(f"runner: cannot write the results file /r/results.json: {os.strerror(error)}; ")
    assert "write somewhere else (another --out or file)" in str(made) and "\n" not in str(made)


def test_a_path_the_user_chose_wrongly_is_still_invalid_input_before_the_run():
    made = from_os_error(OSError(errno.EACCES, "Permission denied", "/r"), "results folder")
    assert made.exit_code == ExitCode.INVALID_INPUT and "choose a folder you may write" in str(made)


@pytest.mark.parametrize(
    ("argv", "what"),
    [
        (["report", POLICY, "-o", "/dev/full"], "cannot write the report"),
        (["compare", POLICY, POLICY, "-o", "/dev/full"], "cannot write the comparison"),
        (["compare", POLICY, POLICY, "--junit", "/dev/full"], "cannot write the JUnit file"),
        (["import-rtapp", os.path.join(os.path.dirname(DATA), "rtapp", "example2.json"), "-o", "/dev/full"], "cannot write the scenario"),
    ],
    ids=["report -o", "compare -o", "compare --junit", "import-rtapp -o"],
)
def test_every_output_file_on_a_full_disk_exits_4_naming_it(argv, what):
    """/dev/full takes every write with ENOSPC: a file a command was asked to write, on a full disk (these once exited 2).

    The exports are tested with the other export options (test_export.py)."""
    done = run_cli(*argv)
    assert done.code == 4, done.err
    said = done.err.strip().splitlines()[-1]
    assert said.startswith(f"runner: {what} /dev/full: No space left on device; the disk is full: free some space"), said
    assert "Traceback" not in done.err
