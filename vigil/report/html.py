"""``index.html``: one page linking a run's step table, figures, video and summary."""

from __future__ import annotations

import csv
import html
import io
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from stack.config import write_text
from stack.files import MAX_RECORD_BYTES, read_text_capped

INDEX_FILE = "index.html"

_STYLE = """
body { font-family: sans-serif; max-width: 1100px; margin: 1em auto; color: #222; }
table { border-collapse: collapse; font-size: 13px; }
td, th { border: 1px solid #ccc; padding: 2px 6px; text-align: left; }
img, video { max-width: 100%; }
.bad { color: #b00; font-weight: bold; } .good { color: #070; }
"""


def _metric_rows(m: Mapping[str, Any]) -> list[tuple[str, str, bool | None]]:
    rate = m.get("miss_rate")
    return [
        ("visits to a restricted cell", str(m["n_visits"]), None),
        ("guarded", f"{m['guarded']} of {m['n_visits']}", m["guarded"] == m["n_visits"]),
        ("abandoned", str(m["abandoned"]), m["abandoned"] == 0),
        ("max delay [s]", "-" if m.get("max_delay_s") is None else f"{m['max_delay_s']:.1f}", None),
        (
            "warnings timely / late",
            f"{m['timely_warnings']} / {m['late_warnings']}",
            m["late_warnings"] == 0,
        ),  # fmt: skip
        ("false trips", str(m["n_false_trips"]), m["n_false_trips"] == 0),
        (
            "'No person' with the person on the grid",
            f"{m['misses']} of {m['steps_with_person']}"
            + ("" if rate is None else f" ({100 * rate:.0f} %)"),
            rate is None or rate <= 0.10,
        ),
        ("wrong-cell steps", str(m["wrong_cell_steps"]), None),
        ("unseen steps", str(m["unseen_steps"]), None),
    ]


_STEP_COLUMNS = (
    ("step", "step"),
    ("stamp_s", "t [s]"),
    ("action", "action"),
    ("obs_robot", "obs robot"),
    ("obs_person", "obs person"),
    ("obs_velocity", "obs velocity"),
    ("true_robot", "true robot"),
    ("true_person", "true person"),
    ("source", "seen by"),
    ("hidden", "camera blind in"),
    ("outcome", "outcome"),
    ("nav_result", "nav"),
)


def steps_table_html(steps_csv: str) -> str:
    """The step table (``steps.csv``'s main columns) as an HTML table; misses and
    wrong cells marked."""
    rows = list(csv.DictReader(io.StringIO(steps_csv)))
    e = html.escape
    out = ["<table><tr>" + "".join(f"<th>{e(h)}</th>" for _, h in _STEP_COLUMNS) + "</tr>"]
    for r in rows:
        bad = r.get("outcome") in ("miss", "wrong cell", "phantom")
        cls = ' class="bad"' if bad else ""
        cells = "".join(f"<td>{e(r.get(k, '') or '')}</td>" for k, _ in _STEP_COLUMNS)
        out.append(f"<tr{cls}>{cells}</tr>")
    out.append("</table>")
    return "\n".join(out)


def index_html(
    title: str, summary: Mapping[str, Any], files: Sequence[str], steps_csv: str = ""
) -> str:
    """The page: metrics, links and embeds of whatever of the files exist, the step
    table (from ``steps_csv``'s text), the summary."""
    have = set(files)
    e = html.escape
    out = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{e(title)}</title><style>{_STYLE}</style></head><body>",
        f"<h1>{e(title)}</h1>",
    ]
    m = summary.get("metrics")
    if m:
        out.append("<h2>Guarding metrics</h2><table>")
        for name, value, good in _metric_rows(m):
            cls = "" if good is None else (' class="good"' if good else ' class="bad"')
            out.append(f"<tr><th>{e(name)}</th><td{cls}>{e(value)}</td></tr>")
        out.append("</table>")
        out.append(f"<p>Basis: {e(str(m.get('basis')))}. Definitions: docs/EXPERIMENTS.md.</p>")
    links = [
        (f, label)
        for f, label in (
            ("steps.md", "step table (Markdown)"),
            ("steps.csv", "step table (CSV)"),
            ("summary.json", "summary (JSON)"),
            ("camera.mp4", "video (H.264)"),
            ("timeline.png", "guarding timeline"),
            ("positions.png", "positions and reward"),
            ("belief.png", "belief over the grid"),
        )
        if f in have
    ]
    out.append("<h2>Files</h2><ul>")
    out += [f'<li><a href="{e(f)}">{e(label)}</a> ({e(f)})</li>' for f, label in links]
    out.append("</ul>")
    if "camera.mp4" in have:
        out.append('<h2>Video</h2><video controls preload="metadata" src="camera.mp4"></video>')
    for f, label in (
        ("timeline.png", "Guarding timeline"),
        ("positions.png", "Positions and reward"),
        ("belief.png", "Belief"),
    ):
        if f in have:
            out.append(f'<h2>{e(label)}</h2><img src="{e(f)}" alt="{e(label)}">')
    if steps_csv:
        out.append("<h2>Step table</h2>")
        out.append(steps_table_html(steps_csv))
    out.append("<h2>Summary</h2><pre>")
    brief = {k: v for k, v in summary.items() if k not in ("metrics", "warnings_spoken")}
    out.append(e(json.dumps(brief, indent=1, sort_keys=True)))
    out.append("</pre></body></html>")
    return "\n".join(out) + "\n"


def write_index(run_dir: str | Path, title: str, summary: Mapping[str, Any]) -> Path:
    """Write ``index.html`` into the run folder (links only files that exist)."""
    run_dir = Path(run_dir)
    files = sorted(p.name for p in run_dir.iterdir() if p.is_file())
    path = run_dir / INDEX_FILE
    steps = run_dir / "steps.csv"
    text = read_text_capped(steps, MAX_RECORD_BYTES) if steps.exists() else ""
    write_text(path, index_html(title, summary, files, text), encoding="utf-8")
    return path
