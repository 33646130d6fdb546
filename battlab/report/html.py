"""One static HTML page from sections of paragraphs, key–value lists, tables and figures.

The page is self-contained apart from its PNG figures, which it references by paths relative to the page, so
the report directory can be zipped, mailed or served as it is. No scripts, no external fonts or styles: it opens
the same offline. Every text is escaped.
"""

from __future__ import annotations

import datetime as _dt
import html
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; margin: 2rem auto; max-width: 1100px;
       color: #222; line-height: 1.45; padding: 0 1rem; }
h1 { font-size: 1.7rem; margin-bottom: 0.2rem; } h2 { font-size: 1.3rem; border-bottom: 1px solid #ddd;
       padding-bottom: 0.2rem; margin-top: 2.2rem; }
.subtitle { color: #555; margin-top: 0; } .meta { color: #777; font-size: 0.85rem; }
table { border-collapse: collapse; margin: 0.8rem 0; font-size: 0.9rem; }
th, td { border: 1px solid #ccc; padding: 0.25rem 0.6rem; text-align: right; }
th { background: #f3f3f3; } td:first-child, th:first-child { text-align: left; }
caption { caption-side: top; text-align: left; font-weight: 600; padding-bottom: 0.3rem; }
.note { color: #555; font-size: 0.85rem; }
figure { margin: 1rem 0; } figure img { max-width: 100%; border: 1px solid #eee; }
figcaption { color: #444; font-size: 0.9rem; }
dl.kv { display: grid; grid-template-columns: max-content auto; gap: 0.2rem 1.2rem; }
dl.kv dt { font-weight: 600; } dl.kv dd { margin: 0; }
.good { color: #1a7f37; } .bad { color: #b42318; font-weight: 600; } .warn { color: #9a6700; font-weight: 600; }
"""


@dataclass(frozen=True)
class Paragraph:
    text: str
    tone: str = ""  # "", "good" (green), "warn" (amber) or "bad" (red)


@dataclass(frozen=True)
class KeyValues:
    items: Mapping[str, Any]


@dataclass(frozen=True)
class Table:
    columns: Sequence[str]
    rows: Sequence[Sequence[Any]]
    caption: str = ""
    note: str = ""


@dataclass(frozen=True)
class Figure:
    path: str | Path  # the PNG, absolute or relative to the working directory (made relative to the page when written)
    caption: str = ""


Block = Paragraph | KeyValues | Table | Figure


@dataclass(frozen=True)
class Section:
    title: str
    blocks: Sequence[Block] = field(default_factory=tuple)


def fmt(value: Any) -> str:
    """A cell value as text: floats to 4 significant digits, None and NaN as a dash, booleans as yes/no."""
    if value is None:
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return "–" if math.isnan(value) else f"{value:.4g}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(fmt(v) for v in value) + "]"
    return str(value)


def _block(b: Block, base: Path | None) -> str:
    e = html.escape
    if isinstance(b, Paragraph):
        cls = f' class="{e(b.tone)}"' if b.tone else ""
        return f"<p{cls}>{e(b.text)}</p>"
    if isinstance(b, KeyValues):
        items = "".join(f"<dt>{e(str(k))}</dt><dd>{e(fmt(v))}</dd>" for k, v in b.items.items())
        return f'<dl class="kv">{items}</dl>'
    if isinstance(b, Table):
        head = "".join(f"<th>{e(c)}</th>" for c in b.columns)
        body = "".join("<tr>" + "".join(f"<td>{e(fmt(v))}</td>" for v in row) + "</tr>" for row in b.rows)
        cap = f"<caption>{e(b.caption)}</caption>" if b.caption else ""
        note = f'<p class="note">{e(b.note)}</p>' if b.note else ""
        return f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>{note}"
    if isinstance(b, Figure):
        p = Path(b.path)
        src = Path(os.path.relpath(p.resolve(), base) if base is not None else p).as_posix()
        cap = f"<figcaption>{e(b.caption)}</figcaption>" if b.caption else ""
        return f'<figure><img src="{e(src)}" alt="{e(b.caption or p.name)}">{cap}</figure>'
    raise TypeError(f"not a report block: {b!r}")


def render(
    title: str, sections: Sequence[Section], *, subtitle: str = "", meta: str = "", base: Path | None = None
) -> str:
    """The page as a string; figure paths (absolute, or relative to the working directory) are made relative to
    ``base`` (the page's directory), so the page finds its figures wherever it is opened from."""
    e = html.escape
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{e(title)}</title><style>{CSS}</style></head><body>",
        f"<h1>{e(title)}</h1>",
    ]
    if subtitle:
        parts.append(f'<p class="subtitle">{e(subtitle)}</p>')
    stamp = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    parts.append(f'<p class="meta">{e(meta + " · " if meta else "")}written {stamp}</p>')
    for s in sections:
        parts.append(f"<section><h2>{e(s.title)}</h2>")
        parts.extend(_block(b, base) for b in s.blocks)
        parts.append("</section>")
    parts.append("</body></html>")
    return "\n".join(parts)


def write(path: str | Path, title: str, sections: Sequence[Section], *, subtitle: str = "", meta: str = "") -> Path:
    """Write the page to ``path`` (its figures must already be written, usually beside it)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = render(title, sections, subtitle=subtitle, meta=meta, base=path.parent.resolve())
    tmp = path.with_suffix(".html.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)
    return path
