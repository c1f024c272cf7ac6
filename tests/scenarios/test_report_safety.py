"""report.md and report.html are shared: a suite name, a scenario name, a planner's stage names
or its stderr must not reach them as markup. Each attack is planted in a hand-made SuiteResult
(no rollout needed); report.html is parsed with lxml and every element and attribute checked:
no script, no event handler, no javascript: URL, no local file inlined, every src a data: URL
of a file the rollout wrote, a strict Content-Security-Policy."""
from __future__ import annotations

import base64
import os
import re

os.environ.setdefault("MPLBACKEND", "Agg")

import lxml.html
import pytest

from feat2map.scenarios.markup import md_code, md_fenced, md_text, written_file
from feat2map.scenarios.report import report_html, report_markdown, write_report
from feat2map.scenarios.rollout import Outcome, SuiteResult

GIF = b"GIF89a\x01\x00\x01\x00\x80\x00\x00\x00\x00\x00\xff\xff\xff!\xf9\x04\x01\x00\x00\x00\x00,\x00\x00\x00\x00" \
      b"\x01\x00\x01\x00\x00\x02\x02D\x01\x00;"
SECRET = b"TOP-SECRET-7f3a9c token=hunter2\n"
CSP = "default-src 'none'; img-src data:; style-src 'unsafe-inline'"


@pytest.fixture()
def secret(tmp_path):
    path = tmp_path / "secret.txt"
    path.write_bytes(SECRET)
    return path


def _attacks(secret) -> dict[str, str]:
    return {
        "script": "<script>alert(1)</script>",
        "md image": f"![x]({secret})",
        "md image up": "![x](../secret.txt)",
        "md link": f"[click]({secret})",
        "javascript link": "[go](javascript:alert(1))",
        "autolink": "<javascript:alert(1)>",
        "handler": '<img src=x onerror="alert(1)"><b onmouseover=alert(1)>b</b>',
        "html block": '\n<div onclick="alert(1)">\n<iframe src="javascript:alert(1)"></iframe>\n</div>\n',
        "code span": "`</code><script>alert(1)</script>`",
        "fence": "\n```\n</pre><script>alert(1)</script>\n```\n",
        "table": "| <script>alert(1)</script> |",
    }


def _result(secret, gif: bytes | None = GIF) -> SuiteResult:
    a = _attacks(secret)
    everything = " ".join(a.values())
    stderr = "\n".join(f"  {k}: {v}" for k, v in a.items())
    outcomes = (
        Outcome(f"sc {a['script']} {a['md image']}", "error", {"<b onclick=x>kind</b>": 1}, 1.0, 5,
                ("LF", a["handler"]), (("LF", a["handler"]),), (a["javascript link"],), 0.5,
                message=f"planner raised: planner stderr:\n{stderr}", map=str(secret), gif=gif),
        Outcome(f"two {a['md link']} {a['html block']}", "violation", {"red_light": 1}, 2.0, 9, ("LF",), (),
                (a["md image up"],), 0.2, message=everything, events=((1, 0.2, a["table"], "SC", a["code span"]),),
                gif=gif),
        Outcome("fine", "completed", {}, 3.0, 15, ("LF",), (), ("J0",), 1.0),
    )
    return SuiteResult(f"s {a['md image']} {a['script']}", f"planner {a['code span']}", outcomes,
                       stopped=f"stopped {a['fence']} {a['autolink']}", scenarios=4)


def _check_page(page: str, folder, written: set[str]) -> lxml.html.HtmlElement:
    """Every element and attribute of the page: nothing active, nothing from outside the folder."""
    assert "<script" not in page.lower() and SECRET.decode().strip() not in page
    assert base64.b64encode(SECRET).decode() not in page
    doc = lxml.html.document_fromstring(page)
    metas = doc.xpath("//meta[@http-equiv='Content-Security-Policy']")
    assert len(metas) == 1 and metas[0].get("content").startswith(CSP)
    assert metas[0].getparent().tag == "head" and not doc.xpath("//script|//iframe|//object|//embed|//base|//form")
    assert len(doc.xpath("//style")) == 1 and doc.xpath("//style")[0].getparent().tag == "head"
    for el in doc.iter():
        if not isinstance(el.tag, str):
            continue
        for name, value in el.attrib.items():
            assert not name.lower().startswith("on"), (el.tag, name, value)
            assert "javascript:" not in value.lower().replace(" ", ""), (el.tag, name, value)
            if name in ("src", "href", "srcset", "action", "formaction", "xlink:href", "background", "poster"):
                assert name in ("src", "href"), (el.tag, name)
                if name == "src":
                    assert re.fullmatch(r"data:image/(png|gif);base64,[A-Za-z0-9+/=]+", value), value[:80]
                else:
                    assert value in written, value
    return doc


def test_attacks_in_names_and_stderr_reach_neither_report_as_markup(tmp_path, secret):
    out = write_report(_result(secret), tmp_path / "rep", fail_on="any")
    written = {str(p.relative_to(out)) for p in out.rglob("*") if p.is_file()}
    assert {"outcomes.png", "coverage.png"} <= written and len([w for w in written if w.startswith("failures/")]) == 2
    page = (out / "report.html").read_text()
    doc = _check_page(page, out, written)
    srcs = [img.get("src") for img in doc.iter("img")]
    assert len(srcs) == 4  # outcomes, two failure GIFs, coverage: the rollout's own pictures, inlined
    assert srcs.count("data:image/gif;base64," + base64.b64encode(GIF).decode()) == 2
    assert not doc.xpath("//a[@href]")  # the report links nowhere
    text = doc.text_content()
    # the attacks are shown as the text they are, not deleted
    assert "<script>alert(1)</script>" in text and f"![x]({secret})" in text and "[go](javascript:alert(1))" in text
    assert "onerror=\"alert(1)\"" in text and "</pre><script>alert(1)</script>" in text
    for f in out.rglob("*"):  # the secret is in no file the rollout wrote
        if f.is_file():
            assert SECRET.strip() not in f.read_bytes() and base64.b64encode(SECRET) not in f.read_bytes()


def _outside_fences(md: str) -> str:
    """The Markdown without its fenced code blocks (shown verbatim, never as markup)."""
    out, fence = [], None
    for line in md.splitlines():
        if fence is None and re.fullmatch(r"`{3,}", line):
            fence = line
        elif fence is not None and line == fence:
            fence = None
        elif fence is None:
            out.append(line)
    assert fence is None, "a code block left open"
    return "\n".join(out)


def test_report_md_keeps_names_literal(secret):
    """In report.md (read on GitHub, GitLab, in editors) no name opens an image, a link or raw HTML."""
    full = report_markdown(_result(secret), "any", {})
    md = _outside_fences(full)
    assert "  script: <script>alert(1)</script>" in full  # stderr verbatim, in a code block
    assert "<script" not in md and "<img" not in md and "<div" not in md and "<iframe" not in md
    assert not re.search(r"(?<!\\)!\[[^\]]*\]\((?!outcomes\.png|coverage\.png|failures/)", md)
    assert not re.search(r"(?<!\\)\[[^\]]*\]\((javascript|/|\.\.)", md)
    for line in md.splitlines():  # a table row keeps its columns: no name adds a cell
        if line.startswith("| sc ") or line.startswith("| two "):
            assert len(re.findall(r"(?<!\\)\|", line)) == 9, line


def test_raw_markdown_attacks_and_files_outside_the_rollout_are_not_embedded(tmp_path, secret):
    """report_html itself, on Markdown written by anyone: raw HTML is text, and only files the
    rollout wrote (the allow-list) are inlined: no absolute path, no `..`, no symlink out."""
    folder = tmp_path / "rep"
    (folder / "failures").mkdir(parents=True)
    (folder / "failures" / "ok.gif").write_bytes(GIF)
    (folder / "failures" / "link.gif").symlink_to(secret)
    (folder / "inside.gif").write_bytes(GIF)  # in the folder, not written by the rollout
    a = _attacks(secret)
    md = "\n\n".join([*a.values(), "![ok](failures/ok.gif)", "![l](failures/link.gif)", "![i](inside.gif)",
                      f"![abs]({secret})", "![up](failures/../../secret.txt)", f"[file]({secret})",
                      "[ok](failures/ok.gif)", '<a href="javascript:alert(1)">x</a>'])
    files = {"failures/ok.gif", "failures/link.gif", str(secret), "failures/../../secret.txt"}
    page = report_html(md, folder, "t <script>alert(1)</script>", files)
    doc = _check_page(page, folder, {"failures/ok.gif"})
    assert [img.get("alt") for img in doc.iter("img")] == ["ok"]
    assert [x.get("href") for x in doc.iter("a") if x.get("href")] == ["failures/ok.gif"]
    assert doc.findtext(".//title") == "t <script>alert(1)</script>"


def test_written_file_refuses_paths_out_of_the_folder(tmp_path, secret):
    folder = tmp_path / "rep"
    folder.mkdir()
    (folder / "a.png").write_bytes(b"png")
    (folder / "s.png").symlink_to(secret)
    (folder / "d").symlink_to(tmp_path, target_is_directory=True)
    allowed = {"a.png", "s.png", "d/secret.txt", "../secret.txt", str(secret), "missing.png"}
    assert written_file(folder, "a.png", allowed) == folder / "a.png"
    for rel in ("s.png", "d/secret.txt", "../secret.txt", str(secret), "missing.png", "b.png"):
        assert written_file(folder, rel, allowed) is None, rel


def test_markdown_helpers():
    assert md_text("a|b [x](y) `c` <i> & *e* _f_ S_PS\nnext") == \
        r"a\|b \[x\](y) \`c\` &lt;i&gt; &amp; \*e\* \_f\_ S_PS next"
    assert md_code("T_A") == "`T_A`" and md_code("a`b") == r"a\`b" and md_code("<i>") == "&lt;i&gt;"
    assert md_fenced("x\n```\ny") == ["````", "x", "```", "y", "````"]
