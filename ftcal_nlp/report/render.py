"""The report's building blocks and their two renderings, Markdown (``report.md``) and HTML (``report.html``).

A :class:`Section` is a title and an ordered list of blocks: paragraphs
(:class:`Text`), labelled tables (:class:`Table`), stage summaries
(:class:`~ftcal_nlp.core.results.Summary`), preformatted text (:class:`Code`),
bullet lists (:class:`Bullets`) and figures (:class:`Figure`).

Paragraph text uses two inline marks only, written as in Markdown:
``` `code` ``` and ``**bold**``. Markdown keeps them (and escapes a lone ``*``,
as in ``N*m``, so it is not read as emphasis); HTML turns them into ``<code>``
and ``<b>`` after escaping, so neither backticks nor asterisks reach the page.
The legacy ``+-`` is written ``±`` (the package's one value-and-error style,
:func:`ftcal_nlp.core.results.fmt_pm`).
"""

from __future__ import annotations

import base64
import html
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from ..core.results import PM, Summary

__all__ = ["Text", "Table", "Code", "Bullets", "Definitions", "Figure", "Section", "render_markdown", "render_html", "bold_md",
           "inline_html", "inline_md", "plain", "md_table", "html_table", "cell"]

_CODE = re.compile(r"`([^`]+)`")
_BOLD = re.compile(r"\*\*(.+?)\*\*")


def plain(text: str) -> str:
    """Text with the legacy ``+-`` as ``±``."""
    return re.sub(r"\s*\+-\s*", f" {PM} ", str(text))


def inline_html(text: str) -> str:
    """Escape ``text`` for HTML and turn ``code`` / **bold** marks into ``<code>`` / ``<b>``."""
    parts = re.split(r"(`[^`]+`)", plain(text))
    out = []
    for p in parts:
        m = _CODE.fullmatch(p)
        if m:
            out.append(f"<code>{html.escape(m.group(1))}</code>")
        else:
            out.append(_BOLD.sub(r"<b>\1</b>", html.escape(p)))
    return "".join(out)


_LONE_STAR = re.compile(r"(?<![*\\])\*(?!\*)")


def inline_md(text: str, *, escape_all: bool = False) -> str:
    """Markdown text: code spans and ``**`` kept; lone ``*`` (``N*m``) escaped where two of them could pair
    into emphasis (or always, ``escape_all``, for text inside emphasis marks)."""
    parts = [p if _CODE.fullmatch(p) else md_escape(p) for p in re.split(r"(`[^`]+`)", plain(text))]
    if not escape_all and sum(len(_LONE_STAR.findall(p)) for p in parts if not _CODE.fullmatch(p)) < 2:
        return "".join(parts)
    return "".join(p if _CODE.fullmatch(p) else _LONE_STAR.sub(r"\\*", p) for p in parts)


_MD_TAG = re.compile(r"<(?=[A-Za-z/!?])")                       # what could open raw HTML or an autolink
_MD_ENTITY = re.compile(r"&(?=#[0-9]{1,7};|#[xX][0-9a-fA-F]{1,6};|[A-Za-z][A-Za-z0-9]*;)")  # what would be read as one
_MD_QUOTE = re.compile(r"^([ \t]*)>", re.MULTILINE)               # a block quote at a line's start


def md_escape(text: str) -> str:
    """Text outside code spans with what Markdown would read as markup backslash-escaped (CommonMark): a ``<``
    that could open raw HTML or an autolink, an ``&`` that would be read as an entity, a ``>`` opening a line.
    Names in a report (legs, recordings, effects) come from data files, so none of them may become markup;
    everything else (``->``, ``a < b``, ``R&D``) is left as written: no HTML entity in ``report.md``."""
    return _MD_QUOTE.sub(r"\1\\>", _MD_ENTITY.sub(r"\\&", _MD_TAG.sub(r"\\<", text)))


def _md_destination(name: str) -> str:
    """A link destination in angle brackets: ``<``, ``>`` and ``\\`` backslash-escaped (CommonMark)."""
    return "<" + re.sub(r"([<>\\])", r"\\\1", name) + ">"


def _fence(text: str) -> str:
    """A code fence longer than any run of backticks in ``text`` (so that the text cannot close it)."""
    runs = re.findall(r"`+", text)
    return "`" * max(3, 1 + max(map(len, runs), default=0))


def bold_md(text: str) -> str:
    return f"**{inline_md(text, escape_all=True)}**"


def cell(v) -> str:
    """A table cell as text: floats to 4 significant digits, NaN/inf as ``n/a``."""
    if isinstance(v, (float, np.floating)):
        return f"{v:.4g}" if np.isfinite(v) else "n/a"
    if v is None:
        return ""
    return plain(str(v))


def _index_name(df: pd.DataFrame) -> str:
    return "" if df.index.name is None else str(df.index.name)


def md_table(df: pd.DataFrame) -> str:
    """A Markdown table with the index (row labels) as its first column."""
    def esc(s: str) -> str:
        return inline_md(s).replace("|", "\\|")

    cols = [_index_name(df)] + [str(c) for c in df.columns]
    lines = ["| " + " | ".join(esc(c) for c in cols) + " |", "|:---|" + "|".join("---:" for _ in cols[1:]) + "|"]
    for i, r in zip(df.index, df.itertuples(index=False)):
        lines.append("| " + " | ".join(esc(x) for x in [str(i)] + [cell(v) for v in r]) + " |")
    return "\n".join(lines) + "\n"


def html_table(df: pd.DataFrame, highlight: str | None = None) -> str:
    """An HTML table with the index as row headers; the row labelled ``highlight`` in bold."""
    head = "".join(f"<th>{html.escape(plain(c))}</th>" for c in [_index_name(df), *map(str, df.columns)])
    rows = []
    for i, r in zip(df.index, df.itertuples(index=False)):
        cls = " class='sel'" if highlight is not None and str(i) == highlight else ""
        rows.append(f"<tr{cls}><th>{html.escape(plain(i))}</th>" + "".join(_td(cell(v)) for v in r) + "</tr>")
    return f"<div class='scroll'><table class='tbl'><thead><tr>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table></div>"


def _td(text: str) -> str:
    # words in a cell (a status, a note): left-aligned and allowed to wrap; numbers stay on one line
    cls = " class='txt'" if len(text) > 24 and re.search(r"[A-Za-z_]{4,}", text.replace("fixed", "")) else ""
    return f"<td{cls}>{html.escape(text)}</td>"


@dataclass
class Text:
    text: str


@dataclass
class Table:
    caption: str
    df: pd.DataFrame
    highlight: str | None = None   # row label shown in bold (the selected model)


@dataclass
class Code:
    text: str


@dataclass
class Bullets:
    items: list[str]


@dataclass
class Definitions:
    """Terms and their meaning (the notation list)."""

    items: list[tuple[str, str]]


@dataclass
class Figure:
    name: str
    path: Path | None       # None: not drawn (the log says why)
    caption: str = ""


@dataclass
class Section:
    """A titled part of the report; ``blocks`` render in order."""

    title: str
    blocks: list = field(default_factory=list)

    def add(self, block) -> "Section":
        self.blocks.append(block)
        return self

    # views by kind (tests, callers that only want one kind)
    @property
    def text(self) -> list[str]:
        return [b.text for b in self.blocks if isinstance(b, Text)]

    @property
    def tables(self) -> list[tuple[str, pd.DataFrame]]:
        return [(b.caption, b.df) for b in self.blocks if isinstance(b, Table)]

    @property
    def figures(self) -> list[tuple[str, Path | None]]:
        return [(b.name, b.path) for b in self.blocks if isinstance(b, Figure)]


def _summary_md(s: Summary) -> list[str]:
    """A stage summary in Markdown: facts as a two-column table, then its tables and notes."""
    out = [bold_md(s.title), ""]
    if s.facts:
        facts = pd.DataFrame({"value": [v for _, v in s.facts]}, index=pd.Index([k for k, _ in s.facts], name="quantity"))
        out += [md_table(facts)]
    for caption, df in s.tables:
        out += [bold_md(caption), "", md_table(df)]
    if s.notes:
        out += [f"- {inline_md(n)}" for n in s.notes] + [""]
    return out


def _summary_html(s: Summary) -> str:
    # Summary.as_html() renders the tables; wrapped so wide tables scroll instead of overflowing
    return f"<div class='summary scroll'>{s.as_html()}</div>"


def render_markdown(title: str, sections: list[Section]) -> str:
    md = [f"# {inline_md(title)}", ""]
    for s in sections:
        md += [f"## {inline_md(s.title)}", ""]
        for b in s.blocks:
            if isinstance(b, Text):
                md += [inline_md(b.text), ""]
            elif isinstance(b, Table):
                md += [bold_md(b.caption), "", md_table(b.df)]
            elif isinstance(b, Summary):
                md += _summary_md(b)
            elif isinstance(b, Code):
                md += [_fence(b.text), b.text, _fence(b.text), ""]
            elif isinstance(b, Bullets):
                md += [f"- {inline_md(i)}" for i in b.items] + [""]
            elif isinstance(b, Definitions):
                md += [f"- {bold_md(t)}: {inline_md(d)}" for t, d in b.items] + [""]
            elif isinstance(b, Figure):
                if b.path is None:
                    md += [f"*(figure {md_escape(b.name)} not drawn: see the log)*", ""]
                else:
                    link = b.path.name if re.fullmatch(r"[\w.+-]+", b.path.name) else _md_destination(b.path.name)
                    md += [f"![{md_escape(b.name)}]({link})", ""]
                    if b.caption:
                        md += [f"Figure: {inline_md(b.caption)}", ""]
    return "\n".join(md)


CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',Roboto,sans-serif;max-width:1150px;margin:2em auto;padding:0 1em;color:#222;line-height:1.45}
h1{border-bottom:2px solid #444;padding-bottom:.2em}
h2{border-bottom:1px solid #bbb;padding-bottom:.15em;margin-top:2em}
h3{margin-bottom:.3em}
h4{margin:1em 0 .3em;font-size:1em}
code{background:#f2f2f2;padding:0 .25em;border-radius:3px;font-size:.92em}
.scroll{overflow-x:auto;max-width:100%}
table.tbl{border-collapse:collapse;font-size:12.5px;margin:.4em 0 1em}
table.tbl th,table.tbl td{padding:3px 8px;border-bottom:1px solid #ddd;white-space:nowrap}
table.tbl td{text-align:right;font-variant-numeric:tabular-nums}
table.tbl thead th{border-bottom:2px solid #888;text-align:right;vertical-align:bottom;white-space:normal;max-width:11em}
table.tbl td.txt{white-space:normal;text-align:left;min-width:16em}
table.tbl thead th:first-child,table.tbl tbody th{text-align:left}
table.tbl tbody th{font-weight:normal;background:#fafafa}
table.tbl tr.sel td,table.tbl tr.sel th{font-weight:bold;background:#eef6ee}
table.facts{border-collapse:collapse;font-size:13px;margin:.3em 0 .8em}
table.facts th{text-align:left;font-weight:normal;color:#555;padding:2px 12px 2px 0;vertical-align:top}
table.facts td{padding:2px 0}
dl.notation{display:grid;grid-template-columns:max-content auto;gap:.25em 1em;margin:.5em 0}
dl.notation dt{font-weight:bold;font-family:monospace}
dl.notation dd{margin:0}
figure{margin:1em 0 1.5em}
figure img{max-width:100%;border:1px solid #eee}
figcaption{font-size:.9em;color:#444;margin-top:.3em}
pre{background:#f7f7f7;padding:.6em;overflow-x:auto;font-size:12px}
nav.toc{font-size:.95em;background:#f7f7f7;padding:.5em 1em;border-radius:4px}
nav.toc a{margin-right:1em}
"""


def _anchor(title: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", title.lower()).strip("-")


def render_html(title: str, sections: list[Section]) -> str:
    body = [f"<h1>{html.escape(title)}</h1>",
            "<nav class='toc'>" + "".join(f"<a href='#{_anchor(s.title)}'>{html.escape(s.title)}</a>" for s in sections) + "</nav>"]
    for s in sections:
        body.append(f"<h2 id='{_anchor(s.title)}'>{inline_html(s.title)}</h2>")
        for b in s.blocks:
            if isinstance(b, Text):
                body.append(f"<p>{inline_html(b.text)}</p>")
            elif isinstance(b, Table):
                body.append(f"<h4>{inline_html(b.caption)}</h4>" + html_table(b.df, b.highlight))
            elif isinstance(b, Summary):
                body.append(_summary_html(b))
            elif isinstance(b, Code):
                body.append(f"<pre>{html.escape(b.text)}</pre>")
            elif isinstance(b, Bullets):
                body.append("<ul>" + "".join(f"<li>{inline_html(i)}</li>" for i in b.items) + "</ul>")
            elif isinstance(b, Definitions):
                body.append("<dl class='notation'>" + "".join(f"<dt>{inline_html(t)}</dt><dd>{inline_html(d)}</dd>" for t, d in b.items) + "</dl>")
            elif isinstance(b, Figure):
                if b.path is None:
                    body.append(f"<p><i>(figure {html.escape(b.name)} not drawn: see the log)</i></p>")
                    continue
                b64 = base64.b64encode(b.path.read_bytes()).decode()
                cap = f"<figcaption>{inline_html(b.caption)}</figcaption>" if b.caption else ""
                body.append(f"<figure><img alt='{html.escape(b.name)}' src='data:image/png;base64,{b64}'>{cap}</figure>")
    return (f"<!doctype html><html lang='en'><head><meta charset='utf-8'><meta name='viewport' content='width=device-width'>"
            f"<title>{html.escape(title)}</title><style>{CSS}</style></head><body>{''.join(body)}</body></html>")
