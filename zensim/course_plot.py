"""The course's figure: one SVG image of every run, written beside course.md (no plotting library needed).

Per item, one row of dots, one per seed: how far the robot walked (x, m), green when it survived, red when it
fell (with the time it fell), grey when the run was skipped; and a bar for the share of seeds that survived.
SVG is text a browser, an editor or a README shows as it is, so the figure needs nothing the project does not
ship (matplotlib is not a dependency; plotly's static export needs kaleido and a browser of its own).
"""

from __future__ import annotations

from collections.abc import Sequence
from html import escape
from typing import Protocol

from .scenario_score import ScenarioResult

ROW_PX = 28
LABEL_PX = 120
PLOT_PX = 420
SHARE_PX = 120
MARGIN_PX = 16
SURVIVED = "#2e9e44"
FELL = "#d43d3d"
SKIPPED = "#9a9a9a"


class PlottedRun(Protocol):
    """What the figure reads of a course row."""

    @property
    def item(self) -> str: ...

    @property
    def seed(self) -> int: ...

    @property
    def result(self) -> ScenarioResult | None: ...


def course_svg(rows: Sequence[PlottedRun], title: str) -> str:
    """The course's runs as an SVG document."""
    items = list(dict.fromkeys(row.item for row in rows))
    distances = [row.result.distance_m for row in rows if row.result is not None]
    longest = max([1.0, *distances])
    scale = PLOT_PX / (longest * 1.1)
    width = LABEL_PX + PLOT_PX + SHARE_PX + 3 * MARGIN_PX
    top = 2 * ROW_PX
    height = top + ROW_PX * len(items) + 2 * ROW_PX
    plot_x = LABEL_PX + MARGIN_PX
    share_x = plot_x + PLOT_PX + 2 * MARGIN_PX
    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
             f'font-family="sans-serif" font-size="12">',
             f'<rect width="{width}" height="{height}" fill="white"/>',
             f'<text x="{MARGIN_PX}" y="{ROW_PX - 8}" font-size="14">{escape(title)}</text>',
             f'<text x="{plot_x}" y="{top - 8}">distance walked, m (dot: one seed; green survived, red fell)</text>',
             f'<text x="{share_x}" y="{top - 8}">survived</text>']
    for index, item in enumerate(items):
        y = top + index * ROW_PX
        middle = y + ROW_PX / 2
        parts.append(f'<text x="{MARGIN_PX}" y="{middle + 4:.0f}">{escape(item)}</text>')
        parts.append(f'<line x1="{plot_x}" y1="{middle:.0f}" x2="{plot_x + PLOT_PX}" y2="{middle:.0f}" stroke="#e4e4e4"/>')
        runs = [row for row in rows if row.item == item]
        done = [row.result for row in runs if row.result is not None]
        for row in runs:
            result = row.result
            if result is None:
                parts.append(f'<circle cx="{plot_x}" cy="{middle:.0f}" r="5" fill="{SKIPPED}">'
                             f'<title>seed {row.seed}: skipped</title></circle>')
                continue
            color = SURVIVED if result.survived else FELL
            said = "survived" if result.survived else (
                "did not finish" if result.fell_at_s is None else f"fell at {result.fell_at_s:.1f} s")
            parts.append(f'<circle cx="{plot_x + result.distance_m * scale:.1f}" cy="{middle:.0f}" r="5" '
                         f'fill="{color}" fill-opacity="0.75"><title>seed {row.seed}: {result.distance_m:.2f} m, '
                         f'{said}</title></circle>')
        survived = sum(1 for result in done if result.survived)
        share = survived / len(done) if done else 0.0
        parts.append(f'<rect x="{share_x}" y="{y + 6}" width="{SHARE_PX}" height="{ROW_PX - 12}" fill="#f0f0f0"/>')
        parts.append(f'<rect x="{share_x}" y="{y + 6}" width="{share * SHARE_PX:.1f}" height="{ROW_PX - 12}" '
                     f'fill="{SURVIVED}"/>')
        parts.append(f'<text x="{share_x + SHARE_PX + 4}" y="{middle + 4:.0f}">{survived}/{len(done)}</text>')
    axis_y = top + len(items) * ROW_PX + 4
    parts.append(f'<line x1="{plot_x}" y1="{axis_y}" x2="{plot_x + PLOT_PX}" y2="{axis_y}" stroke="black"/>')
    step = 1 if longest <= 8 else 2 if longest <= 16 else 5
    for metres in range(0, int(longest * 1.1) + 1, step):
        x = plot_x + metres * scale
        parts.append(f'<line x1="{x:.1f}" y1="{axis_y}" x2="{x:.1f}" y2="{axis_y + 5}" stroke="black"/>')
        parts.append(f'<text x="{x:.1f}" y="{axis_y + 18}" text-anchor="middle">{metres}</text>')
    parts.append("</svg>")
    return "\n".join(parts) + "\n"
