"""`runner.results/1` files: their shape as their readers checked it, and the upgrade to `runner.results/2`."""

from __future__ import annotations

import json
import math
from decimal import Decimal
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StrictBool,
    StrictFloat,
    StrictInt,
    StrictStr,
    field_validator,
)

from runner import figures as fg
from runner import units
from runner.results.document import SCHEMA, FigureName, Status
from runner.results.pstable import CLS
from runner.scenario.model import Policy

# ---------------------------------------------------------------- runner.results/1, read and upgraded
#
# The shape of a `runner.results/1` file, as its readers checked it: only what they used is
# typed; other keys pass.  `upgrade_v1` turns a file that passed into the /2 shape.

_Int = Annotated[StrictInt, Field(ge=-(2**63), le=2**63 - 1)]
_Count = Annotated[StrictInt, Field(ge=0, le=2**63 - 1)]
_Number = Annotated[StrictFloat, Field(ge=-1e18, le=1e18, allow_inf_nan=False)]  # takes ints too, never bools
_Cpus = Annotated[StrictStr | list[_Count], Field(union_mode="left_to_right")]


class _Open(BaseModel):
    model_config = ConfigDict(extra="allow")  # the Strict* types keep 1 from passing as "1" or True


class _V1Settings(_Open):
    policy: Policy
    priority: _Int
    nice: _Int
    cpus: _Cpus | None = None

    @field_validator("cpus")
    @classmethod
    def _cpus(cls, value: Any) -> Any:
        if value not in (None, "all"):
            try:
                units.parse_cpus(value)
            except units.UnitError as exc:
                raise ValueError(str(exc)) from None
        return value


class _V1Involuntary(_Open):
    total: _Count
    per_callback_mean: _Number | None
    per_callback_max: _Count | None
    callbacks_with_any: _Count | None


class _V1Faults(_Open):
    minor: _Count
    major: _Count
    minor_first_callback: _Count | None
    minor_after_first: _Count | None
    minor_per_callback_max: _Count | None


class _V1Voluntary(_Open):
    total: _Count


class _V1Thread(_Open):
    process: StrictStr
    instance: _Count
    index: _Count
    name: StrictStr
    pid: _Int
    tid: _Int
    work: StrictStr
    periodic: StrictBool
    requested: _V1Settings
    applied: _V1Settings | None
    degraded: list[StrictStr]
    complete: StrictBool
    callbacks: _Count
    missed_releases: _Count
    involuntary: _V1Involuntary
    voluntary: _V1Voluntary
    latency_us: dict[str, _Number | None] | None
    callback_wall_us: dict[str, _Number | None] | None
    faults: _V1Faults
    cpus_seen: list[Annotated[StrictInt, Field(ge=0, lt=8192)]]


class _V1Verdict(_Open):
    thread: StrictStr
    metric: FigureName
    limit: StrictStr
    measured: _Number | None
    passed: StrictBool
    note: StrictStr = ""


class _V1ThreadRow(_Open):
    pid: _Int
    tid: _Int
    comm: StrictStr
    cls: StrictStr
    rtprio: _Int
    nice: _Int
    psr: _Int
    cpus: _Cpus | None = None


class _V1Background(_Open):
    kind: StrictStr | None = None
    argv: list[StrictStr] = []


class _V1Throttling(_Open):
    runtime_us: _Number | None = None
    period_us: _Number | None = None


class _V1Machine(_Open):
    rt_throttling: _V1Throttling | None = None
    cpufreq_governors: list[StrictStr] | None = None
    memory_total_bytes: _Int | None = None


class _V1Permissions(_Open):
    rlimit_memlock: _Int | None = None
    missing: list[StrictStr] | None = None


class _V1Cell(_Open):
    id: StrictStr
    matrix: dict[str, Any]
    spec_hash: StrictStr
    status: Status
    spec: dict[str, Any] | None = None
    reason: StrictStr = ""
    started_at: StrictStr = ""
    duration_s: _Number = 0.0
    machine: _V1Machine | None = None
    thread_table: list[_V1ThreadRow] = []
    threads: list[_V1Thread] = []
    expectations: list[_V1Verdict] = []
    background: list[_V1Background] = []
    overhead_s: dict[str, _Number | None] | None = None
    samples_file: StrictStr | None = None
    repeat: Annotated[StrictInt, Field(ge=0, le=1_000_000)] = 0


class _V1Tool(_Open):
    version: StrictStr = "?"


class _V1Scenario(_Open):
    name: StrictStr = "scenario"


class _V1File(_Open):
    """A whole `runner.results/1` file."""

    schema_: Literal["runner.results/1"] = Field(alias="schema")
    tool: _V1Tool = _V1Tool()
    scenario: _V1Scenario
    command: list[StrictStr] = []
    started_at: StrictStr = ""
    finished_at: StrictStr | None = None
    status: StrictStr = "running"
    machine: _V1Machine | None = None
    permissions: _V1Permissions | None = None
    start_settings: dict[str, Any] | None = None
    cells: list[_V1Cell] = []
    cell_ids: list[StrictStr] | None = None
    matrix_cells: list[StrictStr] | None = None
    plan: dict[str, Any] | None = None
    shard: StrictStr | None = None
    merged_from: list[StrictStr] | None = None


def _scaled(value: Any, factor: int) -> Any:
    """A number of microseconds (factor 1000) or seconds (factor 10**9) as integer ns; anything else as it is.

    Exact for what runner/1 wrote (decimal fractions of a few digits): 58.366 us is 58366 ns.
    A value that is not a number is left for the /2 check to name.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return value
    if isinstance(value, int):
        return value * factor  # exact, however large: one past 64 bits is refused by the /2 check, in words
    if not math.isfinite(value):
        return value
    return int((Decimal(repr(value)) * factor).to_integral_value())


def _spread_ns(spread: Any) -> Any:
    """A /1 `latency_us`-style spread in ns; one with a figure that was not a number (stored null) is no spread."""
    if not isinstance(spread, dict):
        return spread
    if any(v is None for v in spread.values()):
        return None
    return {q: _scaled(v, 1000) for q, v in spread.items()}


def _nulls_out(data: dict[str, Any]) -> dict[str, Any]:
    """`data` without its null values: /1 wrote null for "none", /2 leaves those keys to their defaults."""
    return {k: v for k, v in data.items() if v is not None}


def _machine_v1(machine: Any) -> Any:
    if not isinstance(machine, dict):
        return machine
    out = _nulls_out(machine)
    throttle = out.get("rt_throttling")
    if isinstance(throttle, dict):
        out["rt_throttling"] = {
            "runtime_ns": _scaled(throttle["runtime_us"], 1000) if _positive(throttle.get("runtime_us")) else None,
            "period_ns": _scaled(throttle.get("period_us"), 1000),
            "enabled": throttle.get("enabled", _positive(throttle.get("runtime_us"))),
        }
    return out


def _positive(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and value >= 0


def _thread_v1(t: dict[str, Any]) -> dict[str, Any]:
    inv, faults = t["involuntary"], t["faults"]
    figures = {
        "callbacks": t["callbacks"],
        "missed_releases": t["missed_releases"],
        "involuntary": {k: inv[k] for k in ("total", "per_callback_mean", "per_callback_max", "callbacks_with_any")},
        "voluntary": {"total": t["voluntary"]["total"]},
        "latency_ns": _spread_ns(t["latency_us"]),
        "callback_wall_ns": _spread_ns(t["callback_wall_us"]),
        "faults": {k: faults[k] for k in ("minor", "major", "minor_first_callback", "minor_after_first", "minor_per_callback_max")},
        "cpus_seen": t["cpus_seen"],
        "complete": t["complete"],
    }
    same = ("process", "instance", "index", "name", "pid", "tid", "work", "periodic", "requested", "applied", "degraded")
    return {**{k: t[k] for k in same}, "figures": figures}


_POLICY_OF_CLS = {name: number for number, name in CLS.items()}


def _row_v1(row: dict[str, Any]) -> dict[str, Any]:
    return {
        "pid": row["pid"],
        "tid": row["tid"],
        "comm": row["comm"],
        "policy": _POLICY_OF_CLS.get(row["cls"], -1),
        "rtprio": row["rtprio"],
        "nice": row["nice"],
        "psr": row["psr"],
        "prio": None,
        "cpus": row.get("cpus") or "",
    }


def _verdict_v1(v: dict[str, Any]) -> dict[str, Any]:
    duration = fg.figure(v["metric"]).is_duration
    return {
        "thread": v["thread"],
        "metric": v["metric"],
        "limit": v["limit"],
        "measured": _scaled(v["measured"], 1000) if duration else v["measured"],
        "passed": v["passed"],
        "note": v.get("note", ""),
    }


def _cell_v1(c: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {k: c[k] for k in ("id", "matrix", "spec_hash", "status") if k in c}
    out.update(_nulls_out({k: c.get(k) for k in ("spec", "repeat", "reason", "started_at", "samples_file")}))
    out["duration_ns"] = _scaled(c.get("duration_s", 0), 10**9)
    if c.get("machine") is not None:
        out["machine"] = _machine_v1(c["machine"])
    out["thread_table"] = [_row_v1(r) for r in c.get("thread_table", [])]
    out["threads"] = [_thread_v1(t) for t in c.get("threads", [])]
    out["expectations"] = [_verdict_v1(v) for v in c.get("expectations", [])]
    out["background"] = [_nulls_out(b) for b in c.get("background", [])]
    out["overhead_ns"] = {k: _scaled(v, 10**9) for k, v in (c.get("overhead_s") or {}).items()}
    return out


def upgrade_v1(data: dict[str, Any]) -> dict[str, Any]:
    """A `runner.results/1` document (one that `_V1File` accepts) in the `runner.results/2` shape.  Pure.

    Latencies and callback times (float us) become integer ns under `figures`; verdicts on
    durations are measured in ns; the cell's duration, the overhead and the settle pause
    (seconds) become ns; RT throttling (us) becomes ns; ps rows name their policy by number.
    Keys /2 does not know are left for `load` to drop, as it drops a newer runner's.
    """
    data = json.loads(json.dumps(data))  # a copy that shares nothing, ten times faster than deepcopy on a JSON tree
    cells = data.get("cells", [])
    out = _nulls_out(
        {
            k: data.get(k)
            for k in (
                "tool",
                "scenario",
                "command",
                "started_at",
                "finished_at",
                "status",
                "shard",
                "merged_from",
                "permissions",
                "start_settings",
                "matrix_cells",
            )
        }
    )
    out["schema"] = SCHEMA
    out["tool"] = {"name": "runner", "version": (data.get("tool") or {}).get("version", "?")}
    if data.get("machine") is not None:
        out["machine"] = _machine_v1(data["machine"])
    if isinstance(out.get("permissions"), dict):
        out["permissions"] = _nulls_out(out["permissions"])
    out["cell_ids"] = data.get("cell_ids") or [c["id"] for c in cells]
    plan = dict(data.get("plan") or {})
    if "settle_s" in plan:
        plan["settle_ns"] = _scaled(plan.pop("settle_s"), 10**9)
    out["plan"] = plan
    out["cells"] = [_cell_v1(c) for c in cells]
    return out
