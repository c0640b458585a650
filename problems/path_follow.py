"""Path following (Wang et al. 2019, section 5.2): continue a seed motion along a ground path."""
from __future__ import annotations

import csv
import io
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
from scipy.ndimage import gaussian_filter1d

from motionopt.features import advance
from motionopt.metrics import FOOT_SKATING_MEANS, foot_skating
from motionopt.motion import Motion, unit_scale
from motionopt.objective import PathTerm, nearest_on_polyline_sq
from motionopt.smoothing import smoothstep
from motionopt.solver import SolverOptions
from priors.checkpoint import shown

from .common import (FLOOR_SIGMA, MAX_COORDINATE, MAX_HUMAN_SPEED, SKATING_SIGMA, SUPPORT_SIGMA, Prepared, TaskResult,
                     TermSigmas, judged, plant_feet, prepare, read_text, root_features, run, standard_terms, warned)
from .rollout import chosen_rollout, lift_limit

#: Most seconds of new motion one run makes (a longer path: several runs, each continuing the last).
MAX_NEW_SECONDS = 600.0
#: Seconds over which a seed that ends off the path joins it.
JOIN_SECONDS = 0.5
#: Distance (m) from the path within which a joining seed's targets count as on it: the
#: path term holds the root from there, the timed targets alone before.
JOINED = 0.01
#: Distance (m) from the path beyond which the result is said to leave it.
PATH_TOLERANCE = 0.1
#: Seconds (a Gaussian's sigma) over which the timed targets are smoothed: corners are
#: rounded and stops eased as people walk them, not taken dead square.
ROUNDING_SECONDS = 0.15
#: Median pace (m/s) of the timed targets from which the path asks for a walk, and so for
#: a walk's hip sway. The clips' own 3 s root paths: held-out Bandai walks and runs
#: 0.68-1.95 m/s, held-out CMU dance and martial arts 0.04-0.55; the sway taken from a
#: dancer's planted feet made those skate 0.79 times mocap's, against 0.22 clamped.
WALK_PACE = 0.5

#: Units a path is often written in by mistake for metres, tried in this order to explain a pace no one runs.
UNIT_MISTAKES = {"cm": "centimetres", "mm": "millimetres"}
#: Most points a PATH.csv may hold: more than 10 minutes at 8 m/s with a point every 5 cm.
MAX_PATH_POINTS = 100_000


def asks_for_walk(targets: np.ndarray, fps: float) -> bool:
    """Whether timed targets (K, 2), one per frame, move at a walk's pace (``WALK_PACE``)."""
    steps = np.linalg.norm(np.diff(targets, axis=0), axis=1) * fps
    return len(steps) > 0 and float(np.median(steps)) >= WALK_PACE


def rounded(points: np.ndarray, sigma: float) -> np.ndarray:
    """``points`` (K, 2) smoothed over ``sigma`` frames, each end held where it is: the
    points are extended past both ends by reflection through the end point, which keeps
    a straight stretch straight and the ends in place."""
    if len(points) < 3 or sigma <= 0:
        return points
    pad = min(int(4 * sigma) + 1, len(points) - 1)
    head = 2 * points[0] - points[pad:0:-1]
    tail = 2 * points[-1] - points[-2:-pad - 2:-1]
    smooth = gaussian_filter1d(np.concatenate((head, points, tail)), sigma, axis=0, mode="nearest")
    return smooth[pad:pad + len(points)]


def polyline_lengths(path: np.ndarray) -> np.ndarray:
    """Cumulative arc length at each point of a polyline (N,)."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])


def point_at(path: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Points (K, 2) at arc lengths ``s`` (clipped to the path)."""
    cum = polyline_lengths(path)
    s = np.clip(s, 0.0, cum[-1])
    return np.stack([np.interp(s, cum, path[:, 0]), np.interp(s, cum, path[:, 1])], axis=-1)


#: Path points this close (m) to the nearest one count as equally near (``arc_length_of_nearest``).
NEAR_TIE = 0.1


def arc_length_of_nearest(path: np.ndarray, point: np.ndarray) -> float:
    """Arc length along the path of the point nearest ``point`` (2,); of points nearly as
    near (within ``NEAR_TIE``), the earliest: a closed loop, or a path walked twice,
    passes the seed's end again later, and is walked from its start."""
    a, b = path[:-1], path[1:]
    ab = b - a
    t = np.clip(((point - a) * ab).sum(1) / np.maximum((ab * ab).sum(1), 1e-12), 0, 1)
    d = np.linalg.norm(a + t[:, None] * ab - point, axis=1)
    i = int(np.flatnonzero(d <= d.min() + NEAR_TIE)[0])
    return float(polyline_lengths(path)[i] + t[i] * np.linalg.norm(ab[i]))


@dataclass
class PathFollow:
    """Continue ``seed`` so that its root follows ``path`` (N, 2) of ground points (x, z)
    in metres, in the seed file's world coordinates.

    Timing: ``times`` (N,) seconds after the seed's end at each path point, or a constant
    ``speed`` (m/s; default the seed's recent speed, at least 1 m/s). ``seconds`` of new
    motion (default: until the path's end at that timing; at most ``MAX_NEW_SECONDS``).

    The timed targets are first smoothed over ``ROUNDING_SECONDS`` (``rounded``): corners
    are rounded and stops eased as people walk them. The solve starts from a rollout
    along them: each new frame gets the path's yaw change (facing along it as the seed
    faced its way of travel) and forward step, and sideways the step its planted feet
    give, high-passed (``rollout.SwayingPath``; with ``sway`` 0, the root channels are
    clamped to the path, ``root_channels``), and the prior rolls out the rest of each
    frame (at ``options.temperature_for(prior)``), each second the best of
    ``candidates`` (``rollout.chosen_rollout``). With ``refine`` (the default) the MAP
    solver then solves every new frame, root included, under the prior, the rounded
    path (``sigma_path`` metres beyond ``sway`` metres from it, within which the root
    sways freely; ``sigma_timing`` from the point its timing gives), planted feet
    (``ContactTerm``), feet that glide near the floor (``SkatingTerm``), the lowest foot
    on the floor where the prior's contact head expects a foot down (``SupportTerm``; a
    run's flight and a dancer's jump stay free) and no foot through it (``FloorTerm``).
    Held-out Bandai walks (bench/paths.py) showed why each is as it is: with the root
    clamped to the drawn path it swayed at 1.5-3 cm/s across it (``metrics.hip_sway``;
    the held-out walks 5-14), took a square's corners dead square (75-80 cm/s), and its
    feet slid under it (skating within 1.2 times mocap's in 47 of 48 segments; with the
    sway and rounding 48, and the root 0.7-2.8 cm from the drawn path per 5 s segment
    against 0.1-2.3). A free band of 2.5 cm let the solve drift 3-4 cm off a square.
    Without the skating term the solved feet skimmed the floor at walking speed (skating
    1.3-2.3 times mocap's per 5 s); with it but without the support term the solve lifted
    the whole body until the lowest foot floated 6-12 cm above the floor (median per
    second over a 10 s square; the rollout it started from: 2-5 cm) and left the leg IK
    to put the feet back: the energy at the result was below that of the same motion
    lowered to the floor (-712 against 12,593 nats, 10,000 of them skating), an
    objective that prefers to float, not a search failure. With the support term alone
    the lowest foot went more than 3 cm through the floor in up to 8% of frames, hence
    the floor term. At ``sigma_path`` 2 cm the root drifted 5-10 cm off a square, and at
    1 cm 3-4 cm off a straight line, although the same poses with the root on the path
    scored lower (``solver.energies_at``): a search failure in 30 L-BFGS iterations per
    window, which the steeper 5 mm term pulls back. Windows of 56 frames overlapping by
    12 (the solver's default: 34 by 17) run 59-64 frames per second on one thread.
    Without ``refine`` the rollout, its feet planted, is the result. The sway is a walk's:
    timed targets slower than ``WALK_PACE`` (a dancer moving about) are followed as with
    ``sway`` 0 (``asks_for_walk``).

    A pace faster than a person moves (``MAX_HUMAN_SPEED``, along the path or joining it
    from the seed's end) is refused before any synthesis (``check_pace``): such a path is
    most often written in another unit than metres. A result that leaves the path by more
    than ``PATH_TOLERANCE`` still gives the best compromise, with ``TaskResult.warnings``
    saying so. ``path_name`` names the path in messages (its file, on the command line).
    """

    seed: Motion
    path: np.ndarray
    prior: object
    times: np.ndarray | None = None
    speed: float | None = None
    seconds: float | None = None
    sigma_path: float = 0.005
    sigma_timing: float = 0.3
    sway: float = 0.01
    sigmas: TermSigmas = field(default_factory=lambda: TermSigmas(skating=SKATING_SIGMA, support=SUPPORT_SIGMA,
                                                                  support_where="expected", floor=FLOOR_SIGMA))
    options: SolverOptions = field(default_factory=lambda: SolverOptions(window=56, overlap=12))
    refine: bool = True
    candidates: int = 8
    path_name: str = "the path"

    def __post_init__(self) -> None:
        self.path = np.asarray(self.path, dtype=np.float64)
        if self.path.ndim != 2 or self.path.shape[1] != 2:
            raise ValueError(f"the path must be a list of (x, z) points; got shape {self.path.shape}")
        if len(self.path) < 2:
            raise ValueError(f"the path needs at least 2 points, got {len(self.path)}")
        if not np.isfinite(self.path).all():
            raise ValueError("the path holds NaN or infinite coordinates")
        if polyline_lengths(self.path)[-1] < 1e-6:
            raise ValueError("the path has zero length: its points all coincide")
        if self.times is not None:
            self.times = np.asarray(self.times, dtype=np.float64)
            if len(self.times) != len(self.path) or np.any(np.diff(self.times) <= 0):
                raise ValueError("path times must be one per point and strictly increasing")
        if self.speed is not None and not self.speed > 0:
            raise ValueError(f"speed must be positive, got {self.speed}")
        if self.seconds is not None and not self.seconds > 0:
            raise ValueError(f"seconds must be positive, got {self.seconds}")
        wanted = self.seconds or (self.times[-1] if self.times is not None else None)
        if wanted is not None:
            self._check_duration(wanted)

    @staticmethod
    def _check_duration(seconds: float) -> None:
        if seconds > MAX_NEW_SECONDS:
            raise ValueError(f"{seconds:g} s of new motion is more than the {MAX_NEW_SECONDS:g} s one run makes; "
                             "follow a long path in several runs, each continuing the last")

    def targets(self, prep: Prepared, fps: float) -> tuple[np.ndarray, int, float]:
        """Per new frame target points (K, 2), the number of new frames, and the speed used."""
        end = prep.model.root[-1, [0, 2]]
        if self.times is not None:
            n_new = int(round((self.seconds or self.times[-1]) * fps))
            t = np.arange(1, n_new + 1) / fps
            cum = polyline_lengths(self.path)
            s = np.interp(t, self.times, cum)
            return point_at(self.path, s), n_new, float(cum[-1] / max(self.times[-1] - self.times[0], 1e-6))
        speed = self.speed
        if speed is None:
            recent = prep.model.root[-int(fps):, [0, 2]]
            seed_speed = np.linalg.norm(np.diff(recent, axis=0), axis=1).sum() / max(len(recent) - 1, 1) * fps
            speed = max(float(seed_speed), 1.0)
        s0 = arc_length_of_nearest(self.path, end)
        remaining = polyline_lengths(self.path)[-1] - s0
        seconds = self.seconds or max(remaining / speed, 1.0 / fps)
        self._check_duration(seconds)
        n_new = max(1, int(round(seconds * fps)))
        s = s0 + speed * np.arange(1, n_new + 1) / fps
        return point_at(self.path, s), n_new, speed

    def root_channels(self, prep: Prepared, tgt: np.ndarray, fps: float) -> np.ndarray:
        """Unnormalised root displacement and yaw-change features (K, 3) of the new frames
        that put the root on ``tgt`` (K, 2), facing along the path as the seed faced its
        direction of travel (forwards, sideways or backwards: the seed's last half second
        says which)."""
        spec = self.prior.spec
        s = spec.slices()
        raw = prep.raw.double().numpy()
        yaw_end = prep.start.yaw + raw[:, s["yaw_delta"]].sum()
        recent = raw[-max(int(fps / 2), 2):, s["root_delta"]].sum(axis=0)
        travel = float(np.arctan2(recent[0], recent[1])) if np.linalg.norm(recent) * 2 > 0.3 else 0.0
        pts = np.concatenate((prep.model.root[-1:, [0, 2]], tgt))
        # heading from the path's direction over a short look-ahead, held where it is slow
        k = max(int(fps / 10), 1)
        ahead = pts[np.minimum(np.arange(len(pts)) + k, len(pts) - 1)] - pts[np.maximum(np.arange(len(pts)) - k, 0)]
        fast = np.linalg.norm(ahead, axis=1) / (2 * k / fps) > 0.2
        yaw = np.empty(len(pts))
        prev = yaw_end
        for i in range(len(pts)):
            if fast[i]:
                want = np.arctan2(ahead[i, 0], ahead[i, 1]) - travel
                prev = prev + np.arctan2(np.sin(want - prev), np.cos(want - prev))
            yaw[i] = prev
        yaw = gaussian_filter1d(yaw, fps / 15, mode="nearest")
        ramp = smoothstep(np.arange(len(pts)) / max(fps / 3, 1))
        yaw = yaw_end + ramp * (yaw - yaw_end)
        return root_features(pts, yaw)

    def decode(self, x: torch.Tensor, prep: Prepared) -> Motion:
        return prep.codec.motion(x.double(), prep.start, like=prep.original)

    def solve(self) -> TaskResult:
        prior = self.prior
        prep = prepare(self.seed, prior)
        fps = prior.spec.fps
        t0 = time.perf_counter()
        tgt, n_new, speed = self.targets(prep, fps)
        # a seed that ends off the path joins it over the first JOIN_SECONDS
        off = prep.model.root[-1, [0, 2]] - tgt[0] + (tgt[1] - tgt[0] if n_new > 1 else 0)
        fade = smoothstep(1 - np.arange(1, n_new + 1) / max(fps * JOIN_SECONDS, 1))[:, None]
        tgt = tgt + off * fade
        walked = np.concatenate((prep.model.root[-1:, [0, 2]], tgt))
        walk = asks_for_walk(walked, fps)
        if walk:
            walked = rounded(walked, ROUNDING_SECONDS * fps)
            tgt = walked[1:]
        sway = self.sway if walk else 0.0
        self.check_pace(speed, prep.model.root[-1, [0, 2]], float(np.linalg.norm(off)))
        n_seed = len(prep.x)
        n = n_seed + n_new
        cidx = prior.spec.contact_indices()
        gen = torch.Generator().manual_seed(self.options.seed)
        seed_feet = prep.model.positions()[:, cidx]
        new = chosen_rollout(prior, prep.x, advance(prep.start, prep.raw, prior.spec), seed_feet[-1],
                             prep.model.skeleton, prep.planted_height, n_new, self.candidates,
                             self.options.temperature_for(prior), gen,
                             torch.from_numpy(self.root_channels(prep, tgt, fps)),
                             lift_limit(seed_feet, prep.planted_height), sway=sway > 0)
        x = torch.cat((prep.x, new))
        model = plant_feet(self.decode(x, prep), prior, x, prep.planted_height, slice(n_seed, n))
        result = None
        if self.refine:
            free = np.zeros(n, bool)
            free[n_seed:] = True
            # while a seed that ends off the path joins it, its timed targets lead the way
            joined = free.copy()
            joined[n_seed:] = fade[:, 0] * np.linalg.norm(off) < JOINED
            full_targets = np.zeros((n, 2))
            full_targets[n_seed:] = tgt
            terms = [PathTerm(walked, self.sigma_path, mask=joined, name="path", width=sway),
                     PathTerm(self.path, self.sigma_timing, targets=full_targets, mask=free, name="path_timing")]
            terms += standard_terms(prep, prior, self.sigmas, x)
            result, _ = run(prior, prep, x, free, terms, replace(self.options, pso=None))
            x = result.x
            model = plant_feet(self.decode(x, prep), prior, x, prep.planted_height, slice(n_seed, n))
        seconds = time.perf_counter() - t0
        motion = prep.to_file(model)
        new_root = model.root[n_seed:, [0, 2]]
        dist = np.sqrt(nearest_on_polyline_sq(torch.from_numpy(new_root), torch.from_numpy(self.path)).numpy())
        final = prep.codec.features(model, prep.start.ground)
        with torch.no_grad():
            nll = prior.nll(final[n_seed:], final[max(0, n_seed - prior.receptive_field):n_seed])
        metrics = {
            "path_distance_cm_mean": float(dist.mean() * 100),
            "path_distance_cm_max": float(dist.max() * 100),
            "end_distance_to_path_end_m": float(np.linalg.norm(new_root[-1] - self.path[-1])),
            "foot_skating_cm_per_s": float(foot_skating(torch.from_numpy(model.positions()[n_seed:]), fps, cidx) * 100),
            "prior_nll_per_frame": float(nll.mean()),
            "new_frames": n_new,
            "speed_m_per_s": speed,
            "frames_per_second": n_new / max(seconds, 1e-9),
        }
        warnings = warned(distance_warnings(dist))
        settings = {"sigma_path": self.sigma_path, "sway": sway, "speed": speed, "new_seconds": n_new / fps,
                    "refine": self.refine,
                    "temperature": self.options.temperature_for(prior)}
        return judged(TaskResult(motion, model, result, metrics, settings, warnings), prior, prep.start.ground)

    def summary(self, result: TaskResult) -> list[str]:
        """The metrics of ``result`` (of ``solve``) in sentences, for the command line."""
        m = result.metrics
        return [f"root distance to the path: {m['path_distance_cm_mean']:.1f} cm on average, "
                f"{m['path_distance_cm_max']:.1f} cm at most",
                f"the motion ends {m['end_distance_to_path_end_m']:.2f} m from the path's end",
                f"{m['new_frames']} new frames at the prior's rate, at {m['speed_m_per_s']:.2f} m/s",
                f"foot skating: {m['foot_skating_cm_per_s']:.1f} cm/s ({FOOT_SKATING_MEANS})",
                f"naturalness: {m['prior_nll_per_frame']:.1f} nats per frame under the prior (lower is more natural)",
                f"speed: {m['frames_per_second']:.0f} frames per second"]

    def check_pace(self, speed: float, seed_end: np.ndarray, join: float) -> None:
        """Refuse, before any synthesis, a timing that asks the root to go faster than a
        person: the path's speed (``speed``, requested or the seed's; with times, their
        fastest stretch), and the join from the seed's end (``seed_end``, x and z), ``join``
        metres away from the path, over ``JOIN_SECONDS``. The error says which, and the
        unit the path's numbers are likely in when that pace is a unit mistake."""
        beyond = f"faster than a person runs (about {MAX_HUMAN_SPEED:g} m/s at most)"
        problems = []
        if self.times is not None:
            stretch = np.linalg.norm(np.diff(self.path, axis=0), axis=1)
            dt = np.diff(self.times)
            k = int(np.argmax(stretch / dt))
            if stretch[k] / dt[k] > MAX_HUMAN_SPEED:
                problems.append((f"its times ask for {stretch[k] / dt[k]:.1f} m/s from t = {self.times[k]:g} s to "
                                 f"{self.times[k + 1]:g} s ({stretch[k]:.2f} m in {dt[k]:g} s)", stretch[k] / dt[k]))
        elif speed > MAX_HUMAN_SPEED:
            what = "the requested speed" if self.speed is not None else "the seed's speed"
            problems.append((f"{what} is {speed:.1f} m/s", None))
        if join / JOIN_SECONDS > MAX_HUMAN_SPEED:
            problems.append((f"the seed ends at x, z = {seed_end[0]:.2f}, {seed_end[1]:.2f}, {join:.2f} m from where "
                             f"the path takes it, and joining it in {JOIN_SECONDS:g} s asks for "
                             f"{join / JOIN_SECONDS:.1f} m/s", join / JOIN_SECONDS))
        if not problems:
            return
        paces = [pace for _, pace in problems if pace is not None]
        unit = next((u for u in UNIT_MISTAKES if paces and max(paces) * unit_scale(u) <= MAX_HUMAN_SPEED), None)
        hint = (f"; {self.path_name} is read in metres, in the seed file's world coordinates: if it is in "
                f"{UNIT_MISTAKES[unit]}, pass --path-unit {unit}" if unit else "")
        raise ValueError(f"path-follow: {self.path_name} is refused before synthesis: "
                         f"{'; '.join(text for text, _ in problems)}, {beyond}{hint}")


def distance_warnings(dist: np.ndarray) -> list[str]:
    """Where the new root's distances to the path ``dist`` (K,) exceed ``PATH_TOLERANCE``:
    on average, and at the end."""
    out = []
    if dist.mean() > PATH_TOLERANCE:
        out.append(f"path-follow: the root keeps {dist.mean():.2f} m from the path on average ({dist.max():.2f} m "
                   f"at most), beyond the tolerance of {PATH_TOLERANCE:g} m")
    if dist[-1] > PATH_TOLERANCE:
        out.append(f"path-follow: the motion ends {dist[-1]:.2f} m from the path, beyond the tolerance of "
                   f"{PATH_TOLERANCE:g} m")
    return out


def read_path_csv(path: str | Path, unit: str = "m") -> tuple[np.ndarray, np.ndarray | None]:
    """Read PATH.csv: a header line naming the columns ``x`` and ``z`` (world ground plane,
    in ``unit``: metres unless told) and optionally ``t`` (seconds after the seed's end),
    then one point per line. Returns the points (N, 2) in metres and the times (N,) or None.

    The file is data, never evaluated: UTF-8 (a BOM is fine) of at most ``MAX_FILE_BYTES``,
    at most ``MAX_PATH_POINTS`` points, every value a finite number, coordinates within
    ``MAX_COORDINATE`` metres, ``t`` rising and within ``MAX_NEW_SECONDS``. Errors are
    ``ValueError`` naming the file and line."""
    path = Path(path)
    rows = _csv_rows(path)
    if not rows:
        raise ValueError(f"{path}: the file is empty; expected a header line 'x,z' and at least 2 points")
    line, header = rows[0]
    names = [c.strip().lower() for c in header]
    unknown = [n for n in names if n not in ("x", "z", "t")]
    if unknown or "x" not in names or "z" not in names or len(set(names)) != len(names):
        raise ValueError(f"{path}:{line}: the header must name the columns x and z, and optionally t "
                         f"(like 'x,z' or 't,x,z'); got {shown(','.join(header))}")
    values = np.zeros((len(rows) - 1, len(names)))
    for k, (line, row) in enumerate(rows[1:]):
        if len(row) != len(names):
            raise ValueError(f"{path}:{line}: expected {len(names)} values ({','.join(names)}), got {len(row)}")
        values[k] = [_cell(text, name, f"{path}:{line}") for name, text in zip(names, row)]
    if len(values) < 2:
        raise ValueError(f"{path}: the path needs at least 2 points, found {len(values)}")
    points = values[:, [names.index("x"), names.index("z")]] * unit_scale(unit)
    if "t" not in names:
        return points, None
    times = values[:, names.index("t")]
    for k in range(1, len(times)):
        if times[k] <= times[k - 1]:
            raise ValueError(f"{path}:{rows[k + 1][0]}: t {times[k]:g} does not come after the previous point's "
                             f"{times[k - 1]:g}")
    return points, times


def _csv_rows(path: Path) -> list[tuple[int, list[str]]]:
    """(line number, cells) of each non-blank CSV row, header included, stopping past the point cap."""
    reader = csv.reader(io.StringIO(read_text(path, "a CSV path"), newline=""))
    rows = []
    try:
        for row in reader:
            if any(c.strip() for c in row):
                rows.append((reader.line_num, row))
            if len(rows) > MAX_PATH_POINTS + 1:
                raise ValueError(f"{path}:{reader.line_num}: more than {MAX_PATH_POINTS} points; a path needs "
                                 "far fewer (a point every few centimetres is plenty)")
    except csv.Error as e:
        raise ValueError(f"{path}:{reader.line_num}: not CSV text ({e})") from None
    return rows


def _cell(text: str, name: str, where: str) -> float:
    """One CSV value: a finite number, a coordinate within ``MAX_COORDINATE`` m or a time
    within ``MAX_NEW_SECONDS`` s and not negative."""
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{where}: {name} value {shown(text.strip())} is not a number") from None
    if not np.isfinite(value):
        raise ValueError(f"{where}: {name} value {shown(text.strip())} is not a finite number")
    if name == "t" and value < 0:
        raise ValueError(f"{where}: t {value:g} is negative; t counts seconds after the seed's end")
    if name == "t" and value > MAX_NEW_SECONDS:
        raise ValueError(f"{where}: t {value:g} s is later than the {MAX_NEW_SECONDS:g} s of new motion one run "
                         "makes")
    if name != "t" and abs(value) > MAX_COORDINATE:
        raise ValueError(f"{where}: {name} {value:g} is farther than {MAX_COORDINATE:g} m; the path is in metres, "
                         "in the seed file's world coordinates")
    return value
