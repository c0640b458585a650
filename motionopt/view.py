"""An interactive page of motions: skeletons in 3-D with play, pause, a frame slider,
orbit and zoom, over per-frame curves of what to judge them by.

The page is one self-contained HTML file drawn with plotly (plotly.js is embedded, so it
works offline and needs no server): each clip's bones are 3-D line segments (y up) on a
floor grid at the ground height, side by side along x or overlaid, with planted feet
marked as ``plot.stick_figure`` finds them; a target path on the ground or target
points can be drawn with them. Under the 3-D view, one row per measure: hip height,
foot skating (horizontal speed of planted feet), the root's distance to the target path
when there is one, and any ``Curve`` the caller adds (a prior's NLL, say); a vertical
line follows the slider. Opening the page at ``#frame=N`` shows the page's frame ``N``.

Clips are resampled to at most ``MAX_FPS`` frames per second for the page; a shorter
clip holds its last pose. Like ``plot``, nothing replaces an existing file unless
``force`` is set. Lengths are metres, times seconds.
"""
from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import plotly.graph_objects as go
import torch

from .atomic import write_text_atomic
from .motion import Motion
from .objective import nearest_on_polyline_sq
from .plot import CONTACT_COLOR, GROUND_COLOR, StickFigure, check_output, stick_figure

#: Most frames per second a page animates (more makes the file bigger, not the motion clearer).
MAX_FPS = 30.0
#: Colours of the clips, in order: midline bones and curves; left limbs are lighter, right darker.
CLIP_COLORS = ("#1f77b4", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#7f7f7f", "#bcbd22")
#: Longest clip a page shows (seconds): each second of a clip adds about 45 kB to the page.
MAX_SECONDS = 300.0
SCENE_PX, CONTROLS_PX, CURVE_PX = 560, 110, 150
_GAP = 0.6  # metres between clips side by side
_JUMP = {"frame": {"duration": 0, "redraw": True}, "transition": {"duration": 0}, "mode": "immediate"}
#: Shows the frame named in the URL's fragment (``#frame=N``), on load and when it changes.
_HASH_HOOK = """var gd = document.getElementById('{plot_id}');
function showHashFrame() {
  var m = /frame=(\\d+)/.exec(window.location.hash);
  if (m) { Plotly.animate(gd, [m[1]], %s); }
}
showHashFrame();
window.addEventListener('hashchange', showHashFrame);"""


@dataclass(frozen=True)
class Curve:
    """A per-frame series of one clip for the rows under the 3-D view: ``measure`` names
    the row (with its unit), ``label`` the clip (its colour), ``times`` (s) and ``values``."""

    measure: str
    label: str
    times: np.ndarray
    values: np.ndarray


def _shade(hex_colour: str, towards: float, amount: float) -> str:
    """``hex_colour`` mixed with white (``towards`` 1) or black (0) by ``amount``."""
    rgb = np.array([int(hex_colour[i:i + 2], 16) for i in (1, 3, 5)], dtype=float)
    mixed = rgb + (255 * towards - rgb) * amount
    return "#" + "".join(f"{int(round(c)):02x}" for c in mixed)


def _chains(bones: Sequence[tuple[int, int]]) -> list[int]:
    """Point indices that draw ``bones`` as few polylines as possible, -1 between them
    (a chain runs down the first child; each other child starts a chain at its parent)."""
    kids: dict[int, list[int]] = {}
    for p, c in bones:
        kids.setdefault(p, []).append(c)
    children = {c for _, c in bones}
    order: list[int] = []
    starts = [(p, c) for p in kids if p not in children for c in kids[p]]
    while starts:
        p, c = starts.pop(0)
        order += ([-1] if order else []) + [p, c]
        while c in kids:
            starts += [(c, other) for other in kids[c][1:]]
            c = kids[c][0]
            order.append(c)
    return order


def _polylines(points: np.ndarray, order: Sequence[int]) -> np.ndarray:
    """(3, len(order)) x, y, z of the points in ``order`` (``_chains``), NaN at each -1
    (where plotly breaks a line)."""
    idx = np.asarray(order, dtype=int)
    out = np.full((len(idx), 3), np.nan)
    out[idx >= 0] = points[idx[idx >= 0]]
    return out.T.astype(np.float32)


def _xyz(points: np.ndarray) -> dict[str, np.ndarray]:
    """Plotly's x, y, z of (N, 3) points, as compact float32 arrays."""
    p = np.asarray(points, np.float32).reshape(-1, 3)
    return {"x": p[:, 0], "y": p[:, 1], "z": p[:, 2]}


@dataclass(frozen=True)
class _Clip:
    """One clip on the page: its figure at the page's rate, shift along x and colour."""

    label: str
    fig: StickFigure
    shift: float
    colour: str

    @property
    def right(self) -> float:
        """The largest x the clip reaches on the page."""
        return float(np.nanmax(self.fig.points[..., 0])) + self.shift

    @cached_property
    def limbs(self) -> list[list[int]]:
        """``_chains`` of the left, right and midline bones."""
        f = self.fig
        return [_chains([b for b in f.bones if f.sides[b[1]] == side]) for side in (1, -1, 0)]

    def pose(self, k: int) -> list[dict]:
        """The clip's moving traces at page frame ``k``: left, right and midline bones,
        planted feet, head."""
        f = self.fig
        t = min(k, f.num_frames - 1)
        pts = f.points[t] + np.array([self.shift, 0.0, 0.0])
        out = []
        for order in self.limbs:
            line = _polylines(pts, order)
            out.append({"x": line[0], "y": line[1], "z": line[2]})
        out.append(_xyz(pts[f.contacts[t]]))
        head = f.head_centre(t)
        out.append(_xyz(np.empty((0, 3)) if head is None else head + np.array([self.shift, 0.0, 0.0])))
        return [{"type": "scatter3d", **d} for d in out]

    def traces(self) -> list[go.Scatter3d]:
        """The moving traces at frame 0, styled (see ``pose``)."""
        c, group = self.colour, self.label
        styles = [dict(mode="lines", line=dict(color=_shade(c, 1, 0.45), width=6), name=f"{group}: left",
                       showlegend=False),
                  dict(mode="lines", line=dict(color=_shade(c, 0, 0.35), width=6), name=f"{group}: right",
                       showlegend=False),
                  dict(mode="lines", line=dict(color=c, width=7), name=group, showlegend=True),
                  dict(mode="markers", marker=dict(color=CONTACT_COLOR, size=6, line=dict(color="black", width=1)),
                       name=f"{group}: planted feet", showlegend=False),
                  dict(mode="markers", marker=dict(color="white", size=11, line=dict(color=c, width=3)),
                       name=f"{group}: head", showlegend=False)]
        return [go.Scatter3d(**data, **style, legendgroup=group, hoverinfo="name")
                for data, style in zip(self.pose(0), styles)]


def measures(fig: StickFigure, path: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The per-frame curves the page draws for a clip: hip height above its floor (m),
    foot skating (cm/s: mean horizontal speed of its planted feet, NaN where none is
    planted) and, with a target ``path`` (N, 2) on the ground, the hips' distance to it (cm)."""
    pts = fig.points
    speed = np.zeros(pts.shape[:2])
    speed[1:] = np.linalg.norm(np.diff(pts[..., [0, 2]], axis=0), axis=-1) * fig.fps
    speed[0] = speed[1] if len(speed) > 1 else 0.0
    planted = fig.contacts
    with np.errstate(invalid="ignore"):
        skating = np.where(planted.any(axis=1), (speed * planted).sum(axis=1) / planted.sum(axis=1), np.nan)
    out = {"hip height (m)": pts[:, fig.root, 1] - fig.ground, "foot skating (cm/s)": skating * 100}
    if path is not None:
        d2 = nearest_on_polyline_sq(torch.from_numpy(pts[:, fig.root, [0, 2]]), torch.from_numpy(path))
        out["distance to the path (cm)"] = np.sqrt(d2.numpy()) * 100
    return out


def _check_path(path: np.ndarray | None, points: np.ndarray | None) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The target path as (N, 2) x, z and target points as (M, 3), checked."""
    if path is not None:
        path = np.asarray(path, dtype=np.float64)
        if path.ndim != 2 or path.shape[1] != 2 or len(path) < 2:
            raise ValueError(f"the target path must be (N, 2) x, z points with N >= 2, got shape {path.shape}")
    if points is not None:
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3) if np.size(points) else np.empty((0, 3))
    return path, points


def _floor(ground: float, x: tuple[float, float], z: tuple[float, float]) -> list[go.BaseTraceType]:
    """A floor at height ``ground`` over ``x`` by ``z``: a light surface and a grid every
    half metre (every metre or more over a large floor)."""
    step = max(0.5, float(np.ceil(max(x[1] - x[0], z[1] - z[0]) / 40)))
    lines = []
    for u in np.arange(np.ceil(x[0] / step) * step, x[1] + 1e-9, step):
        lines += [(u, ground, z[0]), (u, ground, z[1]), (np.nan,) * 3]
    for w in np.arange(np.ceil(z[0] / step) * step, z[1] + 1e-9, step):
        lines += [(x[0], ground, w), (x[1], ground, w), (np.nan,) * 3]
    surface = go.Mesh3d(x=[x[0], x[1], x[1], x[0]], y=[ground] * 4, z=[z[0], z[0], z[1], z[1]], i=[0, 0], j=[1, 2],
                        k=[2, 3], color=GROUND_COLOR, opacity=0.18, hoverinfo="skip", name="floor", showlegend=False)
    grid = go.Scatter3d(**_xyz(np.array(lines)), mode="lines", line=dict(color=GROUND_COLOR, width=1),
                        hoverinfo="skip", name="floor grid", showlegend=False)
    return [surface, grid]


def _place(clips: Mapping[str, Motion], rate: float, overlay: bool) -> list[_Clip]:
    """The clips' figures at ``rate``, each shifted along x to start right of the one
    before (``_GAP`` between them) unless ``overlay``."""
    placed: list[_Clip] = []
    for i, (label, motion) in enumerate(clips.items()):
        f = stick_figure(motion.resample(rate))
        x = f.points[..., 0]
        shift = 0.0 if overlay or not placed else placed[-1].right + _GAP - float(x.min())
        placed.append(_Clip(label, f, shift, CLIP_COLORS[i % len(CLIP_COLORS)]))
    return placed


def _marks(path: np.ndarray | None, points: np.ndarray | None, ground: float) -> list[go.Scatter3d]:
    """The target path (a dashed line on the floor) and target points (diamonds)."""
    out = []
    if path is not None:
        on_floor = np.column_stack((path[:, 0], np.full(len(path), ground + 0.005), path[:, 1]))
        out.append(go.Scatter3d(**_xyz(on_floor), mode="lines+markers", line=dict(color="black", width=4, dash="dash"),
                                marker=dict(size=2, color="black"), name="target path"))
    if points is not None and len(points):
        out.append(go.Scatter3d(**_xyz(points), mode="markers", name="targets", marker=dict(
            size=5, color="#d62728", symbol="diamond", line=dict(color="black", width=1))))
    return out


def _ranges(placed: list[_Clip], marks: list[go.Scatter3d], ground: float) -> list[tuple[float, float]]:
    """x, y and z ranges around everything drawn, over every frame (fixed, so that the
    axes do not jump from frame to frame)."""
    drawn = [c.fig.points.reshape(-1, 3) + np.array([c.shift, 0.0, 0.0]) for c in placed]
    drawn += [np.column_stack((m.x, m.y, m.z)) for m in marks]
    lo, hi = np.nanmin(np.concatenate(drawn), axis=0), np.nanmax(np.concatenate(drawn), axis=0)
    return [(lo[0] - 0.4, hi[0] + 0.4), (min(ground, lo[1]) - 0.05, hi[1] + 0.25), (lo[2] - 0.4, hi[2] + 0.4)]


def _scene(ranges: list[tuple[float, float]], bottom: float) -> dict:
    """The 3-D scene's layout above ``bottom`` (paper height): y up, metres alike on every axis."""
    span = np.array([b - a for a, b in ranges])
    ratio = span / span.max()
    return dict(domain=dict(x=[0, 1], y=[bottom, 1]), aspectmode="manual",
                aspectratio=dict(x=ratio[0], y=ratio[1], z=ratio[2]),
                **{f"{a}axis": dict(range=r, title=f"{a} (m)") for a, r in zip("xyz", ranges)},
                camera=dict(up=dict(x=0, y=1, z=0), eye=dict(x=0.9, y=0.6, z=1.2)))


def _curves(rows: Mapping[str, Sequence[Curve]], colours: Mapping[str, str], height: float,
            duration: float) -> tuple[list[go.Scatter], list[int], dict]:
    """The traces and axes of the rows of curves, from the bottom of the page up,
    ``CURVE_PX`` each: one line per clip, and a cursor (a vertical line) that the frames
    move, whose places in the traces come second."""
    traces, cursors, layout = [], [], {}
    curve_top = CURVE_PX * len(rows) / height
    for r, (measure, series) in enumerate(rows.items()):
        axis = "" if r == 0 else str(r + 1)
        top = curve_top - r * CURVE_PX / height
        last = r == len(rows) - 1
        layout[f"yaxis{axis}"] = dict(domain=[top - (CURVE_PX - 28) / height, top], title=dict(text=measure),
                                      anchor=f"x{axis}")
        layout[f"xaxis{axis}"] = dict(anchor=f"y{axis}", matches="x" if r else None, range=[0, duration],
                                      showticklabels=last, title=dict(text="time (s)") if last else None)
        where = dict(xaxis=f"x{axis}", yaxis=f"y{axis}", showlegend=False)
        for s in series:
            traces.append(go.Scatter(x=np.asarray(s.times, np.float32), y=np.asarray(s.values, np.float32),
                                     mode="lines", line=dict(color=colours.get(s.label, "black"), width=1.5),
                                     name=f"{s.label}: {measure}", legendgroup=s.label, **where))
        values = np.concatenate([np.asarray(s.values, np.float64).ravel() for s in series])
        values = values[np.isfinite(values)]
        span = [float(values.min()), float(values.max())] if len(values) else [0.0, 1.0]
        cursors.append(len(traces))
        traces.append(go.Scatter(x=[0.0, 0.0], y=span, mode="lines", line=dict(color="black", width=1),
                                 hoverinfo="skip", **where))
    return traces, cursors, layout


def _controls(n_frames: int, rate: float, y: float) -> dict:
    """Play and pause buttons and the frame slider (labelled in seconds) at height ``y``."""
    play = {**_JUMP, "frame": {"duration": 1000 / rate, "redraw": True}, "fromcurrent": True}
    buttons = dict(type="buttons", direction="left", x=0, y=y, xanchor="left", yanchor="top", pad=dict(t=10, r=10),
                   showactive=False, buttons=[dict(label="play", method="animate", args=[None, play]),
                                              dict(label="pause", method="animate", args=[[None], _JUMP])])
    # the steps' own labels are hidden (hundreds would overlap); the current one shows above the slider
    slider = dict(active=0, x=0.12, len=0.88, y=y, yanchor="top", pad=dict(t=10), font=dict(color="rgba(0,0,0,0)"),
                  currentvalue=dict(prefix="time (s): ", font=dict(size=13, color="#333333")), ticklen=2,
                  minorticklen=0, steps=[dict(label=f"{k / rate:.2f}", method="animate", args=[[str(k)], _JUMP])
                                         for k in range(n_frames)])
    return dict(updatemenus=[buttons], sliders=[slider])


def view_figure(clips: Mapping[str, Motion], overlay: bool = False, path: np.ndarray | None = None,
                points: np.ndarray | None = None, curves: Sequence[Curve] = (), title: str | None = None) -> go.Figure:
    """The page's plotly figure of the labelled ``clips`` (see the module docstring):
    side by side along x (the first clip where it is; ``path`` and ``points`` are drawn
    in its world coordinates) or, with ``overlay``, where they are; the floor is the
    first clip's. ``curves`` add rows (or lines to a row of the same measure)."""
    if not clips:
        raise ValueError("give at least one motion to view")
    path, points = _check_path(path, points)
    for label, m in clips.items():
        if m.duration > MAX_SECONDS:
            raise ValueError(f"{label} lasts {m.duration:.0f} s; a page shows at most {MAX_SECONDS:.0f} s: view a "
                             "part of it (--start/--stop)")
    rate = min(MAX_FPS, max(m.fps for m in clips.values()))
    placed = _place(clips, rate, overlay)
    n_frames = max(c.fig.num_frames for c in placed)
    ground = placed[0].fig.ground
    rows: dict[str, list[Curve]] = {}
    for c in placed:
        for measure, values in measures(c.fig, path).items():
            rows.setdefault(measure, []).append(Curve(measure, c.label, np.arange(len(values)) / rate, values))
    for curve in curves:
        rows.setdefault(curve.measure, []).append(curve)
    height = SCENE_PX + CONTROLS_PX + CURVE_PX * len(rows) + 60
    controls_y = (CURVE_PX * len(rows) + CONTROLS_PX) / height

    marks = _marks(path, points, ground)
    ranges = _ranges(placed, marks, ground)
    traces: list[go.BaseTraceType] = _floor(ground, ranges[0], ranges[2]) + marks
    moving = list(range(len(traces), len(traces) + 5 * len(placed)))  # the traces each frame updates
    traces += [t for c in placed for t in c.traces()]
    plots, cursors, axes = _curves(rows, {c.label: c.colour for c in placed}, height, (n_frames - 1) / rate)
    cursors = [len(traces) + i for i in cursors]
    traces += plots
    frames = [go.Frame(name=str(k), traces=moving + cursors,
                       data=[d for c in placed for d in c.pose(k)]
                       + [{"type": "scatter", "x": [k / rate, k / rate]}] * len(cursors))
              for k in range(n_frames)]
    fig = go.Figure(data=traces, frames=frames)
    fig.update_layout(height=height, margin=dict(l=60, r=20, t=50, b=40), title=dict(text=title or " / ".join(clips)),
                      legend=dict(x=0, y=1, yanchor="top", bgcolor="rgba(255,255,255,0.7)"),
                      scene=_scene(ranges, controls_y), **_controls(n_frames, rate, controls_y), **axes)
    return fig


def view_html(clips: Mapping[str, Motion], overlay: bool = False, path: np.ndarray | None = None,
              points: np.ndarray | None = None, curves: Sequence[Curve] = (), title: str | None = None) -> str:
    """The page of ``view_figure``: a whole HTML document with plotly.js inside."""
    fig = view_figure(clips, overlay, path, points, curves, title)
    return fig.to_html(include_plotlyjs=True, full_html=True, auto_play=False,
                       config={"responsive": True, "displaylogo": False}, post_script=_HASH_HOOK % json.dumps(_JUMP))


def write_view(out: str | Path, clips: Mapping[str, Motion], overlay: bool = False, path: np.ndarray | None = None,
               points: np.ndarray | None = None, curves: Sequence[Curve] = (), title: str | None = None,
               force: bool = False) -> Path:
    """Write the page of ``view_html`` to ``out`` (.html); return its path."""
    out = check_output(out, (".html",), force)
    write_text_atomic(out, view_html(clips, overlay, path, points, curves, title))
    return out
