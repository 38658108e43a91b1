"""Holding /dev/cpu_dma_latency for a run: the hold itself, the options, the session, and the real device.

The pure tests hold a plain file (it takes and gives back 4 bytes as the device does) or a
device that fails as a real one can; the kernel tests hold the real device and read it from
another descriptor, as any other program would see it.
"""

from __future__ import annotations

import errno
import json
import os
import struct
import time

import pytest
from conftest import SCENARIOS, run_cli
from fakebackend import FakeBackend
from kernelrun import finish, needs_rt, start_runner, wait_for_threads

from runner.cli import _run_parser
from runner.errors import UsageError
from runner.run import dmalatency
from runner.scenario.loader import load_scenario
from runner.session import RunOptions, run_scenario

MATRIX = os.path.join(SCENARIOS, "policy_matrix.yaml")
FIFO80 = os.path.join(SCENARIOS, "fifo80.yaml")


def _open_fds() -> set[str]:
    return set(os.listdir("/proc/self/fd"))


@pytest.fixture
def device(tmp_path) -> str:
    """A stand-in for the device: a file that reads back the 4 bytes written to it."""
    path = tmp_path / "cpu_dma_latency"
    path.write_bytes(struct.pack("=i", 2_000_000_000))
    return str(path)


# ---------------------------------------------------------------- the hold, without the kernel


def test_dma_hold_writes_the_binary_value_keeps_it_open_and_closes_it(device):
    before = _open_fds()
    with dmalatency.hold(25, device) as held:
        assert held.held and held.requested_us == 25 and held.reads_us == 25 and not held.note
        assert len(_open_fds() - before) == 1  # held open for the whole block
        with open(device, "rb") as handle:
            assert handle.read() == struct.pack("=i", 25)
    assert _open_fds() == before


def test_dma_hold_closes_the_device_when_the_block_raises(device):
    before = _open_fds()
    with pytest.raises(RuntimeError), dmalatency.hold(0, device):
        raise RuntimeError("a cell loop that failed")
    assert _open_fds() == before


def test_dma_left_alone_is_recorded_with_what_the_device_reads(device):
    with dmalatency.hold(None, device) as held:
        assert not held.held and held.requested_us is None and held.reads_us == 2_000_000_000
        assert "--no-dma-latency" in held.note
    with open(device, "rb") as handle:
        assert handle.read() == struct.pack("=i", 2_000_000_000)  # never written


def test_dma_a_missing_device_is_a_note_not_an_error(tmp_path):
    with dmalatency.hold(0, str(tmp_path / "none")) as held:
        assert not held.held and held.requested_us == 0 and held.reads_us is None
        assert "does not exist" in held.note and "not held" in held.note


def test_dma_no_permission_says_what_is_needed(device, monkeypatch):
    def refuse(path: str, flags: int, mode: int = 0o777) -> int:
        if flags & os.O_ACCMODE != os.O_RDONLY:
            raise PermissionError(errno.EACCES, "Permission denied", path)
        return real(path, flags, mode)

    real = os.open
    monkeypatch.setattr(dmalatency.os, "open", refuse)
    with dmalatency.hold(0, device) as held:
        assert not held.held and held.reads_us == 2_000_000_000
        assert held.note == f"cannot open {device}: Permission denied (it needs root or write access to the device); not held"


def test_dma_a_refused_value_closes_the_device_and_says_so(device, monkeypatch):
    def refuse(fd: int, data: bytes) -> int:
        raise OSError(errno.EINVAL, "Invalid argument")

    before = _open_fds()
    monkeypatch.setattr(dmalatency.os, "write", refuse)
    with dmalatency.hold(5, device) as held:
        assert not held.held and held.note == f"cannot write 5 to {device}: Invalid argument; not held"
    assert _open_fds() == before


# ---------------------------------------------------------------- the options


@pytest.mark.parametrize(
    ("args", "want"), [((), 0), (("--dma-latency", "10"), 10), (("--dma-latency", "10us"), 10), (("--no-dma-latency",), None)]
)
def test_dma_options(args, want):
    ns = _run_parser().parse_args([FIFO80, *args])
    assert RunOptions.from_namespace(ns, env={}).dma_latency_us == want


@pytest.mark.parametrize("value", ["-1", "1.5", "abc", "3000000000", "10ms"])
def test_dma_option_out_of_range_is_a_usage_error(value):
    ns = _run_parser().parse_args([FIFO80, "--dma-latency", value])
    with pytest.raises(UsageError) as exc:
        RunOptions.from_namespace(ns, env={})
    assert "expected whole microseconds from 0 to 2,000,000,000" in str(exc.value) and "Traceback" not in str(exc.value)


def test_dma_both_options_are_refused_by_the_cli(tmp_path):
    with pytest.raises(SystemExit) as exc:
        run_cli(FIFO80, "--dma-latency", "0", "--no-dma-latency", "--out", str(tmp_path / "r"))
    assert exc.value.code == 2


# ---------------------------------------------------------------- the session


def _run(out, backend: FakeBackend, *args: str) -> tuple[int, dict]:
    ns = _run_parser().parse_args([MATRIX, "--out", str(out), "--quiet", "--settle", "0", "--no-plots", "--no-report", *args])
    code = run_scenario(load_scenario(MATRIX), RunOptions.from_namespace(ns, env={}), backend)
    with open(os.path.join(out, "results.json")) as handle:
        return code, json.load(handle)


def test_dma_every_cell_runs_while_held_and_records_the_hold(tmp_path):
    backend = FakeBackend()
    code, results = _run(tmp_path / "r", backend)
    assert code in (0, 1)
    assert backend.dma_requests == [0] and backend.dma_held_during == backend.ran and backend.ran
    hold = {"requested_us": 0, "held": True, "reads_us": 0, "note": ""}
    assert results["machine"]["dma_latency"] == hold
    assert all(c["machine"]["dma_latency"] == hold for c in results["cells"])


def test_dma_a_hold_that_fails_warns_and_the_run_goes_on(tmp_path, capsys):
    why = "cannot open /dev/cpu_dma_latency: Permission denied (it needs root or write access to the device); not held"
    backend = FakeBackend(dma_refused=why)
    code, results = _run(tmp_path / "r", backend, "--dma-latency", "10")
    assert code in (0, 1) and len(backend.ran) == 5 and backend.dma_requests == [10]  # a hold that failed changes no outcome
    assert results["machine"]["dma_latency"] == {"requested_us": 10, "held": False, "reads_us": None, "note": why}
    err = capsys.readouterr().err
    assert f"runner: warning: {why}; CPUs may enter deep idle states" in err and "Traceback" not in err


def test_dma_left_alone_asks_nothing_and_warns_nothing(tmp_path, capsys):
    backend = FakeBackend()
    _, results = _run(tmp_path / "r", backend, "--no-dma-latency")
    assert backend.dma_requests == [None] and not backend.dma_held_during
    assert results["machine"]["dma_latency"]["held"] is False
    assert "cpu_dma_latency" not in capsys.readouterr().err


# ---------------------------------------------------------------- the real device

writable = pytest.mark.skipif(not os.access(dmalatency.DEVICE, os.W_OK), reason="needs write access to /dev/cpu_dma_latency")


@pytest.mark.kernel
@writable
def test_dma_the_kernel_holds_the_value_while_the_device_is_open():
    before = dmalatency.read_value()
    assert before is not None
    with dmalatency.hold(7) as held:
        now = dmalatency.read_value()
        assert held.held and held.reads_us == now and now is not None and now <= 7  # another holder may ask for less
    assert dmalatency.read_value() == before


@pytest.mark.kernel
@writable
@needs_rt
@pytest.mark.parametrize(("args", "held"), [((), True), (("--no-dma-latency",), False)])
def test_dma_a_real_run_holds_the_device_at_0_and_lets_it_go(tmp_path, args, held):
    before = dmalatency.read_value()
    proc = start_runner(FIFO80, "--duration", "2s", "--out", str(tmp_path), "--quiet", "--no-plots", *args, cwd=str(tmp_path))
    try:
        wait_for_threads("minimal_schedul", 10)
        during = dmalatency.read_value()
    except BaseException:
        proc.kill()
        raise
    done = finish(proc, str(tmp_path))
    assert done.code in (0, 1) and "Traceback" not in done.err, done.err
    assert during == (0 if held else before)
    recorded = done.results["machine"]["dma_latency"]
    assert recorded["held"] is held and recorded["requested_us"] == (0 if held else None) and recorded["reads_us"] == during
    assert done.results["cells"][0]["machine"]["dma_latency"] == recorded
    time.sleep(0.1)
    assert dmalatency.read_value() == before
