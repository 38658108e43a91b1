"""JSON Schema of the scenario format, for editors (yaml-language-server) and `runner schema`.

Generated from the typed models (runner.scenario.typed), then widened where the YAML accepts shorthands the models read
before validation (`sched: fifo:80`, `work: spin`, `count: cpus`, `events:` for one phase, and a
`${{ matrix.NAME }}` reference: as the whole value anywhere, inside the text of any value that takes
text), and narrowed where a model's validator checks what a schema can say too (names of 15 bytes
without spaces or control characters, fifo:1..99, a policy's own keys, matrix keys and values).

Every pattern is written in the subset of regular expressions that Python and JavaScript read alike
(no inline flags such as `(?i:...)`, which JavaScript refuses, and editors then report nothing or
"Invalid pattern"); tests/test_schema_editors.py checks the schema with ajv and with jsonschema
against `runner validate` on every shipped scenario and every file of the invalid corpus.
What needs arithmetic or a look at other keys (burn < period, runtime <= deadline <= period, a
thread named by an expectation, a value a matrix cell substitutes) is left to `runner validate`.
"""

from __future__ import annotations

from typing import Any

from runner import figures, units
from runner.scenario import matrix
from runner.scenario.model import (
    COMM_FORBIDS,
    COMM_MAX,
    POLICY_PATTERN,
    POLICY_WORDS,
    RESOURCE_NAME_WORDS,
    SCENARIO_NAME_WORDS,
    SCHED_FORMS,
    SCHED_PATTERN,
    SIGNED_DURATION_SCHEMA,
    Scenario,
    policy_pattern,
)
from runner.scenario.typed import json_schema, text_schema

SCHEMA_ID = "https://github.com/rt-scenario-runner/runner/runner.schema.json"
_NAME = r"[A-Za-z_][A-Za-z0-9_-]*"
_REFERENCE_WORDS = "a matrix value, ${{ matrix.NAME }}, NAME an axis of the matrix"
_WHOLE_REFERENCE = text_schema(rf"^\s*\$\{{\{{\s*matrix\.{_NAME}\s*\}}\}}\s*$", _REFERENCE_WORDS)
_TEXT_REFERENCE = text_schema(rf"\$\{{\{{\s*matrix\.{_NAME}\s*\}}\}}", _REFERENCE_WORDS)
# Control, format and separator characters a name or label may not hold (model.control_character): C0, DEL,
# C1, and the format and separator characters of the Basic Multilingual Plane that text can hide.  A fixed
# list, not unicodedata's, so the schema file is the same whatever Python's Unicode version.
_FORMATS = r"\x7f-\x9f\u00ad\u061c\u180e\u200b-\u200f\u2028-\u202e\u2060-\u206f\ufeff\ufff9-\ufffb"
_CONTROLS = r"\x00-\x1f" + _FORMATS
_CONTROLS_BUT_LINES = r"\x00-\x08\x0b-\x1f" + _FORMATS  # a description may have newlines and tabs
_LABEL = text_schema(f"^[^{_CONTROLS}]*$", "text without control characters")
_COMM = text_schema(
    rf"^[^\s/{_CONTROLS}]+$",
    f"a name without {COMM_FORBIDS}",
    minLength=1,
    maxLength=COMM_MAX,  # characters, where the kernel counts bytes: a name of accented letters can pass here
)
_NULL_OR = {"enum": [0, None]}


def _takes_text(node: Any, defs: dict[str, Any]) -> bool:
    """Whether a value of this schema can be text, so a `${{ matrix.X }}` inside longer text may stand for part of it."""
    if not isinstance(node, dict):
        return False
    types = node.get("type")
    if types == "string" or (isinstance(types, list) and "string" in types):
        return True
    if "$ref" in node:
        return _takes_text(defs.get(node["$ref"].rsplit("/", 1)[-1]), defs)
    return any(_takes_text(member, defs) for key in ("anyOf", "oneOf") for member in node.get(key, []))


def _allow_reference(node: Any, defs: dict[str, Any]) -> Any:
    """Let every property (and every item of a list of plain values) hold a `${{ matrix.X }}` reference."""
    if isinstance(node, list):
        return [_allow_reference(v, defs) for v in node]
    if not isinstance(node, dict):
        return node
    out = {k: v if k == "if" else _allow_reference(v, defs) for k, v in node.items()}  # a condition tests what is written

    def widened(prop: Any) -> Any:
        if not isinstance(prop, dict):
            return prop  # `true`: anything goes already
        refs = [_WHOLE_REFERENCE] + ([_TEXT_REFERENCE] if _takes_text(prop, defs) else [])
        return {"anyOf": [prop, *refs], **({"description": prop["description"]} if "description" in prop else {})}

    if isinstance(out.get("properties"), dict):
        out["properties"] = {name: widened(prop) for name, prop in out["properties"].items()}
    items = out.get("items")
    if isinstance(items, dict) and items.get("type") in ("integer", "number", "string"):
        out["items"] = widened(items)
    return out


def _standard(node: Any) -> Any:
    """The schema without pydantic's OpenAPI `discriminator` keyword, which is no JSON Schema keyword (ajv's strict mode refuses it)."""
    if isinstance(node, dict):
        return {k: _standard(v) for k, v in node.items() if k != "discriminator"}
    if isinstance(node, list):
        return [_standard(v) for v in node]
    return node


def _sched(defs: dict[str, Any]) -> None:
    """The text forms, and the mapping form's rules per policy (fifo and rr need 1..99, deadline a runtime, ...)."""
    mapping = defs["Sched"]
    props = mapping["properties"]
    words = props["policy"]["description"]
    props["policy"] = {"anyOf": [{"enum": POLICY_WORDS}, text_schema(POLICY_PATTERN, words)], "description": words}

    def when(names: tuple[str, ...], then: dict[str, Any]) -> dict[str, Any]:
        return {
            "if": {"properties": {"policy": {"type": "string", "pattern": policy_pattern(*names)}}, "required": ["policy"]},
            "then": then,
        }

    dl_keys = {"runtime": {"type": "null"}, "deadline": {"type": "null"}, "period": {"type": "null"}}
    mapping["allOf"] = [
        when(
            ("fifo", "rr"),
            {
                "required": ["priority"],
                "properties": {"priority": {"type": "integer", "minimum": 1, "maximum": 99}, "nice": {"type": "null"}, **dl_keys},
            },
        ),
        when(("other", "normal", "batch"), {"properties": {"priority": _NULL_OR, **dl_keys}}),
        when(("idle",), {"properties": {"priority": _NULL_OR, "nice": _NULL_OR, **dl_keys}}),
        when(("deadline",), {"required": ["runtime"], "properties": {"runtime": True, "priority": _NULL_OR, "nice": _NULL_OR}}),
    ]
    text = text_schema(SCHED_PATTERN, SCHED_FORMS, description=f"a policy as text: {SCHED_FORMS}")
    defs["Sched"] = {"anyOf": [text, mapping], "description": mapping.get("description", "")}


def _expectations(defs: dict[str, Any]) -> None:
    """Bounds in the metric's unit (a duration for latency, a number for counts), not negative unless the figure
    can be (slack), and at least one of max and min."""
    expectation = defs["Expectation"]
    by_kind: dict[tuple[bool, bool], dict[str, Any]] = {
        (True, False): text_schema(units.DURATION_PATTERN, units.DURATION_EXPECTED),
        (True, True): SIGNED_DURATION_SCHEMA,
        (False, False): {"type": "number", "minimum": 0},
        (False, True): {"type": "number"},
    }
    rules = []
    for (is_duration, signed), bound in by_kind.items():
        names = [f.name for f in figures.REGISTRY if f.is_duration == is_duration and f.signed == signed]
        if names:
            rules.append(
                {
                    "if": {"properties": {"metric": {"enum": names}}, "required": ["metric"]},
                    "then": {"properties": {"max": {"anyOf": [bound, {"type": "null"}]}, "min": {"anyOf": [bound, {"type": "null"}]}}},
                }
            )
    expectation["allOf"] = rules
    expectation["anyOf"] = [{"properties": {key: {"not": {"type": "null"}}}, "required": [key]} for key in ("max", "min")]


def _names(schema: dict[str, Any], defs: dict[str, Any]) -> None:
    """Names as the models check them: process and thread names as the kernel keeps them, labels without control characters."""
    for holder in ("ProcessSpec", "ThreadSpec", "Hog"):
        prop = defs[holder]["properties"]["name"]
        defs[holder]["properties"]["name"] = {**_COMM, **{k: v for k, v in prop.items() if k not in ("type",)}}
    label = defs["Command"]["properties"]["name"]
    label["anyOf"] = [_LABEL, {"type": "null"}]
    # no program can receive a NUL byte; an empty argv[0] is left to the model (a prefixItems tuple that
    # stays open is what ajv's strictTuples refuses)
    defs["Command"]["properties"]["argv"]["items"] = text_schema("^[^\\x00]*$", "an argument without a NUL byte")
    schema["properties"]["name"].update(text_schema(r"^[A-Za-z0-9_.+-]+$", SCENARIO_NAME_WORDS))
    schema["properties"]["description"].update(
        text_schema(f"^[^{_CONTROLS_BUT_LINES}]*$", "text without control characters but newlines and tabs")
    )
    schema["properties"]["resources"]["propertyNames"] = text_schema(
        r"^[A-Za-z_][A-Za-z0-9_.-]{0,63}$", f"a resource name of {RESOURCE_NAME_WORDS}"
    )


def _snippets(node: Any) -> Any:
    """The schema with each mapping among `examples` moved to `defaultSnippets`, labelled with its YAML flow form.

    yaml-language-server offers an example as a completion labelled with JavaScript's String() of it, which is
    `[object Object]` for a mapping; a snippet has a label of its own and inserts the same mapping.
    """
    if isinstance(node, list):
        return [_snippets(v) for v in node]
    if not isinstance(node, dict):
        return node
    out = {k: _snippets(v) for k, v in node.items()}
    examples = out.get("examples")
    if isinstance(examples, list) and any(isinstance(e, dict) for e in examples):
        import yaml

        out["examples"] = [e for e in examples if not isinstance(e, dict)]
        mappings = [e for e in examples if isinstance(e, dict)]
        labels = [yaml.safe_dump(e, default_flow_style=True, sort_keys=False, width=1 << 16).strip() for e in mappings]
        out["defaultSnippets"] = [*out.get("defaultSnippets", []), *({"label": t, "body": e} for t, e in zip(labels, mappings))]
    return out


def scenario_schema() -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of a scenario file."""
    schema = json_schema(Scenario)
    defs = schema["$defs"]
    phases = defs["PhasesWork"]  # `events:` directly under the work is its one phase: either key, not both
    phases["properties"]["events"] = {
        "type": "array",
        "items": {"$ref": "#/$defs/Event"},
        "minItems": 1,
        "description": "one phase's events",
    }
    phases["required"] = [r for r in phases.get("required", []) if r != "phases"]
    phases["oneOf"] = [{"properties": {key: True}, "required": [key]} for key in ("phases", "events")]
    _sched(defs)
    _names(schema, defs)
    _expectations(defs)
    kinds = {"type": "string", "enum": ["periodic", "spin", "sleep"]}
    for holder in ("MainThread", "ThreadSpec"):
        work = defs[holder]["properties"]["work"]
        defs[holder]["properties"]["work"] = {"anyOf": [kinds, {k: v for k, v in work.items() if k != "default"}]}
    defs["Hog"]["properties"]["count"] = {
        "anyOf": [defs["Hog"]["properties"]["count"], {"const": "cpus"}],
        "description": "how many hogs; 'cpus' for one per online CPU",
    }
    phases_only = {"type": "object", "properties": {"kind": {"const": "phases"}}, "required": ["kind"]}
    defs["ThreadSpec"]["allOf"] = [  # a spawned thread runs a program from the moment it is spawned
        {
            "if": {"properties": {"spawned": {"const": True}}, "required": ["spawned"]},
            "then": {"required": ["work"], "properties": {"work": phases_only}},
        }
    ]
    count = defs["ThreadSpec"]["properties"]["count"]
    defs["ThreadSpec"]["properties"]["count"] = {
        "anyOf": [{k: v for k, v in count.items() if k != "description"}, {"const": "cpus"}],
        "description": count["description"],
    }
    value = {
        "type": ["string", "number", "boolean"],
        "pattern": f"^[^{_CONTROLS}]*$",
        "patternErrorMessage": "expected a value without control characters",
        "maxLength": matrix.MAX_VALUE_CHARS,
        "not": {"type": "string", "pattern": r"\$\{\{"},
    }
    entries = {
        "type": "array",
        "items": {"type": "object", "minProperties": 1, "additionalProperties": value},
        "maxItems": matrix.MAX_ENTRIES,
    }
    schema["properties"]["matrix"] = {
        "type": "object",
        "description": "axes (lists of values), include and exclude, as GitHub Actions strategy.matrix",
        "properties": {"include": entries, "exclude": entries},
        "propertyNames": text_schema(rf"^{_NAME}$", f"an axis name: {matrix.KEY_WORDS}"),
        "maxProperties": matrix.MAX_KEYS,
        "additionalProperties": {"type": "array", "items": value, "minItems": 1},
    }
    schema = _snippets(_allow_reference(_standard(schema), defs))
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["$id"] = SCHEMA_ID
    schema["title"] = "runner scenario"
    schema["description"] = f"A scheduling scenario for the runner; policies: {SCHED_FORMS}"
    return schema
