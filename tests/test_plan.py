"""Expected settings follow Linux inheritance: creator's settings at creation time, explicit opt-out, own settings."""

from __future__ import annotations

from runner.scenario.model import Policy, ProcessSpec
from runner.scenario.plan import Settings, plan_process

BASE = Settings(Policy.OTHER, 0, 0, None)


def proc(**kw) -> ProcessSpec:
    return ProcessSpec.parse({"name": "p", **kw})


def test_before_threads_everything_inherits():
    p = proc(main={"sched": "fifo:80", "cpus": [1], "apply": "before_threads"}, threads=[{"name": "a"}, {"name": "b", "count": 2}])
    plan = plan_process(p, BASE)
    assert [t.name for t in plan] == ["p", "a", "b-0", "b-1"]
    assert all(t.settings == Settings(Policy.FIFO, 80, 0, (1,)) for t in plan)


def test_after_threads_nothing_inherits():
    p = proc(main={"sched": "rr:50", "apply": "after_threads"}, threads=[{"name": "a"}])
    main, a = plan_process(p, BASE)
    assert (main.settings.policy, main.settings.priority) == (Policy.RR, 50)
    assert a.settings == BASE and a.origin == "inherited"


def test_own_settings_on_top_of_what_was_inherited():
    p = proc(main={"sched": {"policy": "other", "nice": 5}, "cpus": "0"}, threads=[{"name": "rt", "sched": "fifo:90"}])
    _, rt = plan_process(p, BASE)
    assert rt.settings == Settings(Policy.FIFO, 90, 5, (0,)) and rt.origin == "own"


def test_explicit_defaults_opt_out():
    p = proc(
        main={"sched": "fifo:80", "cpus": [1]}, threads=[{"name": "x", "inherit": False}, {"name": "y", "inherit": False, "sched": "batch"}]
    )
    _, x, y = plan_process(p, BASE)
    assert x.settings == Settings() and x.origin == "explicit"
    assert y.settings == Settings(Policy.BATCH, 0, 0, None) and y.origin == "explicit+own"


def test_processes_inherit_from_the_runner_unless_reset_on_fork():
    runner_under_chrt = Settings(Policy.FIFO, 50, -5, None)
    assert plan_process(proc(), runner_under_chrt)[0].settings == runner_under_chrt
    reset = plan_process(proc(reset_on_fork=True), runner_under_chrt)[0].settings
    assert reset == Settings(Policy.OTHER, 0, 0, None)
