"""The golden reports as GitHub shows them: rendered to HTML with GitHub's markdown CSS, measured in a real browser.

Each golden report (tests/golden) becomes an HTML page styled by `github-markdown-css` (npm, installed
by .ci/run into .ci/node_modules), its content column 1012 px wide as on a repository page, and
Debian's `chromium` loads it headless.  A script in the page measures every table and writes the
verdict into the DOM (`--dump-dom` prints it): GitHub's CSS makes a table a scrolling block, so a
table wider than the column is clipped and scrolls (scrollWidth > clientWidth).  A screenshot of each
page is written beside it (in $RUNNER_TEST_ARTIFACTS when set) for a person to look at.

Without chromium or the CSS the tests skip, except under CI, where they fail: .ci/run installs both.
"""

from __future__ import annotations

import html
import json
import os
import re
import shutil
import subprocess

import pytest
from markdown_it import MarkdownIt

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
GOLDEN = os.path.join(REPO, "tests", "golden")
CSS = os.path.join(REPO, ".ci", "node_modules", "github-markdown-css", "github-markdown-light.css")
COLUMN_PX = 1012  # GitHub's content column for a README or a markdown file at the default page width
REPORTS = sorted(name for name in os.listdir(GOLDEN) if name.endswith(".md"))

MEASURE = """
<script>
document.querySelectorAll("details").forEach(d => { d.open = true; });  // what a reader opens is measured too
const out = [...document.querySelectorAll("table")].map((t, i) => ({
  table: i,
  first: (t.querySelector("th") || {}).textContent || "",
  scroll: t.scrollWidth,
  client: t.clientWidth,
}));
const article = document.querySelector("article");
const wide = [...article.querySelectorAll("p, li, pre, summary, h1, h2, h3")]
  .filter(e => e.scrollWidth > e.clientWidth || e.getBoundingClientRect().right > article.getBoundingClientRect().right + 0.5)
  .map(e => e.tagName + ": " + e.textContent.slice(0, 80));
const pre = document.createElement("pre");
pre.id = "verdict";
pre.textContent = JSON.stringify({
  tables: out, wide: wide, article: [article.scrollWidth, article.clientWidth], height: document.documentElement.scrollHeight,
});
document.body.appendChild(pre);
</script>
"""


def _in_ci() -> bool:
    return os.environ.get("CI", "") not in ("", "0", "false")


def _browser() -> str:
    """Debian's chromium; skip without it (or the CSS), fail under CI, where .ci/run installs both."""
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    missing = [what for what, ok in (("chromium", found), ("github-markdown-css", os.path.exists(CSS))) if not ok]
    if missing:
        if _in_ci():
            pytest.fail(f"{' and '.join(missing)} not installed; .ci/run installs them (apt: chromium, npm: github-markdown-css)")
        pytest.skip(f"{' and '.join(missing)} not installed (apt-get install chromium; npm install --prefix .ci github-markdown-css)")
    assert found is not None
    return found


def page(markdown: str) -> str:
    """`markdown` as GitHub renders it: GFM tables (alignment from the `:` markers), GitHub's CSS, a 1012 px column."""
    body = MarkdownIt("commonmark", {"html": True}).enable(["table", "strikethrough"]).render(markdown)  # GitHub keeps <details>
    with open(CSS, encoding="utf-8") as handle:
        css = handle.read()
    return (
        "<!doctype html><html><head><meta charset='utf-8'><style>"
        + css
        + f".markdown-body {{ box-sizing: content-box; width: {COLUMN_PX}px; margin: 0; padding: 16px; }}"
        + "</style></head><body><article class='markdown-body'>"
        + body
        + "</article>"
        + MEASURE
        + "</body></html>"
    )


def chromium(browser: str, path: str, *args: str) -> str:
    done = subprocess.run(
        [browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", f"--window-size={COLUMN_PX + 32},900", *args],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        env={**os.environ, "HOME": os.path.dirname(path)},  # its profile and crash files go beside the page, not in ~
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout


def measure(browser: str, markdown: str, folder: str, name: str) -> dict[str, object]:
    """`markdown` as chromium lays it out, a collapsed `<details>` opened: every table (its first header, scrollWidth and
    clientWidth), the text blocks wider than the column (`wide`) and the column's own widths; a screenshot beside."""
    path = os.path.join(folder, f"{name}.html")
    with open(path, "w", encoding="utf-8") as handle:
        handle.write(page(markdown))
    dom = chromium(browser, path, "--dump-dom", f"file://{path}")
    found = re.search(r'<pre id="verdict">(.*?)</pre>', dom, re.S)
    assert found, dom[-2000:]
    verdict = json.loads(html.unescape(found.group(1)))
    height = min(int(verdict["height"]) + 40, 16_000)
    shot = os.path.join(os.environ.get("RUNNER_TEST_ARTIFACTS") or folder, f"{name}.png")
    os.makedirs(os.path.dirname(shot), exist_ok=True)
    chromium(browser, path, f"--screenshot={shot}", f"--window-size={COLUMN_PX + 32},{height}", f"file://{path}")
    assert os.path.getsize(shot) > 0
    return dict(verdict)


@pytest.mark.parametrize("name", REPORTS)
def test_no_table_of_a_golden_report_overflows_githubs_column(name, tmp_path):
    browser = _browser()
    with open(os.path.join(GOLDEN, name), encoding="utf-8") as handle:
        markdown = handle.read()
    seen = measure(browser, markdown, str(tmp_path), name.removesuffix(".md"))
    tables: list[dict[str, object]] = seen["tables"]  # type: ignore[assignment]
    parsed = MarkdownIt("commonmark").enable("table").parse(markdown)
    assert len(tables) == sum(tok.type == "table_open" for tok in parsed) > 0  # every table was measured
    clipped = [t for t in tables if int(t["scroll"]) > int(t["client"])]  # type: ignore[call-overload]
    assert not clipped, f"{name}: {len(clipped)} of {len(tables)} tables wider than {COLUMN_PX} px: " + "; ".join(
        f"table {t['table']} ({t['first']!r}): {t['scroll']} px" for t in clipped
    )


@pytest.mark.parametrize("name", REPORTS)
def test_nothing_of_a_golden_report_overflows_githubs_column(name, tmp_path):
    """Nor text: a code span of one long word, a line of a code block, the facts in their collapsed block (opened)."""
    browser = _browser()
    with open(os.path.join(GOLDEN, name), encoding="utf-8") as handle:
        seen = measure(browser, handle.read(), str(tmp_path), name.removesuffix(".md"))
    scroll, client = seen["article"]  # type: ignore[misc]
    assert not seen["wide"] and scroll <= client, f"{name}: wider than {COLUMN_PX} px: {seen['wide']} ({scroll} px)"


def test_the_measure_sees_text_too_wide_for_the_column_and_opens_a_collapsed_block(tmp_path):
    """The check can fail: a code block's line of 300 letters is wider than 1012 px, in a collapsed block too, and so is a
    table of one 300-letter word there.  (A code span or a word in a paragraph wraps: GitHub's CSS breaks long words.)"""
    browser = _browser()
    long_line = "```text\n" + "y" * 300 + "\n```\n"
    for markdown in (long_line, "<details>\n<summary>s</summary>\n\n" + long_line + "\n</details>\n"):
        assert measure(browser, markdown, str(tmp_path), "probe")["wide"], markdown
    table = "<details>\n<summary>s</summary>\n\n| a |\n|---|\n| `" + "z" * 300 + "` |\n\n</details>\n"
    found = measure(browser, table, str(tmp_path), "probe")["tables"]
    assert [int(t["scroll"]) > int(t["client"]) for t in found] == [True]  # type: ignore[call-overload,index,union-attr]


def test_the_measure_sees_a_table_too_wide_for_the_column(tmp_path):
    """The check can fail: fourteen columns of long unbroken words do not fit in 1012 px, four short ones do."""
    browser = _browser()
    wide = "| " + " | ".join(f"Involuntary_per_callback_{i}" for i in range(14)) + " |\n|" + "---:|" * 14 + "\n|" + " 1 |" * 14 + "\n"
    narrow = "| a | b | c | d |\n|---|--:|--:|--:|\n| x | 1 | 2 | 3 |\n"
    tables = measure(browser, wide + "\n" + narrow, str(tmp_path), "probe")["tables"]
    assert [int(t["scroll"]) > int(t["client"]) for t in tables] == [True, False]  # type: ignore[call-overload,index,union-attr]
