"""The seed's headline, per callback, on a ROS 2 node the runner did not write: the stand-in node against the real kernel.

The stand-in (tests/programs/rosnode.c, built by tests/rosfake.py against Jazzy's vendored tracetools
header and a fake libtracetools) runs a 10 ms timer whose callback burns 4 ms of CPU, on CPU 0 beside
a busy loop on every CPU, once as SCHED_OTHER and once as SCHED_FIFO 80 (`sched:` before exec, as
`chrt -f 80 ros2 run ...`).  The runner knows nothing of it but its command: every figure below comes
from the interposer inside it (getrusage(RUSAGE_THREAD) around each callback, as the seed measures).
Asserted: many involuntary switches per timer callback at OTHER against about none at FIFO 80; the
callback count and missed releases equal what the node itself printed; the wake-up latency the runner
measured from the node's timer grid agrees in size with the node's own (large effects, not timings).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess

import pytest
import yaml
from kernelrun import finish, needs_rt, start_runner
from rosfake import RosFake, build

from runner.run import roscb

pytestmark = [
    pytest.mark.kernel,
    needs_rt,
    pytest.mark.skipif(not roscb.LIBRARY, reason="the interposer was not built (pip install -e .)"),
]

COUNT = 150  # timer callbacks the node runs, 10 ms apart: 1.5 s
TIMER = "minimal_publisher/MinimalPublisher::MinimalPublisher()::{lambda()#1}"


@pytest.fixture(scope="module")
def ros(tmp_path_factory: pytest.TempPathFactory) -> RosFake:
    return build(tmp_path_factory)


def _run(ros: RosFake, tmp_path, sched: str) -> tuple[dict, dict]:
    """(the cell's results, the node's own JSON line) for one run of the stand-in at `sched`."""
    jazzy = ros.distros["jazzy"]
    scenario = {
        "name": "rosnode",
        "duration": "10s",  # the limit: the cell ends when the node exits
        "processes": [
            {
                "name": "rosnode",
                "command": [jazzy.node, "--period", "10ms", "--burn", "4ms", "--count", str(COUNT)],
                "env": dict(jazzy.env),
                "sched": sched,
                "cpus": 0,
                "until": "exit",
            }
        ],
        "background": {"hogs": [{"count": "cpus", "kind": "process"}]},
    }
    path = tmp_path / f"{sched.replace(':', '')}.yaml"
    path.write_text(yaml.safe_dump(scenario, sort_keys=False))
    out = tmp_path / f"out-{sched.replace(':', '')}"
    done = finish(start_runner(str(path), "--out", str(out), "--settle", "0", cwd=str(tmp_path)), str(out))
    assert done.results is not None, done.err
    (cell,) = done.results["cells"]
    lines = [json.loads(x) for x in open(os.path.join(out, "cells", cell["id"], "rosnode.stdout")) if x.startswith("{")]
    assert lines, "the node printed its counts"
    return cell, lines[-1]


def _callback(cell: dict, name: str) -> dict:
    found = [c for c in cell["callbacks"] if c["name"] == name]
    assert len(found) == 1, [c["name"] for c in cell["callbacks"]]
    return found[0]


def _own(node: dict, kind: str = "timer") -> dict:
    """The node's own record of its first callback of `kind`, from its JSON line."""
    return next(c for c in node["callbacks"] if c.get("kind", "timer") == kind)


@pytest.mark.parametrize("sched", ["other", "fifo:80"])
def test_the_stand_in_nodes_timer_callback_is_measured_callback_by_callback(ros: RosFake, tmp_path, sched: str) -> None:
    cell, node = _run(ros, tmp_path, sched)
    timer = _callback(cell, TIMER)
    own = _own(node)
    figures = timer["figures"]
    assert figures["callbacks"] == own["count"] == COUNT, "every callback the node ran, none more"
    assert figures["missed_releases"] == own["missed"]
    switches = figures["involuntary"]["per_callback_mean"]
    if sched == "other":  # sharing CPU 0 with a busy loop: the scheduler preempts the 4 ms burn, in every callback or nearly
        assert switches >= 1, figures["involuntary"]
        assert figures["involuntary"]["callbacks_with_any"] >= COUNT // 2
    else:  # FIFO 80 above the busy loop: the burn runs through (a kernel thread may get a rare switch in)
        assert switches <= 0.1, figures["involuntary"]
        assert figures["latency_ns"]["p50"] < 1_000_000, "a FIFO 80 timer callback starts well within a ms of its release"
    assert {t["comm"] for t in timer["threads"]} == {"exec0"}, "the executor thread the node named"
    # the runner's grid (from rcl_timer_init's hook) and the node's own (its clock before its first wait) are a few µs
    # apart, and both time the same callback starts: their mean latencies agree far closer than the effect above
    assert abs(figures["latency_ns"]["mean"] - own["latency"]["mean"]) < 100_000, (figures["latency_ns"], own["latency"])
    sub = next(c for c in cell["callbacks"] if c["kind"] == "subscription")
    assert sub["figures"]["callbacks"] == _own(node, "subscription")["count"], "every message the node's subscriber took"
    assert sub["figures"]["message_age_ns"]["count"] == sub["figures"]["callbacks"]


def _seed_installed() -> bool:
    """A ROS 2 host with the ros2-realtime-examples workspace sourced: `ros2 run minimal_scheduling ...` works."""
    if shutil.which("ros2") is None:
        return False
    return subprocess.run(["ros2", "pkg", "prefix", "minimal_scheduling"], capture_output=True, timeout=60).returncode == 0


SEED = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scenarios", "ros2")


@pytest.mark.skipif(not _seed_installed(), reason="needs a ROS 2 host with minimal_scheduling built and sourced (ros2 run)")
@pytest.mark.parametrize("name", sorted(f[:-5] for f in os.listdir(SEED)))
def test_the_seeds_own_program_passes_its_scenario(tmp_path, name: str) -> None:
    """On a ROS 2 host, each shipped seed scenario holds: its program unmodified, its callbacks judged from inside."""
    out = tmp_path / "out"
    done = finish(start_runner(os.path.join(SEED, f"{name}.yaml"), "--out", str(out), cwd=str(tmp_path)), str(out), timeout=120)
    assert done.results is not None, done.err
    for cell in done.results["cells"]:
        assert cell["callbacks"], f"{cell['id']}: no ROS 2 callback seen"
        assert cell["status"] == "passed", [v for v in cell["expectations"] if not v["passed"]]
