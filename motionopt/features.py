"""The versioned per-frame feature representation that priors model, with an exact decoder.

Per frame t (version 1):
- root displacement on the ground plane from frame t-1 to t, in frame t-1's heading frame (2)
- yaw change from frame t-1 to t, radians (1)
- root height above the estimated ground, metres (1)
- root rotation with its heading removed (pitch/roll), 6D (6)
- local rotations of the other modelled joints, 6D (6 per joint)
- foot contact labels, 0 or 1 (one per contact joint)

Frame 0 has zero displacement and yaw change; decoding integrates the root from a
``RootStart`` (frame 0's heading and ground position), so encode then decode is exact.
Heading is the twist of the root rotation about the vertical axis.
"""
from __future__ import annotations

import fnmatch
import re
from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import Tensor

from . import rotations as R
from .kinematics import fk, fk_matrices
from .motion import Motion
from .skeleton import Skeleton

FEATURE_VERSION = 1

#: Joints a prior leaves out by default: fingers, eyes, jaw, toe tips of hand-rigged skeletons.
DEFAULT_DROP = ("*Thumb*", "*Index*", "*Mid[0-9]*", "*Middle*", "*Ring*", "*Pinky*", "*Eye*", "*eye*",
                "*Jaw*", "*_end", "*End*")
_FOOT = re.compile(r"(foot|toe|ankle)", re.IGNORECASE)


@dataclass(frozen=True)
class FeatureSpec:
    """What a prior models: which joints, which contact joints, at which frame rate."""

    joints: tuple[str, ...]
    contact_joints: tuple[str, ...]
    fps: float = 30.0
    contact_height: float = 0.05
    contact_speed: float = 0.5
    version: int = FEATURE_VERSION

    @property
    def num_contacts(self) -> int:
        return len(self.contact_joints)

    @property
    def dim(self) -> int:
        return 10 + 6 * (len(self.joints) - 1) + self.num_contacts

    @property
    def pose_dim(self) -> int:
        """Dimensions modelled as continuous (everything but the contact labels)."""
        return self.dim - self.num_contacts

    def contact_indices(self) -> list[int]:
        """Positions of the contact joints in ``joints``, in the order of the contact labels."""
        return [self.joints.index(n) for n in self.contact_joints]

    def slices(self) -> dict[str, slice]:
        j6 = 6 * (len(self.joints) - 1)
        return {
            "root_delta": slice(0, 2),
            "yaw_delta": slice(2, 3),
            "root_height": slice(3, 4),
            "root_tilt": slice(4, 10),
            "joint_rotations": slice(10, 10 + j6),
            "contacts": slice(10 + j6, self.dim),
        }

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "FeatureSpec":
        d = dict(d)
        d["joints"] = tuple(d["joints"])
        d["contact_joints"] = tuple(d["contact_joints"])
        return cls(**d)


def missing_joints(spec: FeatureSpec, skeleton: Skeleton) -> list[str]:
    """The joints ``spec`` models that ``skeleton`` lacks, in the spec's order."""
    return [n for n in spec.joints if n not in skeleton.names]


def default_spec(skeleton: Skeleton, fps: float = 30.0, drop: tuple[str, ...] = DEFAULT_DROP) -> FeatureSpec:
    """A spec for any humanoid skeleton: all joints but fingers and eyes; contacts on the
    feet and toes found by name. A static top joint (e.g. Bandai's ``joint_Root``) is
    skipped so that the hips are the root."""
    names = list(skeleton.names)
    keep = [n for n in names if not any(fnmatch.fnmatchcase(n, p) for p in drop)]
    if len(skeleton.children(0)) == 1 and "root" in names[0].lower() and names[0] != keep[-1]:
        keep = keep[1:]
    contacts = tuple(n for n in keep if _FOOT.search(n))
    if not contacts:
        raise ValueError("no foot or toe joints found by name; pass contact_joints explicitly")
    return FeatureSpec(tuple(keep), contacts, fps=fps)


@dataclass(frozen=True)
class RootStart:
    """Where decoding starts: frame 0's heading (yaw, radians) and ground position (x, z),
    and the ground height that root heights are measured from."""

    yaw: float = 0.0
    x: float = 0.0
    z: float = 0.0
    ground: float = 0.0


def to_model_motion(motion: Motion, spec: FeatureSpec) -> Motion:
    """The motion as the prior sees it: the spec's joints only, at the spec's frame rate.

    Static top joints are folded into the root; other unmodelled joints are removed while
    keeping world positions of the rest.
    """
    m = motion
    while m.skeleton.names[0] != spec.joints[0]:
        rerooted = m.reroot()
        if rerooted is m:
            raise ValueError(
                f"the prior's root joint {spec.joints[0]!r} is not the file's root {m.skeleton.names[0]!r} "
                "and the joints above it move: this skeleton does not match the prior")
        m = rerooted
    missing = missing_joints(spec, m.skeleton)
    if missing:
        raise ValueError(f"skeleton lacks joints the prior models: {', '.join(missing)}")
    m = m.select_joints(list(spec.joints)).bake_translations(tolerance=1e-4)
    if m.skeleton.names != spec.joints:
        raise ValueError("joint order differs from the prior's definition")
    return m.resample(spec.fps)


def estimate_ground(positions: np.ndarray, contact_idx: list[int]) -> float:
    """Ground height: a low percentile of the lowest contact joint per frame."""
    return float(np.percentile(positions[:, contact_idx, 1].min(axis=1), 5.0))


def contact_labels(positions: np.ndarray | Tensor, contact_idx: list[int], fps: float, ground: float,
                   height: float, speed: float) -> np.ndarray:
    """1 where a contact joint is within ``height`` metres of its resting height above
    the ground and moves slower than ``speed`` m/s, else 0. Shape (T, C)."""
    p = np.asarray(positions)[:, contact_idx]
    vel = np.zeros(p.shape[:2])
    vel[1:] = np.linalg.norm(np.diff(p, axis=0), axis=-1) * fps
    vel[0] = vel[1] if len(vel) > 1 else 0.0
    rest = np.percentile(p[..., 1], 5.0, axis=0) - ground  # each joint's height when planted
    h = p[..., 1] - ground - rest
    return ((h < height) & (vel < speed)).astype(np.float64)


def heading_angle(q: Tensor) -> Tensor:
    """Twist angle of rotations about the vertical y axis."""
    return 2 * torch.atan2(q[..., 2], q[..., 0])


def wrap_angle(a: Tensor) -> Tensor:
    return torch.atan2(torch.sin(a), torch.cos(a))


def encode(motion: Motion, spec: FeatureSpec, ground: float | None = None) -> tuple[Tensor, RootStart]:
    """Features (T, D) of a model motion (see ``to_model_motion``), and where decoding starts."""
    if motion.skeleton.names != spec.joints:
        raise ValueError("encode expects a motion on the prior's joints; call to_model_motion first")
    q = torch.from_numpy(motion.rotations)
    root = torch.from_numpy(motion.root)
    cidx = spec.contact_indices()
    pos = motion.positions()
    if ground is None:
        ground = estimate_ground(pos, cidx)
    yaw = heading_angle(q[:, 0])
    heading = R.yaw_quat(yaw)
    tilt = R.quat_multiply(R.quat_conjugate(heading), q[:, 0])
    delta_world = torch.zeros_like(root)
    delta_world[1:] = root[1:] - root[:-1]
    prev_heading = torch.cat((heading[:1], heading[:-1]))
    delta_local = R.quat_apply(R.quat_conjugate(prev_heading), delta_world)
    yaw_delta = torch.zeros_like(yaw)
    yaw_delta[1:] = wrap_angle(yaw[1:] - yaw[:-1])
    contacts = contact_labels(pos, cidx, motion.fps, ground, spec.contact_height, spec.contact_speed)
    x = torch.cat(
        (
            delta_local[:, [0, 2]],
            yaw_delta[:, None],
            root[:, 1:2] - ground,
            R.quat_to_6d(tilt),
            R.quat_to_6d(q[:, 1:]).reshape(len(q), -1),
            torch.from_numpy(contacts),
        ),
        dim=-1,
    )
    start = RootStart(float(yaw[0]), float(root[0, 0]), float(root[0, 2]), ground)
    return x, start


def decode(x: Tensor, spec: FeatureSpec, start: RootStart = RootStart()) -> tuple[Tensor, Tensor]:
    """Local rotations (..., T, J, 4) and root positions (..., T, 3) from features (..., T, D)."""
    mats, root = decode_matrices(x, spec, start)
    return R.matrix_to_quat(mats), root


def decode_matrices(x: Tensor, spec: FeatureSpec, start: RootStart = RootStart()) -> tuple[Tensor, Tensor]:
    """Local rotation matrices (..., T, J, 3, 3) and root positions (..., T, 3) from features.

    Differentiable; the root is integrated from ``start`` (the state of the frame before
    ``x``; for a whole clip, frame 0 itself, whose deltas are zero) with a cumulative sum,
    so the result of frame t depends on the features of frames 0..t only.
    """
    s = spec.slices()
    yaw = start.yaw + torch.cumsum(x[..., s["yaw_delta"]].squeeze(-1), dim=-1)
    prev_yaw = torch.cat((torch.full_like(yaw[..., :1], start.yaw), yaw[..., :-1]), dim=-1)
    d = x[..., s["root_delta"]]
    c, si = torch.cos(prev_yaw), torch.sin(prev_yaw)
    # rotate (dx, 0, dz) by yaw about y: x' = c dx + s dz, z' = -s dx + c dz
    dxw = c * d[..., 0] + si * d[..., 1]
    dzw = -si * d[..., 0] + c * d[..., 1]
    root = torch.stack(
        (start.x + torch.cumsum(dxw, -1), x[..., s["root_height"]].squeeze(-1) + start.ground,
         start.z + torch.cumsum(dzw, -1)),
        dim=-1,
    )
    tilt = R.sixd_to_matrix(x[..., s["root_tilt"]])
    root_rot = R.quat_to_matrix(R.yaw_quat(yaw)) @ tilt
    n_j = len(spec.joints) - 1
    joints = R.sixd_to_matrix(x[..., s["joint_rotations"]].reshape(*x.shape[:-1], n_j, 6))
    return torch.cat((root_rot[..., None, :, :], joints), dim=-3), root


def decode_positions(x: Tensor, spec: FeatureSpec, skeleton: Skeleton, start: RootStart = RootStart()) -> Tensor:
    """World joint positions (..., T, J, 3) of features, on the prior's skeleton."""
    rot, root = decode_matrices(x, spec, start)
    return fk_matrices(skeleton.parents, rot, root, torch.as_tensor(skeleton.offsets, dtype=x.dtype))


def decode_motion(x: Tensor, spec: FeatureSpec, skeleton: Skeleton, start: RootStart = RootStart(),
                  like: Motion | None = None) -> Motion:
    """A model Motion from features (no gradient), keeping ``like``'s unit and channels."""
    with torch.no_grad():
        rot, root = decode(x.double(), spec, start)
    return Motion(skeleton, rot.numpy(), root.numpy(), spec.fps,
                  source_unit=like.source_unit if like is not None else "m")


def contact_heights(x: Tensor, spec: FeatureSpec, skeleton: Skeleton) -> Tensor:
    """Height above the ground (..., T, C) of each contact joint in unnormalised frames ``x``."""
    cidx = spec.contact_indices()
    return decode_positions(x, spec, skeleton)[..., cidx, 1]


#: Height (m) over which ``planted_root_step`` weighs planted joints down: the foot on the
#: ground carries the body. With an equal mean over every joint within the contact height
#: of its rest, a swing toe skimming the floor dragged the stance foot along: 60 s
#: rollouts of the Bandai prior from 8 held-out starts skated within 1.5 times the
#: held-out data's in 50 of 96 5 s segments, and in 81 with this weighting (94 with
#: ``floored_root_height`` too; bench/prior.py, "a minute of motion").
PLANT_SHARPNESS = 0.01


def planted_root_step(prev: Tensor, new: Tensor, spec: FeatureSpec, skeleton: Skeleton,
                      rest: Tensor | None = None, sharpness: float = PLANT_SHARPNESS) -> Tensor:
    """``new`` (unnormalised frames (B, D) following ``prev`` (B, D)) with its root step on
    the ground plane replaced, where contact joints are planted in both frames, by the
    step that keeps them still: the root moves under the planted foot instead of the foot
    sliding under the body. Frames with no planted joint are returned as they were.

    A joint is planted where the contact channels of both frames say so or, given its
    resting height above the ground ``rest`` (B, C), where it is within the spec's
    contact height of it in both frames. The step is found in the previous frame's
    heading frame, where a joint at body position p then at p' (turned by the yaw
    change) stays still when the root moves by p - p'. With several planted joints the
    steps are weighted to the lowest by exp(-(height - the lowest's) / ``sharpness``),
    a joint's height above its rest (0 without ``rest``) the higher of its two frames';
    ``sharpness`` infinite: their mean."""
    if not sharpness > 0:
        raise ValueError(f"sharpness must be positive (m, or inf for the mean), got {sharpness}")
    s = spec.slices()
    both = torch.stack((prev, new), dim=-2).clone()
    both[..., s["root_delta"]] = 0.0
    both[..., s["yaw_delta"]] = 0.0
    cidx = spec.contact_indices()
    body = decode_positions(both, spec, skeleton)[..., cidx, :]  # (B, 2, C, 3), each in its own heading frame
    turn = R.yaw_quat(new[..., s["yaw_delta"]].expand(*new.shape[:-1], len(cidx)))
    need = (body[..., 0, :, :] - R.quat_apply(turn, body[..., 1, :, :]))[..., [0, 2]]
    planted = (prev[..., s["contacts"]] > 0.5) & (new[..., s["contacts"]] > 0.5)
    if rest is not None:
        low = body[..., 1] - rest[..., None, :] < spec.contact_height  # (B, 2, C)
        planted = planted | (low[..., 0, :] & low[..., 1, :])
    lift = (body[..., 1] - (0.0 if rest is None else rest[..., None, :])).amax(-2)  # (B, C)
    lift = torch.where(planted, lift, torch.inf)
    weight = torch.where(planted, torch.exp(-(lift - lift.amin(-1, keepdim=True)) / sharpness), 0.0)
    step = (need * weight[..., None]).sum(-2) / weight.sum(-1, keepdim=True).clamp_min(1e-12)
    out = new.clone()
    out[..., s["root_delta"]] = torch.where(planted.any(-1, keepdim=True), step, new[..., s["root_delta"]])
    return out


def floored_root_height(x: Tensor, spec: FeatureSpec, skeleton: Skeleton, rest: Tensor | None = None,
                        settle: bool = False) -> Tensor:
    """Unnormalised frames ``x (..., D)`` with the root raised where a contact joint lies
    below its resting height above the ground ``rest (..., C)`` (0 without it), by as much
    as the lowest lies below: the legs a prior draws stand on the floor, not through it.
    With ``settle``, a frame whose contact channels call a joint planted is also lowered
    until the lowest planted joint is at its resting height (never a joint below its own):
    a planted foot stands on the floor rather than above it. Frames with no planted joint
    (a run's flight) are only raised.

    The root height is drawn independently of the legs. 60 s rollouts of the Bandai prior
    from 8 held-out starts (bench/prior.py, "a minute of motion", 96 segments of 5 s):
    unfloored, a foot went up to 10 cm through the floor on fast walks and the lowest foot
    stayed within 3 cm of its rest in 90% of the frames of 65 segments; raised only, 74
    (the proud, feminine and youthful walks floating 2-7 cm above the floor in a third of
    their frames, at walking pace); settled too, 87."""
    cidx = spec.contact_indices()
    heights = decode_positions(x[..., None, :], spec, skeleton)[..., 0, cidx, 1]
    above = heights - (0.0 if rest is None else rest)
    lowest = above.amin(-1, keepdim=True)
    shift = lowest.clamp_max(0.0)
    if settle:
        planted = x[..., spec.slices()["contacts"]] > 0.5
        lowest_planted = torch.where(planted, above, torch.inf).amin(-1, keepdim=True)
        shift = torch.where(planted.any(-1, keepdim=True), torch.minimum(lowest_planted, lowest), shift)
    out = x.clone()
    out[..., spec.slices()["root_height"]] -= shift
    return out


def advance(start: RootStart, x: Tensor, spec: FeatureSpec) -> RootStart:
    """The root state after the (unnormalised) frames ``x (T, D)``, continuing from ``start``:
    what decoding the next frames continues from."""
    if len(x) == 0:
        return start
    with torch.no_grad():
        yaw = start.yaw + float(x[:, spec.slices()["yaw_delta"]].double().sum())
        _, root = decode(x.double(), spec, start)
    return RootStart(yaw, float(root[-1, 0]), float(root[-1, 2]), start.ground)


def to_file_motion(model: Motion, original: Motion) -> Motion:
    """Put a motion on the prior's joints back on the original file's skeleton.

    The result has the original's joints, channels, unit and frame rate (resampled from
    the prior's rate). Modelled joints take the model's rotations; the joints the prior
    leaves out (fingers, eyes) and any joints above the model root keep the original's
    values, frame by frame, holding the last original frame beyond its end. A result up
    to one prior frame shorter than the input (the input's length is rarely a whole
    number of prior frames) holds its last frame, so the frame count is the input's.
    """
    sk = original.skeleton
    out = model.resample(original.fps)
    short = original.num_frames - out.num_frames
    if 0 < short <= original.fps / model.fps + 1:
        # the prior's last frame falls just before the input's last: hold it to keep the length
        out = out.with_frames(np.concatenate([out.rotations, np.repeat(out.rotations[-1:], short, 0)]),
                              np.concatenate([out.root, np.repeat(out.root[-1:], short, 0)]))
    n = out.num_frames
    src = np.minimum(np.arange(n), original.num_frames - 1)
    rotations = original.rotations[src].copy()
    translations = original.local_translations()[src]
    root_name = model.skeleton.names[0]
    r = sk.index(root_name)
    for j, name in enumerate(model.skeleton.names[1:], start=1):
        rotations[:, sk.index(name)] = out.rotations[:, j]
    # the model root's world transform, expressed under the original's joints above it
    world_rot = torch.from_numpy(out.rotations[:, 0])
    world_pos = torch.from_numpy(out.root)
    if r == 0:
        rotations[:, 0] = world_rot.numpy()
        translations[:, 0] = world_pos.numpy()
    else:
        p = int(sk.parents[r])
        _, grot = fk(sk.parents[:p + 1], torch.from_numpy(rotations[:, :p + 1]), torch.from_numpy(translations[:, 0]),
                     torch.from_numpy(sk.offsets[:p + 1]), torch.from_numpy(translations[:, :p + 1]),
                     return_global_rotations=True)
        ppos = fk(sk.parents[:p + 1], torch.from_numpy(rotations[:, :p + 1]), torch.from_numpy(translations[:, 0]),
                  torch.from_numpy(sk.offsets[:p + 1]), torch.from_numpy(translations[:, :p + 1]))
        inv = R.quat_conjugate(grot[:, p])
        rotations[:, r] = R.quat_multiply(inv, world_rot).numpy()
        translations[:, r] = R.quat_apply(inv, world_pos - ppos[:, p]).numpy()
    has_tr = original.translations is not None or r != 0
    hint = None if original.euler_hint is None else original.euler_hint[src]
    return Motion(sk, rotations, translations[:, 0].copy(), original.fps,
                  translations=translations if has_tr else None, source_unit=original.source_unit, euler_hint=hint)
