"""JSON Schema of the scenario format, for editors (yaml-language-server) and `runner schema`.

Generated from the pydantic models, then widened where the YAML accepts shorthands
the models read before validation: `sched: fifo:80`, `work: spin`, `count: cpus` (hogs and threads),
and a `${{ matrix.NAME }}` reference in place of any value.
"""

from __future__ import annotations

import copy
from typing import Any

from runner.scenario.model import POLICY_WORDS, Scenario

SCHEMA_ID = "https://github.com/rt-scenario-runner/runner/runner.schema.json"
_REFERENCE = {"type": "string", "pattern": r"^\s*\$\{\{\s*matrix\.[A-Za-z_][A-Za-z0-9_-]*\s*\}\}\s*$"}
_SCHED_STRING = {
    "type": "string",
    "pattern": r"^((?i:(sched_)?(other|normal|batch|idle|fifo|rr))(:\d+)?"
    r"|(?i:(sched_)?deadline)(:[0-9.]+\s*(ns|us|µs|ms|s)(/[0-9.]+\s*(ns|us|µs|ms|s)){0,2})?)$",
    "description": "policy, optionally with RT priority: fifo:80, SCHED_RR, other; deadline:RUNTIME/DEADLINE/PERIOD",
}


def _allow_reference(node: Any) -> Any:
    """Let every property also hold a `${{ matrix.X }}` reference."""
    if isinstance(node, dict):
        out = {k: _allow_reference(v) for k, v in node.items()}
        if "properties" in out:
            out["properties"] = {
                name: {"anyOf": [prop, _REFERENCE], **({"description": prop["description"]} if "description" in prop else {})}
                for name, prop in out["properties"].items()
            }
        return out
    if isinstance(node, list):
        return [_allow_reference(v) for v in node]
    return node


def scenario_schema() -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of a scenario file."""
    schema = copy.deepcopy(Scenario.model_json_schema(mode="validation"))
    defs = schema["$defs"]
    phases = defs["PhasesWork"]  # `events:` directly under the work is its one phase: either key, not both
    phases["properties"]["events"] = {
        "type": "array",
        "items": {"$ref": "#/$defs/Event"},
        "minItems": 1,
        "description": "one phase's events",
    }
    phases["required"] = [r for r in phases.get("required", []) if r != "phases"]
    phases["oneOf"] = [{"required": ["phases"]}, {"required": ["events"]}]
    defs["Sched"] = {"anyOf": [_SCHED_STRING, defs["Sched"]], "description": defs["Sched"].get("description", "")}
    kinds = {"type": "string", "enum": ["periodic", "spin", "sleep"]}
    for holder in ("MainThread", "ThreadSpec"):
        work = defs[holder]["properties"]["work"]
        defs[holder]["properties"]["work"] = {"anyOf": [kinds, {k: v for k, v in work.items() if k != "default"}]}
    defs["Hog"]["properties"]["count"] = {
        "anyOf": [defs["Hog"]["properties"]["count"], {"const": "cpus"}],
        "description": "how many hogs; 'cpus' for one per online CPU",
    }
    count = defs["ThreadSpec"]["properties"]["count"]
    defs["ThreadSpec"]["properties"]["count"] = {
        "anyOf": [{k: v for k, v in count.items() if k != "description"}, {"const": "cpus"}],
        "description": count["description"],
    }
    schema["properties"]["matrix"] = {
        "type": "object",
        "description": "axes (lists of values), include and exclude, as GitHub Actions strategy.matrix",
        "properties": {
            "include": {"type": "array", "items": {"type": "object"}},
            "exclude": {"type": "array", "items": {"type": "object"}},
        },
        "additionalProperties": {"type": "array", "items": {"type": ["string", "number", "boolean"]}, "minItems": 1},
    }
    schema = _allow_reference(schema)
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["$id"] = SCHEMA_ID
    schema["title"] = "runner scenario"
    schema["description"] = f"A scheduling scenario for the runner; policies: {', '.join(POLICY_WORDS)}"
    return schema
