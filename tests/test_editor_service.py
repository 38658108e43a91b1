"""What an editor shows on a scenario file: yaml-language-server's language service, as VS Code's YAML extension runs it.

The service is driven by .ci/yamlls.cjs (installed from npm by .ci/run; these tests are skipped with the reason
where it is not, and fail in CI).  Each buffer is known by a path in scenarios/, as an editor knows the file it
edits, and no schema is configured: the schema checked against is the one the buffer's first-line modeline
names, read from disk.  Without the modeline an editor checks nothing, which is what five shipped scenarios did.
"""

from __future__ import annotations

import glob
import os
import re

from conftest import SCENARIOS, editor_answers

MODELINE = "# yaml-language-server: $schema=../runner.schema.json"
SHIPPED = sorted(glob.glob(os.path.join(SCENARIOS, "*.yaml")))
NEW = os.path.join(SCENARIOS, "new.yaml")  # a buffer not yet saved, beside the shipped ones
HEAD = f"{MODELINE}\nname: new\nprocesses:\n"


def test_every_shipped_scenario_names_the_schema_on_its_first_line():
    assert SHIPPED
    missing = [os.path.basename(p) for p in SHIPPED if open(p, encoding="utf-8").readline().rstrip("\n") != MODELINE]
    assert not missing, f"no `{MODELINE}` on the first line of: {', '.join(missing)}"


def _mistyped(text: str) -> str:
    """`text` with its top-level `duration:` key written `duraton:`."""
    typo, count = re.subn(r"^duration:", "duraton:", text, count=1, flags=re.MULTILINE)
    assert count == 1
    return typo


def test_a_mistyped_key_in_every_shipped_scenario_is_underlined_at_its_line(tmp_path):
    texts = {path: open(path, encoding="utf-8").read() for path in SHIPPED}
    requests: list[dict[str, object]] = []
    for path, text in texts.items():
        typo = _mistyped(text)
        bare = "".join(typo.splitlines(keepends=True)[1:])  # the modeline left out: the editor knows no schema
        requests += [{"file": path, "text": text}, {"file": path, "text": typo}, {"file": path, "text": bare}]
    answers = iter(editor_answers(requests, tmp_path))
    wrong = []
    for path, text in texts.items():
        name = os.path.basename(path)
        as_written, typo, bare = (next(answers)["diagnostics"] for _ in range(3))
        line = next(i for i, x in enumerate(_mistyped(text).splitlines()) if x.startswith("duraton:"))
        if as_written:
            wrong.append(f"{name} as shipped: {as_written}")
        if [(d["line"], "duraton" in d["message"]) for d in typo] != [(line, True)]:
            wrong.append(f"{name} with duraton: {typo}")
        if bare:
            wrong.append(f"{name} without its modeline is checked against something: {bare}")
    assert not wrong, "\n".join(wrong)
