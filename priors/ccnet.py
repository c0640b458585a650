"""Causal dilated-convolution Gaussian prior (after CCNet, Hou et al. 2021, sections 4-5).

A 1x1 encoder, gated residual blocks of dilated causal convolutions with skip
connections, and a decoder that outputs, for frame t, a diagonal Gaussian over the
pose features of frame t (log-std clamped) and contact logits, from frames before t
only. One teacher-forced pass scores a window. The mean of the joint and root-tilt
rotations and of the root height is predicted as a change from frame t-1; the root
rates (ground velocity, yaw rate) are predicted directly: as changes their errors
integrate twice and free-running rollouts speed up without bound.

Dimensions that never move in the training data (``Normalizer.moving``) are held at
their previous value and left out of the likelihood: a prior that has only seen a
constant there would otherwise give any clip that moves them an unbounded cost.

A prior may carry an anchor (``CCNetConfig.anchor``): a second network that predicts
the pose itself, whose Gaussian is pooled with this one's (``pool``; built by
``priors.pool``), so that free-running rollouts do not drift.
"""
from __future__ import annotations

import copy
import math
from dataclasses import asdict, dataclass, replace

import torch
import torch.nn.functional as Fn
from torch import Tensor, nn

from motionopt import rotations as R
from motionopt.dataset import Normalizer
from motionopt.features import FeatureSpec, contact_heights, floored_root_height, planted_root_step
from motionopt.prior import Steer, gaussian_nll, scoring_log_std, student_nll
from motionopt.skeleton import Skeleton

from .degrade import degraded_batch
from .stacked import StackedWeights, architecture, blocks, encode, stack_weights
from .temperature import DEFAULT_TEMPERATURE


@dataclass(frozen=True)
class CCNetConfig:
    """Architecture; ``dilations`` sets the number of blocks and the receptive field."""

    channels: int = 64
    skip_channels: int = 128
    dilations: tuple[int, ...] = (1, 2, 4, 8, 16, 1, 2, 4, 8, 16)
    kernel_size: int = 2
    log_std_min: float = -5.0
    log_std_max: float = 1.0
    #: Floor of the predicted std in unnormalised feature units (0: none). Without it a
    #: dimension that barely moves in training (a knee's twist: normalised by a std of
    #: 0.004) is predicted to within 1e-4, and one frame of a held-out CMU clip that twists
    #: the knee costs a million nats, more than all its other frames together. A CMU
    #: training with 0.001 scored that clip sanely (its clean frames below its noisy copy's)
    #: but lost 6 nats of median validation NLL and rolled out jitterier (calibrated
    #: temperature 0.05 against 0.15), so the shipped priors have none.
    std_floor: float = 0.0
    input_dropout: float = 0.1
    #: Predict the root rates (ground velocity, yaw rate) directly rather than as a change
    #: from the previous frame.
    absolute_root: bool = True
    #: Predict the root height directly too. A change from the previous frame is more
    #: precise one step ahead but integrates in free-running rollouts: the Bandai prior
    #: trained that way sank its hips 12-17 m below the floor within 60 s from every one
    #: of 8 held-out starts (bench/prior.py, "a minute of motion").
    absolute_height: bool = True
    #: Predict every pose dimension directly, the joint rotations too. As changes from
    #: the previous frame, each step's small bias integrates: the mean rollout of the
    #: Bandai prior trained that way bent its legs, step by step, from every held-out walk
    #: tried, until the hips hovered at their height with the feet 0.6 m above the floor.
    absolute_pose: bool = False
    #: Joints (by name; the root's for its tilt) whose rotations are predicted directly
    #: while the rest are predicted as changes: the legs, so that the support the absolute
    #: root height stands on cannot drift away from it step by step in a rollout.
    absolute_joints: tuple[str, ...] = ()
    #: A second network of this config (trained with ``absolute_pose``) whose next-frame
    #: Gaussian is pooled with this one's (``pool``), with weight ``anchor_weight``: the
    #: changes predicted here are sharp one step ahead but their small biases integrate in
    #: free-running motion, which the anchor's direct prediction of the pose pulls back.
    #: Alone, the Bandai prior's 60 s rollouts lifted the lowest foot off the floor in
    #: every 5 s segment from 8 held-out starts (legs folded under hips held at their
    #: height); an absolute prior alone kept the feet down but scored blunter and ranked
    #: low-passed copies of real motion above it (bench/prior.py).
    anchor: "CCNetConfig | None" = None
    anchor_weight: float = 0.0
    #: Degrees of freedom of a Student-t likelihood per dimension (0: Gaussian). The
    #: predicted log-std is then the t's log-scale. Rollouts draw from a Gaussian of that
    #: scale: the t's tails are for scoring a held-out clip's rare dimensions, not for
    #: sampling jumps.
    tail_dof: float = 0.0

    @classmethod
    def from_dict(cls, d: dict) -> "CCNetConfig":
        d = dict(d)
        if d.get("anchor") is not None:
            d["anchor"] = cls.from_dict(d["anchor"])
        d["dilations"] = tuple(d["dilations"])
        d.setdefault("absolute_root", False)  # checkpoints from before the field predicted changes
        d.setdefault("absolute_height", d["absolute_root"])  # and from before this one, like the rates
        d.setdefault("std_floor", 0.0)
        d.setdefault("absolute_pose", False)  # checkpoints from before the field predicted changes
        d["absolute_joints"] = tuple(d.get("absolute_joints", ()))
        d.setdefault("tail_dof", 0.0)  # checkpoints from before the field are Gaussian
        return cls(**d)

    def to_dict(self) -> dict:
        return asdict(self)


def absolute_dims(spec: FeatureSpec, joints: tuple[str, ...]) -> Tensor:
    """(P,) True on the pose dimensions of ``joints``' rotations (the root's: its tilt)."""
    unknown = [j for j in joints if j not in spec.joints]
    if unknown:
        raise ValueError(f"absolute joints {', '.join(unknown)} are not among the prior's joints "
                         f"({', '.join(spec.joints)})")
    s = spec.slices()
    mask = torch.zeros(spec.pose_dim, dtype=torch.bool)
    for name in joints:
        i = spec.joints.index(name)
        start = s["root_tilt"].start if i == 0 else s["joint_rotations"].start + 6 * (i - 1)
        mask[start:start + 6] = True
    return mask


class GatedResidualBlock(nn.Module):
    """The weights of one gated residual block: tanh(filter) * sigmoid(gate) of a dilated
    causal convolution (``conv``), with residual (``res``) and skip (``skip``) outputs.
    ``priors.stacked`` evaluates the blocks, as batched matrix products."""

    def __init__(self, channels: int, skip: int, kernel: int, dilation: int):
        super().__init__()
        self.conv = nn.Conv1d(channels, 2 * channels, kernel, dilation=dilation)
        self.res = nn.Conv1d(channels, channels, 1)
        self.skip = nn.Conv1d(channels, skip, 1)


@dataclass
class ContextCache:
    """A context's share of the network's pass, computed once (``CCNetPrior.cache_context``)
    and passed as ``context`` to score many windows after it: a window of 34 frames then
    costs 34 frames of work, not 34 plus the receptive field's 63.

    ``frames (C, D)``: the context; ``last (1, D)``: the frame that predicts the window's
    first (the context's last, or a zero frame); ``past``: per group of stacked networks
    (``CCNetPrior._stacks``), per block, its input at the frames before ``last``
    (networks, channels, 1, pad), zeros before the sequence's start."""

    frames: Tensor
    last: Tensor
    past: list[list[Tensor]]

    @property
    def shape(self) -> torch.Size:
        return self.frames.shape


class CCNetPrior(nn.Module):
    """The causal-convolution prior; implements ``motionopt.prior.MotionPrior``."""

    def __init__(self, spec: FeatureSpec, normalizer: Normalizer, skeleton: Skeleton,
                 config: CCNetConfig = CCNetConfig(), metadata: dict | None = None):
        super().__init__()
        self.spec, self.normalizer, self.skeleton = spec, normalizer, skeleton
        self.config = config
        self.metadata = dict(metadata or {})
        d, c = spec.dim, config.channels
        self.encoder = nn.Sequential(nn.Conv1d(d, c, 1), nn.ReLU(), nn.Conv1d(c, c, 1))
        self.blocks = nn.ModuleList(GatedResidualBlock(c, config.skip_channels, config.kernel_size, dil)
                                    for dil in config.dilations)
        self.decoder = nn.Sequential(nn.ReLU(), nn.Conv1d(config.skip_channels, config.skip_channels, 1), nn.ReLU(),
                                     nn.Conv1d(config.skip_channels, 2 * spec.pose_dim + spec.num_contacts, 1))
        nn.init.zeros_(self.decoder[-1].weight)
        nn.init.zeros_(self.decoder[-1].bias)
        self.register_buffer("moving", normalizer.moving()[:spec.pose_dim].float(), persistent=False)
        floor = (torch.log(config.std_floor / normalizer.std[:spec.pose_dim]) if config.std_floor > 0
                 else torch.full((spec.pose_dim,), -math.inf))
        self.register_buffer("log_std_floor", floor.float(), persistent=False)
        self.register_buffer("absolute_dims", absolute_dims(spec, config.absolute_joints), persistent=False)
        self.anchor = (CCNetPrior(spec, normalizer, skeleton, config.anchor) if config.anchor is not None
                       else None)
        if self.anchor is not None:   # the pool's log-std correction per pose dimension (``pool``)
            self.register_buffer("pool_log_scale", torch.zeros(spec.pose_dim))

    @property
    def receptive_field(self) -> int:
        own = 1 + sum((self.config.kernel_size - 1) * d for d in self.config.dilations)
        return own if self.anchor is None else max(own, self.anchor.receptive_field)

    @property
    def sample_temperature(self) -> float:
        return float(self.metadata.get("sample_temperature", DEFAULT_TEMPERATURE))

    # ---- core pass ---------------------------------------------------------------------
    def _predict(self, history: Tensor, past: list[list[Tensor]] | None = None) -> tuple[Tensor, Tensor, Tensor]:
        """For every frame of ``history (B, T, D)``: the Gaussian (mean, log-std) and contact
        logits of the *next* frame. Shapes (B, T, P), (B, T, P), (B, T, C). ``past``: each
        block's input before ``history`` (``ContextCache.past``); None: the sequence starts here."""
        inp = history
        if self.training and self.config.input_dropout > 0:
            inp = Fn.dropout(history.transpose(1, 2), self.config.input_dropout).transpose(1, 2)
        outs, _ = self._run(inp, past)
        return self._pooled(history, outs)

    def _stacks(self) -> list[StackedWeights]:
        """This network's weights and its anchor's, stacked (``priors.stacked``): both in one
        stack when they share an architecture. Rebuilt on every call in training, so that
        gradients reach the parameters; otherwise kept until a parameter changes."""
        if self.training:
            return self._stack_groups()
        key = tuple((id(q), q._version) for q in self.parameters())
        cached = self.__dict__.get("_stacked")
        if cached is None or cached[0] != key:
            with torch.no_grad():
                cached = (key, self._stack_groups())
            self.__dict__["_stacked"] = cached
        return cached[1]

    def _stack_groups(self) -> list[StackedWeights]:
        """This network and its anchor grouped by ``stacked.architecture``, each group stacked."""
        groups: dict[tuple, list[CCNetPrior]] = {}
        for net in ([self] if self.anchor is None else [self, self.anchor]):
            groups.setdefault(architecture(net), []).append(net)
        return [stack_weights(g) for g in groups.values()]

    def _run(self, history: Tensor, past: list[list[Tensor]] | None = None
             ) -> tuple[list[Tensor], list[list[Tensor]]]:
        """Each network's decoder output (B, T, out) for frames ``history (B, T, D)``, in the
        order this one, its anchor; and per stack, per block, its input over its receptive
        span (``stacked.blocks``)."""
        outs, spans = [], []
        for g, w in enumerate(self._stacks()):
            out, span = blocks(w, encode(w, history), None if past is None else past[g])
            outs += list(out.permute(0, 2, 3, 1))
            spans.append(span)
        return outs, spans

    def _pooled(self, history: Tensor, outs: list[Tensor]) -> tuple[Tensor, Tensor, Tensor]:
        """The next frame's mean, log-std and contact logits after ``history`` from the
        networks' outputs ``outs`` (``_run``): this network's Gaussian, pooled with its
        anchor's when it has one."""
        mean, log_std, logits = self._head(history, outs[0])
        if self.anchor is None:
            return mean, log_std, logits
        anchor_mean, anchor_log_std, _ = self.anchor._head(history, outs[1])
        return (*self.pool(mean, log_std, anchor_mean, anchor_log_std), logits)

    def unpooled(self) -> "CCNetPrior":
        """This prior without its anchor (itself when it has none), sharing its weights:
        the change model alone, sharp one step ahead, for scoring motion whose every frame
        is observed. Denoising held-out Bandai clips through the pool ended further from
        the clean clips at 5 cm of noise (1.74 cm against 1.61 through the change model;
        bench/tasks.py): the anchor keeps free-running motion from drifting, which a
        denoised clip never does, and its blunter Gaussian pulls observed poses toward
        typical ones."""
        if self.anchor is None:
            return self
        alone = copy.copy(self)
        alone._modules = {**self._modules, "anchor": None}
        alone.config = replace(self.config, anchor=None, anchor_weight=0.0)
        return alone

    def pool(self, mean: Tensor, log_std: Tensor, anchor_mean: Tensor, anchor_log_std: Tensor
             ) -> tuple[Tensor, Tensor]:
        """The geometric pool of this network's Gaussian and the anchor's (``anchor_weight``
        w): density proportional to p^(1-w) q^w, a Gaussian whose precision is the
        weighted mean of the two precisions, and whose mean their precision-weighted mean.
        Where both predict the same Gaussian the pool is that Gaussian; where they differ
        its mean is nearer the truth than its spread says (the Bandai pool's one-step z RMS
        was 0.74 on held-out clips), which ``pool_log_scale``, fitted on the training
        clips (``priors.pool.fit_pool_spread``), corrects per dimension."""
        w = self.config.anchor_weight
        a = (1 - w) * torch.exp(-2 * log_std)
        b = w * torch.exp(-2 * anchor_log_std)
        precision = a + b
        return (a * mean + b * anchor_mean) / precision, -0.5 * torch.log(precision) + self.pool_log_scale

    def _head(self, history: Tensor, out: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """The decoder's output ``out`` read as the next frame's mean, log-std and contact logits."""
        p = self.spec.pose_dim
        if self.config.absolute_pose:   # still dimensions are held at their previous value either way
            return (torch.lerp(history[..., :p], out[..., :p], self.moving), *self._spread(out))
        mean = history[..., :p] + out[..., :p] * self.moving
        if self.config.absolute_joints:
            mean = torch.where(self.absolute_dims, torch.lerp(history[..., :p], out[..., :p], self.moving), mean)
        if self.config.absolute_root:
            s = self.spec.slices()
            r = (s["root_tilt"] if self.config.absolute_height else s["root_height"]).start
            mean = torch.cat((out[..., :r], mean[..., r:]), dim=-1)
        return (mean, *self._spread(out))

    def _spread(self, out: Tensor) -> tuple[Tensor, Tensor]:
        """The decoder's output ``out`` read as the next frame's log-std and contact logits."""
        p = self.spec.pose_dim
        log_std = torch.maximum(out[..., p:2 * p].clamp(self.config.log_std_min, self.config.log_std_max),
                                self.log_std_floor)
        return log_std, out[..., 2 * p:]

    def _past(self, frames: Tensor) -> list[list[Tensor]]:
        """Per stack, per block, its input (networks, channels, B, pad) at the frames of
        ``frames (B, T, D)`` before the last (zeros before the sequence's start): the state
        ``_advance`` continues from when it is handed the last frame."""
        t = frames.shape[-2] - 1
        if t < 1:   # nothing before the last frame: the sequence starts there
            return [[frames.new_zeros(w.encoder[0][0].shape[0], w.channels, len(frames), (w.kernel - 1) * d)
                     for d in w.dilations] for w in self._stacks()]
        _, spans = self._run(frames[:, :-1])
        return [[x[..., t:] for x in span] for span in spans]

    def _advance(self, frame: Tensor, past: list[list[Tensor]]
                 ) -> tuple[Tensor, Tensor, Tensor, list[list[Tensor]]]:
        """The next frame's mean, log-std and contact logits (B, P), (B, P), (B, C) after
        ``frame (B, D)``, and the blocks' inputs moved on by it: one frame of network work
        per step of a rollout instead of a pass over the receptive field's 63 frames."""
        outs, spans = self._run(frame[:, None], past)
        mean, log_std, logits = self._pooled(frame, [o[:, 0] for o in outs])
        return mean, log_std, logits, [[x[..., 1:] for x in span] for span in spans]

    def _history(self, x: Tensor, context: Tensor | None) -> tuple[Tensor, int]:
        """Frames that predict ``x``: context (or a zero frame) followed by x without its last frame."""
        if context is None or context.shape[-2] == 0:
            context = torch.zeros_like(x[..., :1, :])
        full = torch.cat((context.to(x), x), dim=-2)
        return full[..., :-1, :], context.shape[-2] - 1

    def _flat(self, x: Tensor) -> tuple[Tensor, tuple[int, ...]]:
        lead = x.shape[:-2]
        return x.reshape(-1, *x.shape[-2:]), lead

    @torch.no_grad()
    def cache_context(self, context: Tensor) -> ContextCache:
        """``context (C, D)``'s share of every pass over windows after it (``ContextCache``)."""
        last = context[-1:] if len(context) else context.new_zeros(1, self.spec.dim)
        return ContextCache(context, last, self._past((context if len(context) else last)[None]))

    def gaussian(self, x: Tensor, context: Tensor | ContextCache | None = None) -> tuple[Tensor, Tensor, Tensor]:
        """Predicted mean, log-std (..., T, P) and contact logits (..., T, C) for frames of ``x``."""
        if isinstance(context, ContextCache):
            hist = torch.cat((context.last.to(x).expand(*x.shape[:-2], 1, x.shape[-1]), x[..., :-1, :]), dim=-2)
            flat, lead = self._flat(hist)
            out = self._predict(flat, context.past)
            return tuple(t.reshape(*lead, x.shape[-2], t.shape[-1]) for t in out)  # type: ignore[return-value]
        if context is not None and context.dim() < x.dim():
            context = context.expand(*x.shape[:-2], *context.shape[-2:])
        hist, skip = self._history(x, context)
        flat, lead = self._flat(hist)
        mean, log_std, logits = self._predict(flat)
        T = x.shape[-2]
        out = [t[:, skip:skip + T] for t in (mean, log_std, logits)]
        return tuple(t.reshape(*lead, T, t.shape[-1]) for t in out)  # type: ignore[return-value]

    # ---- protocol ----------------------------------------------------------------------
    def nll_and_contacts(self, x: Tensor, context: Tensor | None = None, min_log_std: float | Tensor | None = None,
                         log_std: Tensor | None = None) -> tuple[Tensor, Tensor]:
        mean, predicted, logits = self.gaussian(x, context)
        return self._frame_nll(x, mean, scoring_log_std(predicted, log_std, min_log_std)), torch.sigmoid(logits)

    def _frame_nll(self, x: Tensor, mean: Tensor, log_std: Tensor) -> Tensor:
        """Per-frame NLL of the pose part of ``x`` over the moving dimensions: Gaussian, or
        Student-t with ``config.tail_dof`` degrees of freedom."""
        pose = x[..., :self.spec.pose_dim]
        if self.config.tail_dof > 0:
            return student_nll(pose, mean, log_std, self.config.tail_dof, self.moving).sum(-1)
        return gaussian_nll(pose, mean, log_std, self.moving).sum(-1)

    def nll(self, x: Tensor, context: Tensor | None = None) -> Tensor:
        return self.nll_and_contacts(x, context)[0]

    def predict_contacts(self, x: Tensor, context: Tensor | None = None) -> Tensor:
        return self.nll_and_contacts(x, context)[1]

    @torch.no_grad()
    def sample(self, context: Tensor, n_frames: int, generator: torch.Generator | None = None,
               temperature: float = 1.0, noise: Tensor | None = None, plant: bool = True,
               steer: Steer | None = None) -> Tensor:
        """Roll out ``n_frames`` after ``context`` (``MotionPrior.sample``), one frame of
        network work per new frame (``_advance``). With ``plant`` the root step of each new
        frame keeps planted contact joints still on the ground plane
        (``features.planted_root_step``): those the contact head calls planted, and, given
        half a second of context, those within the spec's contact height of their resting
        height in the context (a low percentile, as ``metrics.rest_heights``); and its root
        is raised where a contact joint would go below that height, and lowered where a
        joint the contact head calls planted floats above it (``features.floored_root_height``
        with ``settle``). The prior's own foot sliding, sinking and floating are removed: of
        96 5 s segments of 60 s rollouts of the Bandai prior from 8 held-out starts, 89 skate
        at most 1.5 times the held-out data's and 87 keep the lowest foot within 3 cm of the
        floor, against 50 and 71 with an equal mean of the planted joints' steps and no
        floor, and 94 and 74 raised but not lowered (bench/prior.py)."""
        flat, lead = self._flat(context)
        if n_frames == 0:
            return context[..., :0, :]
        if noise is not None:
            noise = noise.reshape(-1, n_frames, self.spec.pose_dim)
        rest = None
        if plant and flat.shape[-2] >= self.spec.fps / 2:
            heights = contact_heights(self.normalizer.denormalize(flat), self.spec, self.skeleton)
            rest = torch.quantile(heights, 0.05, dim=-2)
        last, past = flat[:, -1], self._past(flat[:, -self.receptive_field:])
        new = []
        for _ in range(n_frames):
            mean, log_std, logits, past = self._advance(last, past)
            eps = noise[:, len(new)] if noise is not None else torch.randn(
                mean.shape, generator=generator, dtype=mean.dtype, device=mean.device)
            nxt = self._draw(mean, log_std, logits, temperature * eps)
            if plant:
                norm = self.normalizer
                step = planted_root_step(norm.denormalize(last), norm.denormalize(nxt), self.spec,
                                         self.skeleton, rest)
                nxt = norm.normalize(floored_root_height(step, self.spec, self.skeleton, rest, settle=True)).to(nxt)
            if steer is not None:
                nxt = steer(len(new), last, nxt)
            new.append(nxt)
            last = nxt
        out = torch.stack(new, dim=1)
        return out.reshape(*lead, n_frames, self.spec.dim)

    def _draw(self, mean: Tensor, log_std: Tensor, logits: Tensor, eps: Tensor) -> Tensor:
        """A frame from the predicted Gaussian (standard noise ``eps``) and contacts."""
        pose = mean + torch.exp(log_std) * eps * self.moving
        return self.project(torch.cat((pose, (logits > 0).to(pose)), dim=-1))

    def project(self, x: Tensor) -> Tensor:
        """Normalised features with every 6D rotation made orthonormal (keeps rollouts on
        the manifold the data lives on)."""
        raw = self.normalizer.denormalize(x)
        s = self.spec.slices()
        parts = []
        for key in ("root_tilt", "joint_rotations"):
            v = raw[..., s[key]]
            six = v.reshape(*v.shape[:-1], -1, 6)
            parts.append(R.matrix_to_6d(R.sixd_to_matrix(six)).reshape(v.shape))
        raw = torch.cat((raw[..., :4], parts[0], parts[1], raw[..., s["contacts"]]), dim=-1)
        return self.normalizer.normalize(raw)

    # ---- training loss -----------------------------------------------------------------
    def loss(self, x: Tensor, valid: Tensor | None = None, noise_std: float = 0.03, smooth_weight: float = 10.0,
             contact_weight: float = 2.0, passes: int = 1, contrast_weight: float = 0.0, contrast_margin: float = 0.1,
             generator: torch.Generator | None = None, rollout_frames: int = 0,
             rollout_temperature: float = 0.5) -> tuple[Tensor, dict[str, float]]:
        """Training loss on windows ``x (B, T, D)`` (frames where ``valid (B, T)`` is False
        are padding): Gaussian NLL per frame and moving dimension, plus smoothness of the
        predicted means and contact cross-entropy. Noise augmentation perturbs the
        history, not the targets.

        ``passes`` > 1 trains on the model's own predictions (parallel scheduled sampling):
        pass k+1 predicts the same targets from a history made of frames drawn from pass
        k's predictions (no gradient through the draw), so the model learns to recover
        from its own errors, which teacher forcing alone never shows it and which make
        free-running rollouts drift.

        ``contrast_weight`` > 0 adds the ranking part: each window gets a degraded copy
        (``priors.degrade``: frozen, low-passed, slowed, sped up or noisy) whose mean NLL
        per frame and moving dimension must exceed the real window's by
        ``contrast_margin`` nats; the shortfall is penalised (hinge). Only the copy's NLL
        gets this gradient (the real window's is detached), and only through the
        predicted mean (the log-std is detached): raising a copy's NLL by a wider std
        widened it on real motion too (a Bandai training stalled at +165 nats per frame),
        and by a narrower one made held-out clips overconfident (CMU validation NLL +400).
        So the network learns to expect real motion after a degraded history, and the
        likelihood of real motion, and its calibration, stay the maximum-likelihood fit.

        ``rollout_frames`` > 0 adds a free-running pass: the window's last
        ``rollout_frames`` frames are predicted from a history in which the model drew
        them itself, one after another from its own draws (at ``rollout_temperature``, as
        rollouts sample), after the real frames before them. The parallel passes show the
        model one step of its own error; this shows it the drift that builds up over a
        second, and trains it to steer back to real motion from there. Without it the
        mean rollout of the Bandai prior drifted, from every held-out walk tried, into a
        pose that holds the hips at their height and the feet 0.6 m above the floor.
        """
        p = self.spec.pose_dim
        target = x[:, 1:]
        w = (valid[:, 1:] if valid is not None else torch.ones(target.shape[:2], dtype=torch.bool)).to(x)
        hist = x[:, :-1]
        nlls = []
        for k in range(passes):
            mean, log_std, logits = self._predict(self._noised(hist, noise_std))
            per_frame = self._frame_nll(target, mean, log_std)
            nlls.append((per_frame * w).sum() / w.sum())
            if k == 0:
                real = per_frame
                acc = (mean[:, 2:] - 2 * mean[:, 1:-1] + mean[:, :-2]).pow(2).sum(-1)
                smooth = (acc * w[:, 2:]).sum() / w[:, 2:].sum().clamp_min(1)
                bce = Fn.binary_cross_entropy_with_logits(logits, target[..., p:], reduction="none").mean(-1)
                contact = (bce * w).sum() / w.sum() if self.spec.num_contacts else smooth * 0
            if k + 1 < passes:
                with torch.no_grad():
                    drawn = self._draw(mean, log_std, logits, torch.randn_like(mean))
                    hist = torch.cat((x[:, :1], drawn[:, :-1]), dim=1)
        if rollout_frames > 0:
            nlls.append(self._rollout_nll(x, w, rollout_frames, rollout_temperature, noise_std))
        nll = torch.stack(nlls).mean()
        dims = self.moving.sum()
        total = nll / dims + smooth_weight * smooth / dims + contact_weight * contact
        parts = {"nll": float(nlls[0].detach()), "nll_own": float(nlls[passes - 1].detach()),
                 "smooth": float(smooth.detach()), "contact": float(contact.detach())}
        if rollout_frames > 0:
            parts["nll_rollout"] = float(nlls[-1].detach())
        if contrast_weight > 0:
            hinge, ranked = self._contrast(x, real.detach(), w, noise_std, contrast_margin, generator)
            total = total + contrast_weight * hinge
            parts.update(contrast=float(hinge.detach()), ranked=ranked)
        return total, parts

    def _rollout_nll(self, x: Tensor, w: Tensor, frames: int, temperature: float, noise_std: float) -> Tensor:
        """Mean NLL per frame of the last ``frames`` frames of ``x (B, T, D)`` (weights ``w``
        per target frame), each predicted from the real frames before them and the frames
        the model drew itself in their place (no gradient through the draws)."""
        c = x.shape[1] - frames   # real frames of the history
        drawn = self.sample(x[:, :c], frames - 1, temperature=temperature, plant=False)
        hist = torch.cat((x[:, :c], drawn), dim=1)
        mean, log_std, _ = self._predict(self._noised(hist, noise_std))
        per_frame = self._frame_nll(x[:, c:], mean[:, c - 1:], log_std[:, c - 1:])
        wr = w[:, c - 1:]
        return (per_frame * wr).sum() / wr.sum().clamp_min(1)

    def _noised(self, hist: Tensor, noise_std: float) -> Tensor:
        """The history with Gaussian noise of ``noise_std`` on its pose dimensions."""
        if noise_std <= 0:
            return hist
        noise = torch.randn_like(hist) * noise_std
        noise[..., self.spec.pose_dim:] = 0
        return hist + noise

    def _contrast(self, x: Tensor, real: Tensor, w: Tensor, noise_std: float, margin: float,
                  generator: torch.Generator | None) -> tuple[Tensor, float]:
        """Hinge on (real window's NLL + margin - its degraded copy's NLL), per moving
        dimension and frame, for windows whose copy differs from them (a frozen copy of a
        window that stands still is no degradation); and the share of windows ranked
        right by the margin."""
        norm = self.normalizer
        with torch.no_grad():
            raw, mask, _ = degraded_batch(norm.denormalize(x), self.spec, generator)
            copy = self.project(norm.normalize(raw).to(x))
        mask = mask[:, 1:].to(x) * w
        mean, log_std, _ = self._predict(self._noised(copy[:, :-1], noise_std))
        fake = self._frame_nll(copy[:, 1:], mean, log_std.detach())
        dims = self.moving.sum()
        fake_mean = (fake * mask).sum(1) / mask.sum(1).clamp_min(1) / dims
        real_mean = (real * w).sum(1) / w.sum(1).clamp_min(1) / dims
        p = self.spec.pose_dim
        differs = ((copy[:, 1:, :p] - x[:, 1:, :p]).abs().mean(-1) * mask).sum(1) / mask.sum(1).clamp_min(1) > 0.05
        gap = Fn.relu(real_mean + margin - fake_mean) * differs
        ranked = float(((fake_mean > real_mean + margin) | ~differs).float().mean())
        return gap.sum() / differs.sum().clamp_min(1), ranked
