"""Report text that cannot inject: names, messages and planner stderr as literal Markdown
(`md_text`, `md_code`, `md_fenced`), and a Markdown report as one self-contained HTML page
(`html_page`) that embeds only files the rollout wrote and passes a strict Content-Security-Policy.
Reports get shared, and a suite name, a scenario name or a planner's stderr is whatever its
author wrote: none of them may open a link, load a local file or run a script.
"""
from __future__ import annotations

import base64
import html
import mimetypes
import re
from pathlib import Path, PurePosixPath
from typing import Collection

from feat2map.config import REPORT_CSP
from feat2map.messages import printable

# what Python-Markdown's own backslash escapes cover and a name could misuse: code spans, link
# and image brackets, table cells, headings, emphasis (an underscore only where it can open or
# close one: ids like S_PS stay readable); < > & become HTML entities instead
_MD_SPECIAL = re.compile(r"[\\`*\[\]|#]|(?<!\w)_|_(?!\w)")
_PLAIN_CODE = re.compile(r"[\w .,:;()→+-]+")  # shown as a code span as is
# the elements and attributes the Markdown report produces; anything else is dropped from the page
ALLOWED_TAGS = frozenset({"h1", "h2", "h3", "h4", "h5", "h6", "p", "br", "hr", "strong", "em", "code", "pre",
                          "table", "thead", "tbody", "tr", "th", "td", "ul", "ol", "li", "blockquote", "img", "a"})
_ALLOWED_ATTRS = {"img": {"src", "alt", "title"}, "a": {"href", "title"}, "th": {"style"}, "td": {"style"}}
_ALIGN_STYLE = re.compile(r"text-align: (left|right|center);")  # the tables extension's column alignment
_CSS = ("body{font-family:system-ui,sans-serif;max-width:75em;margin:2em auto;padding:0 1em;line-height:1.4}"
        "table{border-collapse:collapse;margin:1em 0}th,td{border:1px solid #ccc;padding:.2em .5em;"
        "vertical-align:top}th{background:#f3f3f3}img{max-width:100%}code,pre{background:#f6f6f6}"
        "pre{padding:.5em;overflow-x:auto}")


def md_text(text: object) -> str:
    """`text` as literal inline Markdown on one line: whitespace runs become one space, control
    characters their escapes, Markdown punctuation backslash-escaped and < > & " ' entities."""
    s = printable(re.sub(r"\s+", " ", str(text)).strip())
    return html.escape(_MD_SPECIAL.sub(lambda m: "\\" + m.group(0), s))


def md_code(text: object) -> str:
    """`text` as an inline code span where it is a plain code (letters, digits, `_ .,:;()→+-`),
    else as `md_text`: any other character (a backtick, a pipe, < > [ ] ...) could end the span,
    split a table cell or be read as markup by a less strict reader."""
    s = printable(re.sub(r"\s+", " ", str(text)).strip())
    return f"`{s}`" if _PLAIN_CODE.fullmatch(s) else md_text(s)


def md_fenced(text: object) -> list[str]:
    """`text` as a fenced code block, one Markdown line per line of it (control characters as
    escapes); the fence is longer than any run of backticks inside, so no line can close it."""
    lines = [printable(ln) for ln in str(text).splitlines()] or [""]
    fence = "`" * max(3, 1 + max((len(r) for r in re.findall(r"`+", "\n".join(lines))), default=0))
    return [fence, *lines, fence]


def written_file(folder: Path, rel: str, files: Collection[str]) -> Path | None:
    """The file `rel` names inside `folder`, if it is one of `files` (those the rollout wrote)
    and stays inside `folder`: no absolute path, no `..`, no symlink; else None."""
    p = PurePosixPath(rel)
    if rel not in files or p.is_absolute() or ".." in p.parts or "\\" in rel or ":" in rel:
        return None
    path = folder.joinpath(*p.parts)
    root = folder.resolve()
    if path.is_symlink() or not path.is_file() or not path.resolve().is_relative_to(root):
        return None
    return path


def _data_url(path: Path) -> str:
    kind = mimetypes.guess_type(path.name)[0] or "application/octet-stream"
    return f"data:{kind};base64,{base64.b64encode(path.read_bytes()).decode()}"


def _clean(body: str, folder: Path, files: Collection[str]) -> str:
    """The page body with only ALLOWED_TAGS and their attributes: pictures among `files` inlined
    as data: URLs (others removed), links kept only to `files`, every other attribute dropped."""
    import lxml.html

    root = lxml.html.fragment_fromstring(body or "<p></p>", create_parent="div")
    for el in list(root.iter()):
        if el is root or not isinstance(el.tag, str):  # comments and processing instructions
            if el is not root:
                el.drop_tree()
            continue
        if el.tag not in ALLOWED_TAGS:
            el.drop_tree()  # with its content: a <script> or <style> body is no report text
            continue
        allowed = _ALLOWED_ATTRS.get(el.tag, set())
        for name, value in list(el.attrib.items()):
            if name not in allowed or (name == "style" and not _ALIGN_STYLE.fullmatch(value)):
                del el.attrib[name]
        if el.tag == "img":
            path = written_file(folder, el.get("src", ""), files)
            if path is None:
                el.drop_tree()
            else:
                el.set("src", _data_url(path))
        elif el.tag == "a" and "href" in el.attrib and written_file(folder, el.get("href", ""), files) is None:
            del el.attrib["href"]
    inner = (root.text and html.escape(root.text, quote=False) or "")
    return inner + "".join(lxml.html.tostring(child, encoding="unicode") for child in root)


def html_page(markdown_text: str, folder: Path, title: str, files: Collection[str] = ()) -> str:
    """The Markdown report as one self-contained HTML page: raw HTML in the Markdown is shown as
    text, pictures among `files` (paths relative to `folder` that the rollout wrote) are inlined
    as base64 data, and the page's Content-Security-Policy (REPORT_CSP) lets it load and run
    nothing else, so it can be mailed or attached to a CI run on its own."""
    import markdown

    md = markdown.Markdown(extensions=["tables", "fenced_code"], output_format="html")
    md.preprocessors.deregister("html_block")  # raw HTML blocks and inline tags stay text
    md.inlinePatterns.deregister("html")
    body = _clean(md.convert(markdown_text), folder, files)
    return (f'<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
            f'<meta http-equiv="Content-Security-Policy" content="{html.escape(REPORT_CSP)}">\n'
            f"<title>{html.escape(title)}</title>\n<style>{_CSS}</style>\n</head>\n<body>\n{body}\n</body>\n</html>\n")
