"""One self-contained HTML page: every figure embedded as a base64 PNG, with its file name.

The page needs nothing beside it (no scripts, styles or images from
elsewhere); each image also names and links its PNG file in the same folder.
"""

from __future__ import annotations

import base64
import datetime as dt
import html
import os
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from tasks.runstore import atomic_write_bytes

__all__ = ["Section", "write_page"]

STYLE = """
body { font-family: system-ui, -apple-system, Segoe UI, Helvetica, Arial, sans-serif; margin: 1.5em auto;
       max-width: 1250px; padding: 0 1em; color: #222; line-height: 1.4; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; border-bottom: 1px solid #ccc; padding-bottom: .2em; margin-top: 2em; }
figure { margin: 1em 0; } figure img { max-width: 100%; border: 1px solid #eee; }
figcaption { font-size: .85em; color: #555; }
table { border-collapse: collapse; font-size: .85em; margin: .6em 0; }
th, td { border: 1px solid #ccc; padding: .2em .5em; text-align: right; } th { background: #f3f3f3; }
td:first-child, th:first-child { text-align: left; }
.note { background: #fff7e0; border-left: 4px solid #e0b000; padding: .4em .8em; }
code { background: #f3f3f3; padding: 0 .2em; }
"""


@dataclass
class Section:
    """A heading, paragraphs (plain text, escaped), tables and figures (PNG paths with captions)."""

    title: str
    paragraphs: list[str] = field(default_factory=list)
    tables: list[tuple[str, pd.DataFrame]] = field(default_factory=list)
    figures: list[tuple[Path, str]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def _table(caption: str, df: pd.DataFrame) -> str:
    out = [f"<table><caption>{html.escape(caption)}</caption><tr>"]
    out += [f"<th>{html.escape(str(c))}</th>" for c in df.columns]
    out.append("</tr>")
    for _, row in df.iterrows():
        out.append("<tr>" + "".join(f"<td>{html.escape(_fmt(v))}</td>" for v in row) + "</tr>")
    out.append("</table>")
    return "".join(out)


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def _figure(path: Path, caption: str, page_dir: Path) -> str:
    data = base64.b64encode(Path(path).read_bytes()).decode("ascii")
    rel = Path(path).resolve().relative_to(page_dir.resolve()) if Path(path).resolve().is_relative_to(
        page_dir.resolve()) else Path(path).name
    name = html.escape(str(rel))
    return (f'<figure><img src="data:image/png;base64,{data}" alt="{name}">'
            f'<figcaption>{html.escape(caption)} (<a href="{name}">{name}</a>)</figcaption></figure>')


def write_page(path: Path, title: str, sections: list[Section], intro: list[str] | None = None) -> Path:
    """Write the page atomically and return its path."""
    path = Path(path)
    parts = ["<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
             f"<title>{html.escape(title)}</title><style>{STYLE}</style></head><body>",
             f"<h1>{html.escape(title)}</h1>"]
    stamp = dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds")
    for p in intro or []:
        parts.append(f"<p>{html.escape(p)}</p>")
    parts.append(f"<p><small>Written {stamp}.</small></p>")
    for s in sections:
        parts.append(f"<h2>{html.escape(s.title)}</h2>")
        parts += [f"<p class='note'>{html.escape(n)}</p>" for n in s.notes]
        parts += [f"<p>{html.escape(p)}</p>" for p in s.paragraphs]
        parts += [_table(c, df) for c, df in s.tables]
        parts += [_figure(fp, cap, path.parent) for fp, cap in s.figures]
    parts.append("</body></html>\n")
    atomic_write_bytes(path, "\n".join(parts).encode("utf-8"))
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(path, 0o666 & ~umask)  # readable like any other file (the temporary file was private)
    return path
