"""Pictures of motions: ground-plane root paths, joint trajectories, stick-figure
filmstrips and animated GIFs, drawn with matplotlib and written to files.

Every function writes one file and returns its path. Figures are drawn on the Agg
canvas without pyplot, so nothing opens a window and a notebook's backend is left
alone (show a written picture with ``IPython.display.Image(path)``). Like
``bvh.save``, no function replaces an existing file unless ``force`` is set.

Stick figures are orthographic views from a fixed camera beside the body: screen
right is the direction of travel (or the way the body faces when it stays in place),
up is the world's y axis, and ``elevation`` tilts the camera down to show the floor.
Lengths are metres, times seconds.
"""
from __future__ import annotations

import fnmatch
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from matplotlib.animation import PillowWriter
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Circle
from tqdm import tqdm

from . import rotations as R
from .features import DEFAULT_DROP, contact_labels, default_spec, estimate_ground
from .kinematics import fk
from .motion import Motion
from .skeleton import Skeleton

#: A motion, or its positions: (T, 3) one joint or root, (T, 2) ground-plane x, z, (T, J, 3) all joints.
Track = Motion | np.ndarray

LEFT_COLOR, RIGHT_COLOR, CENTRE_COLOR = "#1f77b4", "#d62728", "#404040"
CONTACT_COLOR = "#2ca02c"
GROUND_COLOR = "#8c7b6b"
_LEFT = re.compile(r"[Ll]eft|LEFT|^l(?=[A-Z])|^L(?=[A-Z_])|[_.][Ll]$")
_RIGHT = re.compile(r"[Rr]ight|RIGHT|^r(?=[A-Z])|^R(?=[A-Z_])|[_.][Rr]$")
_HEAD_RADIUS = 0.1  # metres
GIF_FPS = 25.0  # default animation rate: a whole number of GIF's 1/100 s ticks per frame


def _side(name: str) -> int:
    """+1 for a left joint, -1 for a right one, 0 on the body's midline (by name)."""
    return 1 if _LEFT.search(name) else -1 if _RIGHT.search(name) else 0


@dataclass(frozen=True)
class StickFigure:
    """What a stick figure draws: world points of the shown joints and end sites per
    frame, the bones joining them, and foot contacts.

    Fingers, eyes and a static top joint (Bandai's ``joint_Root``) are left out so the
    figure reads at a glance; hands and feet keep their End Sites.
    """

    points: np.ndarray  # (T, P, 3) metres
    bones: tuple[tuple[int, int], ...]  # (parent point, child point)
    sides: np.ndarray  # (P,) +1 left, -1 right, 0 midline
    contacts: np.ndarray  # (T, P) bool: joint planted on the ground
    head: int | None  # point index of the head joint, drawn as a circle
    neck: int | None  # point the head circle leans away from
    ground: float  # floor height, metres
    fps: float

    @property
    def num_frames(self) -> int:
        return self.points.shape[0]

    @property
    def root(self) -> int:
        """Point index of the body root (the hips): always the first point."""
        return 0

    def head_centre(self, t: int | slice = slice(None)) -> np.ndarray | None:
        """Centre of the head circle: a head radius beyond the head joint, away from the neck."""
        if self.head is None:
            return None
        h = self.points[t, self.head]
        if self.neck is None:
            return h
        d = h - self.points[t, self.neck]
        return h + _HEAD_RADIUS * d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-9)


def body_root(skeleton: Skeleton) -> int:
    """Index of the joint that carries the body (the hips): the top joint, or its only
    child when the top joint is a helper named like a root (Bandai's ``joint_Root``)."""
    kids = skeleton.children(0)
    return kids[0] if len(kids) == 1 and "root" in skeleton.names[0].lower() else 0


def stick_figure(motion: Motion) -> StickFigure:
    """The points, bones and contacts to draw for ``motion``."""
    sk = motion.skeleton
    top = body_root(sk)
    shown = [j for j, n in enumerate(sk.names)
             if j >= top and not any(fnmatch.fnmatchcase(n, p) for p in DEFAULT_DROP)]
    pos, grot = fk(sk.parents, torch.from_numpy(motion.rotations), torch.from_numpy(motion.root),
                   torch.from_numpy(sk.offsets),
                   None if motion.translations is None else torch.from_numpy(motion.translations),
                   return_global_rotations=True)
    index = {j: i for i, j in enumerate(shown)}
    points = [pos[:, j] for j in shown]
    bones: list[tuple[int, int]] = []
    sides = [_side(sk.names[j]) for j in shown]
    for j in shown:
        p = int(sk.parents[j])
        while p != -1 and p not in index:
            p = int(sk.parents[p])
        if p != -1:
            bones.append((index[p], index[j]))
    owner: list[int] = list(range(len(shown)))  # point -> the shown joint it belongs to
    for j in shown:
        if j in sk.end_sites and not sk.children(j):
            points.append(pos[:, j] + R.quat_apply(grot[:, j], torch.from_numpy(sk.end_sites[j]).expand_as(pos[:, j])))
            bones.append((index[j], len(points) - 1))
            sides.append(sides[index[j]])
            owner.append(index[j])
    pts = torch.stack(points, dim=1).numpy()
    ground = estimate_ground(pts, list(range(pts.shape[1])))
    contacts = np.zeros(pts.shape[:2], dtype=bool)
    try:
        spec = default_spec(sk)
    except ValueError:  # no joint named like a foot: no contacts to show
        spec = None
    if spec is not None:
        cidx = [sk.index(n) for n in spec.contact_joints if sk.index(n) in index]
        labels = contact_labels(pos.numpy(), cidx, motion.fps, ground, spec.contact_height, spec.contact_speed)
        for c, j in enumerate(cidx):
            for i, o in enumerate(owner):
                if o == index[j]:
                    contacts[:, i] |= labels[:, c] > 0.5
    names = [sk.names[j].lower() for j in shown]
    head = next((i for i, n in enumerate(names) if "head" in n), None)
    neck = None
    if head is not None:
        neck = next((p for p, c in bones if c == head), None)
    return StickFigure(pts, tuple(bones), np.array(sides), contacts, head, neck, ground, motion.fps)


@dataclass(frozen=True)
class Camera:
    """A fixed orthographic camera beside the body (see the module docstring)."""

    forward: np.ndarray  # (3,) unit vector on the ground plane: screen right
    left: np.ndarray  # (3,) unit vector on the ground plane, pointing away from the camera
    elevation: float = 0.0  # radians the camera looks down

    @property
    def up(self) -> np.ndarray:
        """World direction shown as screen up."""
        e = self.elevation
        return np.array([0.0, np.cos(e), 0.0]) + np.sin(e) * self.left

    def project(self, p: np.ndarray) -> np.ndarray:
        """Screen coordinates (..., 2) in metres of world points (..., 3)."""
        return np.stack((p @ self.forward, p @ self.up), axis=-1)

    def depth(self, p: np.ndarray) -> np.ndarray:
        """Distance along the view direction (larger is farther from the camera)."""
        e = self.elevation
        return p @ (np.cos(e) * self.left - np.sin(e) * np.array([0.0, 1.0, 0.0]))

    def floor_depth(self, p: np.ndarray) -> np.ndarray:
        """Distance along the view direction's track on the ground (larger is farther), which
        places a point's foot on the floor: its height does not count, as it does in ``depth``."""
        return p @ self.left

    @classmethod
    def beside(cls, sf: StickFigure, elevation_deg: float = 0.0) -> "Camera":
        """A camera that sees ``sf`` from its side: screen right along the root's travel
        when it travels over a metre, else the way the body faces on average."""
        up = np.array([0.0, 1.0, 0.0])
        travel = sf.points[-1, sf.root] - sf.points[0, sf.root]
        travel[1] = 0.0
        if np.linalg.norm(travel) > 1.0:
            forward = travel / np.linalg.norm(travel)
        else:
            forward = np.cross(_mean_left(sf), up)  # left x up = forward (y up, right-handed)
        left = np.cross(up, forward)
        return cls(forward, left / np.linalg.norm(left), np.deg2rad(elevation_deg))


def _mean_left(sf: StickFigure) -> np.ndarray:
    """Unit ground-plane vector from the body's right side to its left, averaged over
    frames (the x axis when the joints have no left/right names)."""
    if not ((sf.sides > 0).any() and (sf.sides < 0).any()):
        return np.array([1.0, 0.0, 0.0])
    lat = sf.points[:, sf.sides > 0].mean(axis=1) - sf.points[:, sf.sides < 0].mean(axis=1)
    lat[:, 1] = 0.0
    lat = (lat / np.maximum(np.linalg.norm(lat, axis=-1, keepdims=True), 1e-9)).mean(axis=0)
    n = np.linalg.norm(lat)
    return lat / n if n > 1e-6 else np.array([1.0, 0.0, 0.0])


# ---- shared drawing pieces ---------------------------------------------------------------------

def _new_figure(width: float, height: float, dpi: float = 100) -> Figure:
    fig = Figure(figsize=(width, height), dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def check_output(out: str | Path, suffixes: tuple[str, ...], force: bool) -> Path:
    """``out`` as a Path, after checking its suffix, its folder, and that it is new (or ``force``)."""
    out = Path(out)
    if out.suffix.lower() not in suffixes:
        raise ValueError(f"{out}: picture files must end in {' or '.join(suffixes)}")
    if out.exists() and not force:
        raise FileExistsError(f"{out} exists; pass force=True (--force) to overwrite it")
    if not out.parent.exists():
        raise FileNotFoundError(f"folder {out.parent} does not exist; create it first")
    return out


def _save(fig: Figure, out: Path) -> Path:
    fig.savefig(out, dpi=fig.dpi, facecolor="white", bbox_inches="tight", pad_inches=0.15)
    return out


class _Figure2D:
    """Artists of one stick figure on one axes, updated frame by frame."""

    def __init__(self, ax: Axes, fig: StickFigure, cam: Camera, lw: float = 2.2, shadow: bool = False):
        self.fig, self.cam = fig, cam
        # draw the far side first so the near limbs cover it
        depth = np.array([cam.depth(fig.points[:, c]).mean() for _, c in fig.bones])
        self.order = np.argsort(-depth)
        colors = {1: LEFT_COLOR, -1: RIGHT_COLOR, 0: CENTRE_COLOR}
        self.colors = [colors[int(fig.sides[fig.bones[i][1]])] for i in self.order]
        self.shadow = LineCollection([], colors="#00000022", linewidths=lw * 1.6, capstyle="round",
                                     zorder=2) if shadow else None
        if self.shadow is not None:
            ax.add_collection(self.shadow)
        self.lines = LineCollection([], colors=self.colors, linewidths=lw, capstyle="round", zorder=3)
        ax.add_collection(self.lines)
        self.joints = ax.scatter([], [], s=(lw * 2.2) ** 2, c=CENTRE_COLOR, zorder=4, linewidths=0)
        self.feet = ax.scatter([], [], s=(lw * 4.5) ** 2, facecolors=CONTACT_COLOR, edgecolors="black",
                               linewidths=0.8, zorder=5)
        self.head = Circle((0, 0), _HEAD_RADIUS, facecolor="white", edgecolor=CENTRE_COLOR, linewidth=lw,
                           zorder=4) if fig.head is not None else None
        if self.head is not None:
            ax.add_patch(self.head)

    def update(self, t: int, du: float = 0.0) -> None:
        """Show frame ``t``, shifted ``du`` metres along screen x."""
        f, cam = self.fig, self.cam
        s = cam.project(f.points[t]) - np.array([du, 0.0])
        bones = [f.bones[i] for i in self.order]
        self.lines.set_segments([s[[p, c]] for p, c in bones])
        self.joints.set_offsets(s)
        self.feet.set_offsets(s[f.contacts[t]] if f.contacts[t].any() else np.empty((0, 2)))
        if self.head is not None:
            self.head.center = tuple(cam.project(f.head_centre(t)) - np.array([du, 0.0]))
        if self.shadow is not None:
            flat = f.points[t].copy()
            flat[:, 1] = f.ground
            sh = cam.project(flat) - np.array([du, 0.0])
            self.shadow.set_segments([sh[[p, c]] for p, c in bones])


def _draw_ground(ax: Axes, cam: Camera, ground: float, u_range: tuple[float, float],
                 depth_range: tuple[float, float], du: float = 0.0, spacing: float = 0.5) -> None:
    """The floor under screen x in ``u_range`` (world metres, drawn shifted by ``du``):
    a line with ticks every ``spacing`` metres seen from the side, a grid band when the
    camera looks down."""
    u0, u1 = u_range
    ticks = np.arange(np.floor(u0 / spacing) * spacing, u1 + spacing, spacing) - du
    u0, u1 = u0 - du, u1 - du
    if cam.elevation < 1e-3:
        v = ground
        ax.axhline(v, color=GROUND_COLOR, linewidth=2, zorder=1)
        ax.axhspan(v - 10, v, color=GROUND_COLOR, alpha=0.15, zorder=0, linewidth=0)
        ax.add_collection(LineCollection([[(u, v), (u - 0.06, v - 0.06)] for u in ticks],
                                         colors=GROUND_COLOR, linewidths=1, zorder=1))
        return
    e = cam.elevation
    near, far = depth_range
    v_near, v_far = ground * np.cos(e) + near * np.sin(e), ground * np.cos(e) + far * np.sin(e)
    rows = np.arange(np.floor(near / spacing) * spacing, far + 1e-9, spacing)
    segs = [[(u, v_near), (u, v_far)] for u in ticks]
    segs += [[(u0 - spacing, ground * np.cos(e) + d * np.sin(e)), (u1 + spacing, ground * np.cos(e) + d * np.sin(e))]
             for d in rows]
    ax.axhspan(v_near, v_far, color=GROUND_COLOR, alpha=0.12, zorder=0, linewidth=0)
    ax.add_collection(LineCollection(segs, colors=GROUND_COLOR, linewidths=0.7, alpha=0.6, zorder=1))


def _legend_handles(any_contacts: bool) -> list:
    h = [Line2D([], [], color=LEFT_COLOR, lw=2.2, label="left limbs"),
         Line2D([], [], color=RIGHT_COLOR, lw=2.2, label="right limbs")]
    if any_contacts:
        h.append(Line2D([], [], marker="o", ls="", markerfacecolor=CONTACT_COLOR, markeredgecolor="black",
                        markersize=8, label="foot on the ground"))
    return h


# ---- pictures ------------------------------------------------------------------------------------

def _ground_xz(track: Track) -> np.ndarray:
    """(T, 2) ground-plane x, z of a root track."""
    if isinstance(track, Motion):
        return track.positions()[:, body_root(track.skeleton)][:, [0, 2]]
    a = np.asarray(track, dtype=np.float64)
    if a.ndim == 2 and a.shape[1] == 2:
        return a
    if a.ndim == 2 and a.shape[1] == 3:
        return a[:, [0, 2]]
    if a.ndim == 3 and a.shape[2] == 3:
        return a[:, 0, [0, 2]]
    raise ValueError(f"a path must be a Motion or an array of shape (T, 2), (T, 3) or (T, J, 3); got {a.shape}")


def plot_root_paths(paths: Mapping[str, Track], out: str | Path, target: np.ndarray | None = None,
                    title: str = "Root path on the ground", force: bool = False) -> Path:
    """The root's path on the ground plane (x, z seen from above: x to the right, z down
    the page, as a right-handed y-up world looks from above) of each labelled motion, with
    start and end marked, dots every second, and the ``target`` polyline ((N, 2) x, z
    points) when given. Writes a PNG."""
    out = check_output(out, (".png",), force)
    if not paths:
        raise ValueError("give at least one motion to plot")
    fig = _new_figure(7.5, 6.5)
    ax = fig.add_subplot()
    if target is not None:
        tgt = np.asarray(target, dtype=np.float64)
        if tgt.ndim != 2 or tgt.shape[1] != 2 or len(tgt) < 2:
            raise ValueError(f"the target path must be (N, 2) x, z points with N >= 2, got shape {tgt.shape}")
        ax.plot(tgt[:, 0], tgt[:, 1], "--", color="black", lw=1.5, label="target path", zorder=2)
        ax.plot(tgt[:, 0], tgt[:, 1], "o", color="black", ms=3, zorder=2)
    for i, (label, track) in enumerate(paths.items()):
        xz = _ground_xz(track)
        color = f"C{i}"
        ax.plot(xz[:, 0], xz[:, 1], color=color, lw=2, label=label, zorder=3)
        if isinstance(track, Motion):
            step = max(1, int(round(track.fps)))
            ax.plot(xz[step::step, 0], xz[step::step, 1], "o", color=color, ms=3.5, zorder=3)
        ax.plot(*xz[0], "o", color=color, ms=9, markeredgecolor="black", zorder=4)
        ax.plot(*xz[-1], "s", color=color, ms=9, markeredgecolor="black", zorder=4)
    ax.plot([], [], "o", color="white", markeredgecolor="black", ms=8, label="start")
    ax.plot([], [], "s", color="white", markeredgecolor="black", ms=8, label="end")
    if any(isinstance(t, Motion) for t in paths.values()):
        ax.plot([], [], "o", color="gray", ms=3.5, label="every second")
    ax.set_aspect("equal", adjustable="datalim")
    # seen from above (y up, right-handed) with x to the right, z points down the page, so a turn to the
    # walker's left turns left here too, as in render's views; z up the page would be the view from below
    ax.invert_yaxis()
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m), growing down the page")
    ax.set_title(f"{title}\n(seen from above: y up, toward you)")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=9, framealpha=0.9)
    fig.tight_layout()
    return _save(fig, out)


def plot_path_follow(motion: Motion, out: str | Path, target: np.ndarray, new_from: int = 0, poses: int = 6,
                     title: str = "Path following", force: bool = False) -> Path:
    """What a path-following result is about, on two panels. Left, seen from above: the
    target path, the root's path, each foot's track with the frames it is planted on the
    ground marked, and the whole body at ``poses`` moments of the new frames (from
    ``new_from`` on). Right, over time: the hip height and the lowest foot's height above
    the floor, so that a walk that sinks, floats or falls shows where it does. Writes a PNG."""
    out = check_output(out, (".png",), force)
    tgt = np.asarray(target, dtype=np.float64)
    if tgt.ndim != 2 or tgt.shape[1] != 2 or len(tgt) < 2:
        raise ValueError(f"the target path must be (N, 2) x, z points with N >= 2, got shape {tgt.shape}")
    sf = stick_figure(motion)
    feet = [i for i in range(sf.points.shape[1]) if sf.contacts[:, i].any()] or [sf.root]
    fig = _new_figure(13.0, 6.0)
    fig.set_layout_engine("constrained")
    top, curve = fig.subplots(1, 2, width_ratios=(1.25, 1.0))
    top.plot(tgt[:, 0], tgt[:, 1], "--", color="black", lw=1.5, label="target path", zorder=2)
    xz = sf.points[:, sf.root][:, [0, 2]]
    top.plot(xz[:new_from + 1, 0], xz[:new_from + 1, 1], color="gray", lw=2, label="seed", zorder=3)
    top.plot(xz[new_from:, 0], xz[new_from:, 1], color="C0", lw=2, label="root (output)", zorder=3)
    for k, i in enumerate(feet):
        p = sf.points[new_from:, i][:, [0, 2]]
        top.plot(p[:, 0], p[:, 1], color="C1", lw=0.6, alpha=0.6, zorder=2,
                 label="foot tracks" if k == 0 else None)
        down = sf.contacts[new_from:, i]
        top.plot(p[down, 0], p[down, 1], "o", color=CONTACT_COLOR, ms=3, zorder=3,
                 label="foot on the ground" if k == 0 else None)
    colors = {1: LEFT_COLOR, -1: RIGHT_COLOR, 0: CENTRE_COLOR}
    n = motion.num_frames
    for t in np.unique(np.linspace(new_from, n - 1, max(1, poses)).round().astype(int)):
        for a, b in sf.bones:
            seg = sf.points[t, [a, b]][:, [0, 2]]
            top.plot(seg[:, 0], seg[:, 1], color=colors[int(sf.sides[b])], lw=1.4, zorder=4)
        top.annotate(f"{t / motion.fps:.1f} s", sf.points[t, sf.root][[0, 2]], fontsize=8, zorder=5,
                     xytext=(4, 4), textcoords="offset points")
    top.set_aspect("equal", adjustable="datalim")
    top.invert_yaxis()  # seen from above, y up: z grows down the page (see plot_root_paths)
    top.set_xlabel("x (m)")
    top.set_ylabel("z (m), growing down the page")
    top.set_title("seen from above: path, feet and poses")
    top.grid(True, alpha=0.3)
    top.legend(loc="best", fontsize=8, framealpha=0.9)
    time = np.arange(n) / motion.fps
    curve.plot(time, sf.points[:, sf.root, 1] - sf.ground, color="C0", label="hip height")
    curve.plot(time, sf.points[:, feet, 1].min(axis=1) - sf.ground, color="C1", label="lowest foot joint")
    curve.axvspan(0, new_from / motion.fps, color="gray", alpha=0.15, label="seed")
    curve.axhline(0.0, color="black", lw=0.8)
    curve.set_xlabel("time (s)")
    curve.set_ylabel("height above the floor (m)")
    curve.set_title("hips and feet over time")
    curve.grid(True, alpha=0.3)
    curve.legend(loc="best", fontsize=8)
    fig.suptitle(title)
    return _save(fig, out)


def _joint_track(track: Track, joint: str | int) -> tuple[np.ndarray, str]:
    """(T, 3) world positions of one joint, and its name for the title."""
    if isinstance(track, Motion):
        j = track.skeleton.index(joint) if isinstance(joint, str) else int(joint)
        if not 0 <= j < track.skeleton.num_joints:
            raise ValueError(f"joint index {j} is outside the skeleton's {track.skeleton.num_joints} joints")
        return track.positions()[:, j], track.skeleton.names[j]
    a = np.asarray(track, dtype=np.float64)
    if a.ndim == 2 and a.shape[1] == 3:
        return a, str(joint)
    if a.ndim == 3 and a.shape[2] == 3:
        if isinstance(joint, str):
            raise ValueError("with (T, J, 3) position arrays give the joint as an index, not a name")
        return a[:, joint], str(joint)
    raise ValueError(f"a trajectory must be a Motion or an array of shape (T, 3) or (T, J, 3); got {a.shape}")


def plot_joint_trajectories(tracks: Mapping[str, Track], joint: str | int, out: str | Path,
                            fps: float | None = None, title: str | None = None, first_frame: int = 0,
                            force: bool = False) -> Path:
    """One joint's world x, y and z over time for each labelled motion (for example
    noisy, denoised and clean), stacked in three panels. Arrays need ``fps``. Time counts
    from the file's start: the tracks begin at frame ``first_frame`` (a cut of the file).
    Writes a PNG."""
    out = check_output(out, (".png",), force)
    if not tracks:
        raise ValueError("give at least one motion to plot")
    fig = _new_figure(9, 7.5)
    axes = fig.subplots(3, 1, sharex=True)
    name = str(joint)
    for i, (label, track) in enumerate(tracks.items()):
        p, name = _joint_track(track, joint)
        rate = track.fps if isinstance(track, Motion) else fps
        if rate is None:
            raise ValueError(f"{label!r} is an array: pass fps to put time on the axis")
        t = (np.arange(len(p)) + first_frame) / rate
        style = dict(color=f"C{i}", lw=1.1 if i == 0 and len(tracks) > 2 else 1.6, label=label,
                     alpha=0.75 if i == 0 and len(tracks) > 2 else 1.0)
        for k, ax in enumerate(axes):
            ax.plot(t, p[:, k], **style)
    for ax, axis in zip(axes, "xyz"):
        ax.set_ylabel(f"{axis} (m)")
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("time (s)")
    axes[0].legend(loc="upper right", fontsize=9, framealpha=0.9, ncol=min(len(tracks), 4))
    fig.suptitle(title or f"Trajectory of joint {name} (world coordinates)")
    fig.tight_layout()
    return _save(fig, out)


#: Most stick figures a filmstrip row holds: beyond it they are too small to read, and a
#: picture of 400 took minutes to draw.
MAX_FILMSTRIP_FRAMES = 30


def _pick_times(figs: Sequence[StickFigure], frames: int | Sequence[int]) -> np.ndarray:
    """Times (s) of the filmstrip's columns: ``frames`` evenly spread over the shortest
    motion, or the given frame numbers of the longest motion (the first of several as long)."""
    frames = frames if isinstance(frames, int) else list(frames)
    count = frames if isinstance(frames, int) else len(frames)
    if count > MAX_FILMSTRIP_FRAMES:
        raise ValueError(f"a filmstrip draws at most {MAX_FILMSTRIP_FRAMES} figures per row, got {count}: "
                         "write an interactive page with 'motionopt view' to see every frame")
    if isinstance(frames, int):
        if frames < 1:
            raise ValueError(f"a filmstrip needs at least one frame, got {frames}")
        dur = min((f.num_frames - 1) / f.fps for f in figs)
        return np.linspace(0.0, dur, frames)
    idx = np.asarray(frames, dtype=int)
    if len(idx) == 0:
        raise ValueError("a filmstrip needs at least one frame")
    longest = max(figs, key=lambda f: (f.num_frames - 1) / f.fps)
    n = longest.num_frames
    if idx.min() < 0 or idx.max() >= n:
        raise ValueError(f"filmstrip frames must lie in 0..{n - 1}, got {idx.min()}..{idx.max()}")
    return idx / longest.fps


def plot_filmstrip(rows: Mapping[str, Motion], out: str | Path, frames: int | Sequence[int] = 6,
                   elevation: float = 0.0, first_frame: int = 0, title: str | None = None,
                   force: bool = False) -> Path:
    """Stick figures at selected moments side by side, one row per labelled motion (for
    example input and output), from one fixed camera, with the ground and planted feet
    highlighted. ``frames`` is a count spread over the shortest clip or frame numbers of the
    longest (a shorter clip shows its last frame after its end); ``first_frame`` is added
    to the frame numbers shown. Writes a PNG."""
    out = check_output(out, (".png",), force)
    if not rows:
        raise ValueError("give at least one motion to draw")
    figs = [stick_figure(m) for m in rows.values()]
    times = _pick_times(figs, frames)
    cam = Camera.beside(figs[0], elevation)
    idx = [[min(int(round(t * f.fps)), f.num_frames - 1) for t in times] for f in figs]
    # one scale for every panel: the widest pose and the tallest figure decide it
    half_w, top, bottom = 0.45, 0.0, np.inf
    for f, ii in zip(figs, idx):
        s = cam.project(f.points[ii])
        u_root = s[:, f.root, 0][:, None]
        half_w = max(half_w, float(np.abs(s[..., 0] - u_root).max()) + 0.15)
        top = max(top, float(s[..., 1].max()) + 2 * _HEAD_RADIUS + 0.05)
        near_floor = f.ground * np.cos(cam.elevation) + (cam.floor_depth(f.points[ii]).min() - 0.3) * np.sin(cam.elevation)
        bottom = min(bottom, float(s[..., 1].min()) - 0.05, float(near_floor) - 0.05, f.ground - 0.12)
    n_r, n_c = len(figs), len(times)
    panel_h = 2.6
    panel_w = panel_h * 2 * half_w / (top - bottom)
    fig = _new_figure(max(4.5, panel_w * n_c + 1.0), panel_h * n_r + 1.3)
    # the constrained layout keeps the title, the time labels, the frame labels and the legend apart
    # however many rows there are (tight_layout let the title run into the time labels from five rows on)
    fig.set_layout_engine("constrained")
    axes = fig.subplots(n_r, n_c, squeeze=False, sharey=True)
    for r, (label, f) in enumerate(zip(rows, figs)):
        for c, t in enumerate(idx[r]):
            ax = axes[r, c]
            u = float(cam.project(f.points[t, f.root])[0])
            _draw_ground(ax, cam, f.ground, (u - half_w, u + half_w),
                         (float(cam.floor_depth(f.points[t]).min()) - 0.3, float(cam.floor_depth(f.points[t]).max()) + 0.3),
                         du=u)
            art = _Figure2D(ax, f, cam, lw=2.0, shadow=cam.elevation > 0)
            art.update(t, du=u)
            ax.set_xlim(-half_w, half_w)
            ax.set_ylim(bottom, top)
            ax.set_aspect("equal")
            ax.set_xticks([])
            for side in ("top", "right", "bottom"):
                ax.spines[side].set_visible(False)
            if r == 0 or figs[r].fps != figs[0].fps:
                ax.set_title(f"{(t + first_frame) / f.fps:.2f} s", fontsize=10)
            ax.set_xlabel(f"frame {t + first_frame}", fontsize=8, color="gray")
            if c == 0:
                ax.set_ylabel(f"{label}\nheight (m)", fontsize=10)
            else:
                ax.spines["left"].set_visible(False)
                ax.tick_params(left=False)
    fig.legend(handles=_legend_handles(any(f.contacts.any() for f in figs)), loc="outside lower center",
               ncol=3, fontsize=9, frameon=False)
    fig.suptitle(title or "Stick figures over time (side view)" if elevation == 0 else
                 title or "Stick figures over time")
    return _save(fig, out)


def _glide(track: np.ndarray, rate: float) -> np.ndarray:
    """A camera coordinate that follows ``track`` (one value per frame at ``rate``),
    smoothed over a second so that the view glides."""
    k = max(1, int(rate))
    pad = np.pad(track, (k, k), mode="edge")
    return np.convolve(pad, np.ones(2 * k + 1) / (2 * k + 1), mode="valid")


def render_gif(motion: Motion, out: str | Path, fps: float | None = None, size: tuple[int, int] = (640, 480),
               elevation: float = 15.0, first_frame: int = 0, title: str | None = None,
               progress: bool = False, force: bool = False) -> Path:
    """An animated GIF of ``motion`` as a stick figure with its shadow on a floor grid and
    planted feet highlighted; the camera follows the body sideways.

    ``fps`` is the animation's frame rate (default the motion's, at most 25): the motion
    is resampled to it, so playback runs at real speed. GIF stores frame times in
    hundredths of a second, so rates like 20, 25 or 50 play exactly and 30 plays at 33.
    ``size`` is width, height in pixels; ``progress`` shows a progress bar on stderr.
    """
    out = check_output(out, (".gif",), force)
    rate = float(fps) if fps is not None else min(motion.fps, GIF_FPS)
    if not rate > 0:
        raise ValueError(f"the animation frame rate must be positive, got {fps}")
    width, height = size
    if width < 64 or height < 64:
        raise ValueError(f"a picture of {width}x{height} pixels is too small to show a figure; use at least 64x64")
    shown = motion.resample(rate)
    sf = stick_figure(shown)
    cam = Camera.beside(sf, elevation)
    s = cam.project(sf.points)
    e = cam.elevation
    depth = cam.floor_depth(sf.points)
    dmin, dmax = float(depth.min()) - 0.4, float(depth.max()) + 0.4
    # each frame's view: from the floor just in front of the figure to above its head; a camera that looks
    # down sees the figure higher as it walks away, so the view follows it up and down rather than
    # holding every depth of the clip at once (which shrank a figure walking a curve to a speck)
    low = np.minimum(sf.ground * np.cos(e) + (depth.min(axis=1) - 0.4) * np.sin(e), s[..., 1].min(axis=1)) - 0.05
    high = s[..., 1].max(axis=1) + 2 * _HEAD_RADIUS + 0.1
    if high.max() - low.min() <= (high - low).max() + 0.3:  # fits: keep the camera still
        half_h = (high.max() - low.min()) / 2
        middle = np.full(len(low), (high.max() + low.min()) / 2)
    else:
        half_h = (high - low).max() / 2 + 0.15
        middle = np.clip(_glide((high + low) / 2, rate), high - half_h, low + half_h)  # gliding, never cutting it
    half_w = half_h * width / height
    root_u = s[:, sf.root, 0]
    if root_u.max() - root_u.min() <= 2 * half_w - 1.2:  # fits: keep the camera still
        centre = np.full(len(root_u), (root_u.max() + root_u.min()) / 2)
    else:  # gliding, the root never nearer an edge than 0.6 m
        centre = np.clip(_glide(root_u, rate), root_u - half_w + 0.6, root_u + half_w - 0.6)
    fig = _new_figure(width / 100, height / 100, dpi=100)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_axis_off()
    ax.set_aspect("equal")
    # the floor reaches under the lowest view the camera takes, so that no frame shows its edge in front
    _draw_ground(ax, cam, sf.ground, (float(root_u.min()) - 2 * half_w, float(root_u.max()) + 2 * half_w),
                 (dmin - 2 * half_h / max(np.sin(e), 0.1), dmax))
    art = _Figure2D(ax, sf, cam, lw=max(1.5, height / 220), shadow=e > 0)
    label = ax.text(0.02, 0.97, "", transform=ax.transAxes, va="top", fontsize=max(7, height / 45),
                    family="monospace")
    if title:
        ax.text(0.98, 0.97, title, transform=ax.transAxes, va="top", ha="right", fontsize=max(7, height / 40))
    ax.legend(handles=_legend_handles(bool(sf.contacts.any())), loc="lower right", fontsize=max(6, height / 60),
              framealpha=0.8)
    writer = PillowWriter(fps=rate)
    with writer.saving(fig, str(out), dpi=100):
        for t in tqdm(range(sf.num_frames), desc="frames", unit="frame", disable=not progress, leave=False):
            art.update(t)
            ax.set_xlim(centre[t] - half_w, centre[t] + half_w)
            ax.set_ylim(middle[t] - half_h, middle[t] + half_h)
            src = int(round(t / rate * motion.fps)) + first_frame
            label.set_text(f"t = {src / motion.fps:5.2f} s\nframe {src}")
            writer.grab_frame()
    return out
