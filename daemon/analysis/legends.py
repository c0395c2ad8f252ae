"""Legends that hide nothing (the report's figures, daemon/analysis/plots.py): each legend is
placed at the first spot inside its axes where it covers no line and no other legend, else
outside the axes, and the figure is redrawn until the layout settles."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Literal

import numpy as np
from matplotlib.axes import Axes
from matplotlib.container import BarContainer
from matplotlib.figure import Figure
from matplotlib.legend import Legend
from matplotlib.lines import Line2D
from matplotlib.transforms import Bbox

#: Clearance kept between a legend box and what it must not hide (display pixels at DPI 100).
LEGEND_CLEARANCE_PX = 3.0
LegendLoc = Literal[
    "upper left",
    "upper right",
    "lower left",
    "lower right",
    "center left",
    "center right",
    "upper center",
    "lower center",
    "center",
]
_SIDES: tuple[tuple[LegendLoc, float], ...] = (
    ("center right", 1.0),
    ("center left", 0.0),
    ("center", 0.5),
)
#: Where a legend may sit inside the axes: (the legend's point, the axes point it is put at,
#: in axes fractions). First the corners and edge centres, then between them at the sides
#: (a gap between a rising and a falling curve is often at 3/4 or 1/4 of the height).
LEGEND_SPOTS: tuple[tuple[LegendLoc, tuple[float, float]], ...] = (
    ("upper left", (0.0, 1.0)),
    ("upper right", (1.0, 1.0)),
    ("lower left", (0.0, 0.0)),
    ("lower right", (1.0, 0.0)),
    ("center left", (0.0, 0.5)),
    ("center right", (1.0, 0.5)),
    ("upper center", (0.5, 1.0)),
    ("lower center", (0.5, 0.0)),
    *((side, (x, height)) for height in (0.75, 0.25, 0.85, 0.15, 0.65, 0.35) for side, x in _SIDES),
)
#: Rounds of placing legends and redrawing: a legend moved outside an axes makes the
#: constrained layout shrink that axes, which may move what another legend sits over.
LEGEND_ROUNDS = 3


def _line_hits(line: Line2D, box: Bbox) -> bool:
    """Whether a drawn line (or its markers) touches ``box`` (display coordinates): its
    segments crossing the box, or any of its points inside it."""
    xy = np.asarray(line.get_xydata(), dtype=float)
    if xy.size == 0:
        return False
    finite = np.isfinite(xy).all(axis=1)
    if not finite.any():
        return False
    transform = line.get_transform()
    points = transform.transform(xy[finite])
    margin = LEGEND_CLEARANCE_PX + (
        float(line.get_markersize()) / 2 if line.get_marker() not in (None, "None", "", " ") else 0
    )
    grown = box.expanded(1.0, 1.0).padded(margin)
    inside = (
        (points[:, 0] >= grown.x0)
        & (points[:, 0] <= grown.x1)
        & (points[:, 1] >= grown.y0)
        & (points[:, 1] <= grown.y1)
    )
    if inside.any():
        return True
    if line.get_linestyle() in ("None", "none", "", " "):
        return False
    # segments between consecutive finite points (a NaN is a gap: no segment across it)
    path = transform.transform_path(line.get_path())
    return bool(path.intersects_bbox(grown, filled=False))


def legend_obstacles(ax: Axes) -> Iterator[Line2D | Bbox]:
    """What a legend of ``ax`` must not hide: every drawn line (the data and the reference
    lines), the text boxes and the bars. Shaded bands (the +-S_x span) are not obstacles:
    they fill the whole width, and a legend over a pale band hides no value."""
    for line in ax.get_lines():
        if line.get_visible():
            yield line
    for text in ax.texts:
        if text.get_visible() and text.get_text():
            yield text.get_window_extent()
    for container in ax.containers:
        if isinstance(container, BarContainer):
            for bar in container.patches:
                yield bar.get_window_extent()


def legend_overlaps(ax: Axes, legend: Legend) -> list[str]:
    """Labels (or kinds) of what ``legend``'s box hides on ``ax`` in the last drawing."""
    box = legend.get_window_extent()
    hidden = []
    for obstacle in legend_obstacles(ax):
        if isinstance(obstacle, Line2D):
            if _line_hits(obstacle, box):
                hidden.append(str(obstacle.get_label()))
        elif obstacle.overlaps(box.padded(LEGEND_CLEARANCE_PX)):
            hidden.append("text or bar")
    return hidden


def place_legends(figure: Figure, axes: list[Axes], fontsize: float = 10) -> None:
    """Give each axes with labelled artists a legend that hides nothing it shows.

    matplotlib's ``loc="best"`` only minimises the overlap; when every spot covers some data
    (a noisy error fills its panel) it still covers a curve. Here each corner and edge centre
    is tried in turn on the laid-out figure, and the first whose box touches no line, text box
    or bar wins; when none is free the legend goes outside the axes, at its right."""
    outside: set[int] = set()
    for ax in axes:
        handles, labels = ax.get_legend_handles_labels()
        if handles:
            corner, anchor = LEGEND_SPOTS[0]
            ax.legend(
                handles=handles,
                labels=labels,
                loc=corner,
                bbox_to_anchor=anchor,
                bbox_transform=ax.transAxes,
                fontsize=fontsize,
            )
    for _ in range(LEGEND_ROUNDS):
        figure.draw_without_rendering()  # lays the axes out; then a legend's box is known
        relaid = False  # only a legend put outside changes the layout (inside ones do not)
        for index, ax in enumerate(axes):
            legend = ax.get_legend()
            if legend is None or index in outside or not legend_overlaps(ax, legend):
                continue
            for corner, anchor in LEGEND_SPOTS:
                legend.set_loc(corner)
                legend.set_bbox_to_anchor(anchor, transform=ax.transAxes)
                if not legend_overlaps(ax, legend):
                    break
            else:
                outside.add(index)
                relaid = True
                handles, labels = ax.get_legend_handles_labels()
                ax.legend(
                    handles=handles,
                    labels=labels,
                    loc="upper left",
                    bbox_to_anchor=(1.01, 1.0),
                    borderaxespad=0.0,
                    fontsize=fontsize,
                )
        if not relaid:
            return
