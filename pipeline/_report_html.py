"""HTML pieces of the run report: one self-contained page (inline CSS and JS, images as
base64 data URIs, nothing fetched from the network)."""

from __future__ import annotations

import base64
import html
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

__all__ = ["Raw", "esc", "fmt", "png_img", "html_table", "key_values", "stat_cards", "page"]


def esc(value: Any) -> str:
    return html.escape(str(value), quote=True)


def fmt(value: Any, digits: int = 3) -> str:
    """A table cell: numbers rounded, None/NaN as an em dash."""
    if value is None:
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return f"{value:,}"
    if isinstance(value, float):
        if not math.isfinite(value):
            return "—"
        if value != 0 and (abs(value) < 10**-digits or abs(value) >= 1e6):
            return f"{value:.{digits}g}"
        return f"{value:.{digits}f}"
    return str(value)


def png_img(png: bytes, alt: str, *, cls: str = "") -> str:
    data = base64.b64encode(png).decode("ascii")
    klass = f' class="{esc(cls)}"' if cls else ""
    return f'<img{klass} alt="{esc(alt)}" src="data:image/png;base64,{data}">'


def html_table(
    headers: Sequence[str],
    rows: Iterable[Sequence[Any]],
    *,
    numeric: Sequence[bool] | None = None,
    cls: str = "",
    digits: int = 3,
) -> str:
    """A table; cells are escaped unless they are ``Raw``; numeric columns right-aligned."""
    num = list(numeric) if numeric is not None else [False] * len(headers)
    head = "".join(
        f'<th class="{"num" if n else ""}">{esc(h)}</th>' for h, n in zip(headers, num, strict=True)
    )
    body = []
    for row in rows:
        cells = "".join(
            f'<td class="{"num" if n else ""}">{_cell(v, digits)}</td>'
            for v, n in zip(row, num, strict=True)
        )
        body.append(f"<tr>{cells}</tr>")
    klass = f' class="{esc(cls)}"' if cls else ""
    return f"<table{klass}><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


class Raw(str):
    """Trusted HTML for a table cell."""


def _cell(value: Any, digits: int) -> str:
    if isinstance(value, Raw):
        return str(value)
    return esc(fmt(value, digits))


def key_values(pairs: Iterable[tuple[str, Any]]) -> str:
    rows = "".join(f"<tr><th>{esc(k)}</th><td>{_cell(v, 3)}</td></tr>" for k, v in pairs)
    return f'<table class="kv"><tbody>{rows}</tbody></table>'


def stat_cards(cards: Iterable[tuple[str, Any, str]]) -> str:
    """Big numbers: (label, value, css modifier such as 'ok', 'bad', '')."""
    items = "".join(
        f'<div class="card {esc(mod)}"><div class="value">{esc(fmt(value))}</div>'
        f'<div class="label">{esc(label)}</div></div>'
        for label, value, mod in cards
    )
    return f'<div class="cards">{items}</div>'


_CSS = """
:root{--fg:#1d2430;--muted:#5b6472;--line:#e3e6eb;--bg:#f6f7f9;--accent:#2f6fb2;
--ok:#2e7d32;--bad:#c62828;--warn:#b26a00}
*{box-sizing:border-box}
body{margin:0;font:14px/1.45 system-ui,-apple-system,"Segoe UI",Roboto,Helvetica,Arial,sans-serif;
color:var(--fg);background:var(--bg)}
header{background:#17212f;color:#fff;padding:18px 28px}
header h1{margin:0;font-size:22px;font-weight:600}
header .sub{color:#b8c2d0;margin-top:4px;font-size:13px}
nav{position:sticky;top:0;z-index:2;background:#fff;border-bottom:1px solid var(--line);
padding:8px 28px;display:flex;gap:18px}
nav a{color:var(--accent);text-decoration:none;font-weight:500}
main{max-width:1240px;margin:0 auto;padding:8px 28px 60px}
section{background:#fff;border:1px solid var(--line);border-radius:8px;padding:16px 20px;
margin:18px 0}
h2{margin:0 0 12px;font-size:18px}
h3{margin:18px 0 8px;font-size:15px;color:#2b3442}
.note{color:var(--muted);font-size:13px}
.banner{background:#fff4e0;border:1px solid #f0c36d;color:#6b4500;padding:10px 14px;
border-radius:6px;margin:16px 0}
.cards{display:flex;flex-wrap:wrap;gap:12px;margin:4px 0 10px}
.card{border:1px solid var(--line);border-radius:8px;padding:10px 16px;min-width:120px;
background:#fbfcfd}
.card .value{font-size:24px;font-weight:600}
.card .label{color:var(--muted);font-size:12px;text-transform:uppercase;letter-spacing:.03em}
.card.ok .value{color:var(--ok)}.card.bad .value{color:var(--bad)}
.card.warn .value{color:var(--warn)}
table{border-collapse:collapse;margin:6px 0 12px;font-size:13px}
th,td{border-bottom:1px solid var(--line);padding:4px 10px;text-align:left;vertical-align:top}
thead th{background:#f0f2f5;font-weight:600;position:sticky;top:0}
td.num,th.num{text-align:right;font-variant-numeric:tabular-nums}
table.kv th{color:var(--muted);font-weight:500;width:170px}
code,.mono{font-family:ui-monospace,SFMono-Regular,Menlo,Consolas,monospace;font-size:12px}
.grid{display:grid;grid-template-columns:repeat(auto-fit,minmax(420px,1fr));gap:16px}
figure{margin:0}figure img{max-width:100%;border:1px solid var(--line);border-radius:4px}
figcaption{color:var(--muted);font-size:12px;margin-top:2px}
.toolbar{display:flex;gap:12px;align-items:center;margin:4px 0 12px;flex-wrap:wrap}
.toolbar input,.toolbar select{font:inherit;padding:5px 8px;border:1px solid #c9ced6;
border-radius:5px}
details.frame{border:1px solid var(--line);border-radius:6px;margin:8px 0;background:#fff}
details.frame>summary{cursor:pointer;padding:8px 12px;display:flex;gap:14px;
align-items:center;list-style:none}
details.frame>summary::-webkit-details-marker{display:none}
details.frame>summary::before{content:"\\25B8";color:var(--muted)}
details.frame[open]>summary::before{content:"\\25BE"}
details.frame[open]>summary{border-bottom:1px solid var(--line);background:#fafbfc}
.frame-body{padding:12px}
.badge{display:inline-block;padding:1px 8px;border-radius:10px;font-size:12px;font-weight:600}
.badge.done{background:#e6f4ea;color:var(--ok)}.badge.failed{background:#fdecea;color:var(--bad)}
.badge.pending{background:#fff4e0;color:var(--warn)}
.quicklooks{display:grid;grid-template-columns:1fr 1fr 2fr;gap:12px;align-items:start}
@media (max-width:900px){.quicklooks{grid-template-columns:1fr 1fr}
.quicklooks figure.wide{grid-column:1 / span 2}}
.quicklooks img{width:100%;image-rendering:auto}
.quicklooks figure.scene-graph{grid-column:1 / span 2;max-width:640px}
.error{color:var(--bad);white-space:pre-wrap}
.scroll{max-height:340px;overflow:auto}
"""

_JS = """
(function(){
  function filterFrames(){
    var q=(document.getElementById('frame-search').value||'').toLowerCase();
    var st=document.getElementById('frame-status').value;
    var shown=0,all=document.querySelectorAll('details.frame');
    all.forEach(function(d){
      var ok=(!q||d.dataset.id.toLowerCase().indexOf(q)>=0)&&(st==='all'||d.dataset.status===st);
      d.style.display=ok?'':'none'; if(ok){shown++;}
    });
    document.getElementById('frame-count').textContent=shown+' of '+all.length+' frames shown';
  }
  function init(){
    var s=document.getElementById('frame-search'),t=document.getElementById('frame-status');
    if(s){s.addEventListener('input',filterFrames);t.addEventListener('change',filterFrames);
      filterFrames();}
  }
  function ready(){
    var imgs=Array.prototype.slice.call(document.images);
    var broken=imgs.filter(function(i){return !(i.complete&&i.naturalWidth>0);}).length;
    var root=document.documentElement;
    root.setAttribute('data-images',String(imgs.length));
    root.setAttribute('data-broken-images',String(broken));
    root.setAttribute('data-report-ready','1');
  }
  if(document.readyState==='loading'){document.addEventListener('DOMContentLoaded',init);}
  else{init();}
  if(document.readyState==='complete'){ready();}else{window.addEventListener('load',ready);}
})();
"""


def page(title: str, subtitle: str, nav: Mapping[str, str], sections: Sequence[str]) -> str:
    """The whole document. ``nav``: anchor id -> label."""
    links = "".join(f'<a href="#{esc(k)}">{esc(v)}</a>' for k, v in nav.items())
    return (
        "<!DOCTYPE html>\n"
        '<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>{esc(title)}</title><style>{_CSS}</style></head><body>"
        f'<header><h1>{esc(title)}</h1><div class="sub">{subtitle}</div></header>'
        f"<nav>{links}</nav><main>{''.join(sections)}</main>"
        f"<script>{_JS}</script></body></html>\n"
    )
