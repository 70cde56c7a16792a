"""``report.html``: the inspection report an inspector sends on, one self-contained folder.

Design notes: docs/report.md (services/inspection/html.py).
"""

from __future__ import annotations

import html
import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .deliverable import SEVERITY_ORDER, SORT_KEY, Deliverable, aligned_text, resolution_note, unusable_text, width_text

__all__ = ["write_html", "VIEWER_JS"]

_CSS = """
body{font-family:system-ui,sans-serif;max-width:1200px;margin:1em auto;padding:0 1em;color:#222}
h1{font-size:1.5em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em}
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #bbb;padding:.2em .5em;font-size:.9em;text-align:left}
th{background:#eee}.crop{image-rendering:pixelated;max-width:100%;height:auto;border:1px solid #999}
.worst{display:flex;gap:1em;align-items:flex-start;margin:.6em 0}.worst img{max-width:420px;max-height:260px;width:auto}
.wide{color:#b00;font-weight:bold}.moderate{color:#b60}.insignificant{color:#060}
#zoom{position:relative;overflow:hidden;height:460px;background:#333;cursor:grab;touch-action:none;user-select:none}
#zoom img{position:absolute;max-width:none;image-rendering:auto}
#zoombar{position:absolute;left:10px;bottom:10px;background:rgba(255,255,255,.85);padding:2px 6px;font-size:12px}
#zoombar div{height:4px;background:#000;margin-top:2px}#zoompos{position:absolute;right:10px;bottom:10px;
background:rgba(255,255,255,.85);padding:2px 6px;font-size:12px}.fig{max-width:100%}
"""

#: the zoomable view: tiles z/x_y.jpg of a pyramid, wheel or buttons to zoom, drag to pan
VIEWER_JS = """
(function(){
const el=document.getElementById('zoom');if(!el)return;
const W=+el.dataset.w,H=+el.dataset.h,T=+el.dataset.tile,Z=+el.dataset.zmax,src=el.dataset.src;
const M=+el.dataset.mpp,HM=+el.dataset.hm;const bar=document.getElementById('zoombar'),pos=document.getElementById('zoompos');
let s0=el.clientWidth/W,s=s0,ox=0,oy=(el.clientHeight-H*s)/2;const imgs={};
function level(){return Math.max(0,Math.min(Z,Z+Math.ceil(Math.log2(s)-1e-9)));}
function draw(){const L=level(),f=Math.pow(2,Z-L),ts=T*f*s,cw=el.clientWidth,ch=el.clientHeight;
const lw=Math.ceil(W/f),lh=Math.ceil(H/f),nx=Math.ceil(lw/T),ny=Math.ceil(lh/T),seen={};
const x0=Math.max(0,Math.floor(-ox/ts)),x1=Math.min(nx-1,Math.floor((cw-ox)/ts));
const y0=Math.max(0,Math.floor(-oy/ts)),y1=Math.min(ny-1,Math.floor((ch-oy)/ts));
for(let y=y0;y<=y1;y++)for(let x=x0;x<=x1;x++){const k=L+'/'+x+'_'+y;let im=imgs[k];
if(!im){im=new Image();im.src=src+'/'+k+'.jpg';im.draggable=false;im.className='tile';el.appendChild(im);imgs[k]=im;}
im.style.left=(ox+x*ts)+'px';im.style.top=(oy+y*ts)+'px';im.style.width=(Math.min(T,lw-x*T)*f*s)+'px';
im.style.height=(Math.min(T,lh-y*T)*f*s)+'px';im.style.display='';seen[k]=1;}
for(const k in imgs)if(!seen[k])imgs[k].style.display='none';
const want=100/(s/M);const p=Math.pow(10,Math.floor(Math.log10(want)));const m=[1,2,5,10].map(a=>a*p).find(a=>a>=want)||10*p;
bar.firstChild.nodeValue=(m>=1?m+' m':(m>=0.01?Math.round(m*100)+' cm':Math.round(m*1000)+' mm'));
bar.lastChild.style.width=(m/M*s)+'px';el.dataset.level=L;}
function zoom(k,mx,my){const ns=Math.min(8,Math.max(s0/2,s*k));ox=mx-(mx-ox)*ns/s;oy=my-(my-oy)*ns/s;s=ns;draw();}
el.addEventListener('wheel',e=>{e.preventDefault();const r=el.getBoundingClientRect();zoom(e.deltaY<0?1.25:0.8,e.clientX-r.left,e.clientY-r.top);},{passive:false});
let drag=null;el.addEventListener('pointerdown',e=>{drag=[e.clientX,e.clientY,ox,oy];el.setPointerCapture(e.pointerId);});
el.addEventListener('pointermove',e=>{const r=el.getBoundingClientRect();const u=((e.clientX-r.left-ox)/s)*M,v=HM-((e.clientY-r.top-oy)/s)*M;
pos.textContent='u '+u.toFixed(3)+' m, v '+v.toFixed(3)+' m';if(drag){ox=drag[2]+e.clientX-drag[0];oy=drag[3]+e.clientY-drag[1];draw();}});
el.addEventListener('pointerup',()=>{drag=null;});
window.skynetZoom=function(k,u,v){const cx=el.clientWidth/2,cy=el.clientHeight/2;
if(u!==undefined){ox=cx-(u/M)*s;oy=cy-((HM-v)/M)*s;}zoom(k,cx,cy);return level();};
document.getElementById('zin').onclick=()=>zoom(2,el.clientWidth/2,el.clientHeight/2);
document.getElementById('zout').onclick=()=>zoom(0.5,el.clientWidth/2,el.clientHeight/2);
document.getElementById('zfit').onclick=()=>{s=s0;ox=0;oy=(el.clientHeight-H*s)/2;draw();};
window.addEventListener('resize',draw);draw();})();
"""


def _e(x: Any) -> str:
    return html.escape(str(x), quote=True)


def _table(head: Sequence[str], rows: Sequence[Sequence[Any]], raw: bool = False) -> str:
    h = "".join(f"<th>{_e(c)}</th>" for c in head)
    body = "".join("<tr>" + "".join(f"<td>{c if raw else _e(c)}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><thead><tr>{h}</tr></thead><tbody>{body}</tbody></table>"


def write_html(path: str | Path, res: Deliverable, acc: Any = None, prefix: str = "inspection",
               frames: str = "frames", figures: Sequence[str] = (), record: Any = None, absent: str = "") -> Path:
    """Write ``report.html`` for the deliverable ``res`` (its files under ``prefix/``) and return its path."""
    from .mission import WORST, class_ranges, orientation_text_of

    p = Path(path)
    m = res.mosaic
    note = resolution_note(m.m_per_px)
    ranges = class_ranges()
    tiles = json.loads((p.parent / prefix / "defects.json").read_text()).get("tiles", {})
    by = {c: [d for d in res.defects if d.severity == c] for c in SEVERITY_ORDER}
    name = getattr(getattr(record, "scenario", None), "name", "") or "surface"
    fleet = getattr(record, "fleet", "")
    when = getattr(record, "started", None)
    outcome = ""
    if record is not None:
        ok = bool(getattr(record, "success", False))
        outcome = f"Mission {'succeeded' if ok else 'failed'}" + (
            f": {'; '.join(map(str, record.failures))}" if getattr(record, "failures", None) else "") + ". "
    h: list[str] = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
        f"<title>Inspection report: {_e(name)}</title><style>{_CSS}</style></head><body>",
        f"<h1>Inspection report: {_e(name)}</h1>",
        f"<p>{_e(outcome)}Fleet {_e(fleet)}" + (f", flown {_e(time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime(when)))}"
                                                  if when else "") + ".</p>",
        "<h2>Findings</h2>",
        f"<p><b>{len(res.defects)} defects</b>: " + ", ".join(
            f"<span class='{c}'>{len(by[c])} {c}</span>" for c in SEVERITY_ORDER) +
        f". Coverage of the surface {m.coverage:.0%} ({m.frames_used} of {res.frames} captures); ground sampling "
        f"distance {m.m_per_px * 1e3:.2f} mm/px: a crack narrower than {note['smallest_width_mm']:.2f} mm is flagged, "
        f"not measured; classes told apart by width: {_e(', '.join(note['classes_resolved']))}"
        + (f" (not {_e(', '.join(note['classes_unresolved']))})" if note["classes_unresolved"] else "") + "."
        + "".join(f" {_e(x)}" for x in (absent, unusable_text(res), aligned_text(m)) if x) + "</p>",
        f"<p>{_e(orientation_text_of(res))}</p>",
        _table(["class (AASHTO, max width)", "defects", "longest (m)", "widest (mm)"],
               [[f"{c} ({ranges[c]})", len(by[c]), f"{max((d.length_m for d in by[c]), default=0):.2f}",
                 f"{max((d.width_max_mm for d in by[c]), default=0):.1f}"] for c in SEVERITY_ORDER]),
    ]
    if res.defects:
        h.append(f"<h3>The worst {min(WORST, len(res.defects))} cracks</h3>")
    for d in res.defects[:WORST]:
        seen = ", ".join(f"<a href='{_e(frames)}/{_e(n)}.jpg'>{_e(n)}</a>" for n in d.seen_by) or "–"
        ll = f"{d.lla[0]:.7f}, {d.lla[1]:.7f}, {d.lla[2]:.1f} m" if d.lla else "–"
        h.append(f"<div class='worst' id='defect-{d.id}'><img class='crop' src='{_e(prefix)}/{_e(d.crop)}' "
                 f"alt='defect {d.id}'><div><b>{d.id}. <span class='{_e(d.severity)}'>{_e(d.severity)}</span></b>"
                 f"<br>length {d.length_m:.2f} m, width max / mean {_e(width_text(d))} mm<br>u {d.u_m:.2f} m, "
                 f"v {d.v_m:.2f} m; {_e(ll)}<br>captures: {seen}</div></div>")
    if acc is not None:
        s = acc.summary

        def pct(x: float | None) -> str:
            return "–" if x is None else f"{100 * x:.1f} %"

        def mm(x: float | None) -> str:
            return "–" if x is None else f"{x:.2f} mm"

        h += ["<h3>Measurements against the ground truth</h3>",
              _table(["", "median", "worst"],
                     [["length error", pct(s["length_error_median"]), pct(s["length_error_worst"])],
                      ["maximum width error", mm(s["width_max_error_mm_median"]), mm(s["width_max_error_mm_worst"])],
                      ["mean width error", mm(s["width_mean_error_mm_median"]), mm(s["width_mean_error_mm_worst"])]]),
              f"<p>{s['matched']} of {s['truth']} true cracks found; {s['unmatched_defects']} defects on no true "
              f"crack; in their true class: {pct(s['class_agreement'])} (widths and classes over the {s['resolved']} "
              "cracks wider than one pixel).</p>",
              _table(["truth", "length (m) truth / measured", "width max (mm)", "width mean (mm)", "class", "defects"],
                     [[r.truth.id, f"{r.truth.length_m:.2f} / {'–' if r.length_m is None else f'{r.length_m:.2f}'}",
                       f"{r.truth.width_max_mm:.2f} / {'–' if r.width_max_mm is None else f'{r.width_max_mm:.2f}'}",
                       f"{r.truth.width_mean_mm:.2f} / {'–' if r.width_mean_mm is None else f'{r.width_mean_mm:.2f}'}",
                       f"{r.truth.severity} / {r.severity or 'missed'}" + ("" if r.resolved else " (below 1 px)"),
                       ", ".join(map(str, r.defects)) or "–"] for r in acc.rows])]
    h += ["<h2>The wall</h2>",
          f"<p>Zoom with the wheel or the buttons, drag to pan; the bar gives the scale, the corner the (u, v) "
          f"under the pointer. Full resolution {m.image.shape[1]} x {m.image.shape[0]} px.</p>",
          "<p><button id='zin'>zoom in</button> <button id='zout'>zoom out</button> <button id='zfit'>whole wall"
          "</button></p>",
          f"<div id='zoom' data-w='{tiles.get('width', m.image.shape[1])}' data-h='{tiles.get('height', m.image.shape[0])}'"
          f" data-tile='{tiles.get('tile', 256)}' data-zmax='{tiles.get('zmax', 0)}' data-src='{_e(prefix)}/tiles'"
          f" data-mpp='{m.m_per_px!r}' data-hm='{m.plane.height_m!r}'><div id='zoombar'>1 m<div></div></div>"
          "<div id='zoompos'></div></div>",
          f"<p><img class='fig' src='{_e(prefix)}/overview.png' alt='overview of the wall with a 1 m grid'></p>",
          f"<h2>Defects (sorted by {_e(SORT_KEY)})</h2>",
          _table(["id", "class", "length (m)", "width max / mean (mm)", "u, v (m)", "lat, lon (deg), alt (m)",
                  "seen in (UAV, capture, mission time)", "crop"],
                 [[d.id, f"<span class='{_e(d.severity)}'>{_e(d.severity)}</span>", f"{d.length_m:.2f}",
                   _e(width_text(d)), f"{d.u_m:.2f}, {d.v_m:.2f}",
                   f"{d.lla[0]:.7f}, {d.lla[1]:.7f}, {d.lla[2]:.2f}" if d.lla else "–",
                   "–" if d.uav is None else _e(f"UAV {d.uav}, capture {d.capture_id}"
                                                + (f", t {d.t:.1f} s" if d.t is not None else "")),
                   f"<img class='crop' style='max-width:260px' src='{_e(prefix)}/{_e(d.crop)}' alt='defect {d.id}'>"]
                  for d in res.defects], raw=True),
          "<h2>Files</h2><ul>",
          f"<li><a href='{_e(prefix)}/defects.geojson'>defects.geojson</a>: each crack's centre line (LineString) "
          "and outline (Polygon), lon, lat, altitude (RFC 7946)</li>",
          f"<li><a href='{_e(prefix)}/defects.kml'>defects.kml</a>: the same for Google Earth (absolute altitudes)</li>",
          f"<li><a href='{_e(prefix)}/defects.json'>defects.json</a>, <a href='{_e(prefix)}/mosaic.png'>mosaic.png</a>"
          " (full resolution)</li>", "<li><a href='report.md'>report.md</a>: the mission report</li></ul>"]
    if figures:
        h.append("<h2>The mission's figures</h2>")
        h += [f"<p><img class='fig' src='{_e(f)}' alt='{_e(f)}'></p>" for f in figures]
    h.append(f"<script>{VIEWER_JS}</script></body></html>")
    p.write_text("\n".join(h))
    return p
