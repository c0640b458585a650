"""Benchmark of the shipped latent (W+) priors on their held-out clips.

For each checkpoint (default: the shipped latent ones), with the training and validation
clips named in its metadata, loaded from the data folder named there:

1. Reconstruction of held-out 64-frame windows (stride 32): G(I(m)) with the encoder
   alone, then with L-BFGS refinement of W+ against the input (``problems.latent``'s
   fidelity term plus the W regulariser). Errors as MoDi table 5: global root position,
   root-relative (local) joint position and global joint position, mean Euclidean
   distance in mm, with every window decoded from the origin. Also the masked encoder
   completing each window from its first half (errors on the seen and unseen halves).
2. Sampling quality: Fréchet distance between held-out windows and (a) the latent
   prior's samples, (b) rollouts of the autoregressive prior trained on the same data
   (64 frames after 8 held-out frames of context, at its calibrated temperature and at
   1), (c) Gaussian noise in the normalised feature space, (d) training windows (a
   floor). Features: the 32-dimensional code of a small convolutional autoencoder
   trained here on the training clips only.
3. Semantic editing on 256 sampled motions: for each computed attribute and strength
   (standard deviations of the codes along the fitted direction), the mean of every attribute
   score and the mean horizontal root-path change (cm) against strength 0. The edited
   attribute must move monotonically, and each other attribute must move less than half
   as much as the edited one, in standard deviations of the unedited scores. Style
   directions (Bandai) are checked by the checkpoint's style classifier
   (``priors.style``): the probability it gives the style must rise with strength.
4. Tasks on held-out clips, latent inversion against the autoregressive MAP tasks of
   the same name: denoising (accuracy against the clean clip), completion of the second
   after the first (accuracy on that second) and in-betweening of a 1.5 s gap (accuracy
   on the gap), with seconds per clip.
5. What a user sees, on the first 10 s of 4 held-out clips of at least 4 s (spread over
   the list), each
   figure at the prior's rate on its joints: the round trip (local joint error, root
   path distance, seconds) with the encoder alone and refined; at 1, 3 and 5 cm of
   joint noise, the latent inversion, ``denoise --method latent`` (the MAP denoiser with
   the latent prior term, ``priors.latent_density``), the default denoiser and the same
   MAP without a prior term, against the noisy input; edits at strength +2 against -2
   (``problems.latent_edit``; mean hip height and right hand height in cm, root speed in
   percent, the style classifier's probability of a style) with the root path change and
   the feet's sliding against strength 0's.
6. Variations, interpolation and fusion on section 5's clips: ``vary`` (mean pairwise
   joint distance of 4 variations) and the middle step of ``interpolate``, as generated
   and settled under the autoregressive prior (``problems.settle``), each with its NLL
   per frame under that prior, jerk and foot skating beside the inputs'; how far each
   end of ``interpolate`` is from its input; and
   ``fuse`` (each part's distance from its input, the fastest joint across the seam).

Run ``python bench/latent.py [CHECKPOINT ...] [--threads N] [--sections 1 4 ...]``; the
report is printed and, for all sections of the shipped checkpoints, written to
bench/results/latent.txt.
"""
from __future__ import annotations

import argparse
from dataclasses import replace
import time
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn

from motionopt import attributes as A
from motionopt import bvh, naturalness
from motionopt import rotations as R
from motionopt.codec import Codec
from motionopt.dataset import build_dataset
from motionopt.features import estimate_ground, heading_angle
from motionopt.metrics import foot_skating, jerk
from motionopt.metrics_latent import frechet_distance, local_position_error_mm, root_position_error_mm
from motionopt.motion import Motion
from motionopt.noise import capture_noise, position_noise
from motionopt.solver import InversionOptions, refine, regulariser
from motionopt.table import format_table
from priors.checkpoint import CHECKPOINT_DIR, SHIPPED_LATENT, load_prior, read_checkpoint, shipped_checkpoints
from priors.heldout import data_folder, held_out_clips
from priors.latent_density import LatentDensity
from priors.semantic import AttributeScorer, Direction, directions_of, edit_codes
from priors.style import StyleClassifier, style_classifier_of
from problems.latent import FidelityTerm, LatentTask, fuse, interpolate, reconstruct, settled, vary
from problems.latent_edit import goal_of, latent_edit

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results" / "latent.txt"
AR_FOR = {"cmu-latent.pt": "cmu-ccnet.pt", "bandai-latent.pt": "bandai-locomotion-ccnet.pt"}
STRENGTHS = (-2.0, -1.0, 0.0, 1.0, 2.0)


def clip_windows(clips: list[Tensor], window: int, stride: int) -> Tensor:
    """Windows (N, window, D) of normalised clips (T, D), from those at least ``window`` frames long."""
    return torch.cat([x.unfold(0, window, stride).permute(0, 2, 1) for x in clips if len(x) >= window])


def positions(prior, x: Tensor) -> Tensor:
    """World joint positions of normalised windows, each decoded from the origin, in float64."""
    return Codec.of(prior).positions(x.double())


def renormalised(x: Tensor, source, target) -> Tensor:
    """Features normalised for prior ``source``, normalised for ``target`` instead (each
    prior normalises with statistics of its own training set)."""
    return target.normalizer.normalize(Codec.of(source).raw(x.double())).float()


def errors(prior, pred: Tensor, target: Tensor) -> dict[str, float]:
    pp, pt = positions(prior, pred), positions(prior, target)
    return {"root_mm": root_position_error_mm(pp, pt), "local_mm": local_position_error_mm(pp, pt),
            "global_mm": float((pp - pt).norm(dim=-1).mean() * 1000)}


def reconstruction(prior, val: Tensor, iters: int, reg: float) -> list[str]:
    lines = ["1. Reconstruction of held-out windows (mm, mean Euclidean distance; paper: root 59.0, local 20.4, "
             "global 78.2 on Mixamo)",
             f"   {len(val)} windows of {prior.window} frames; refinement: L-BFGS {iters} iterations, "
             f"fidelity sigma {InversionOptions().position_sigma * 100:g} cm, W regulariser weight {reg}"]
    with torch.no_grad():
        t0 = time.perf_counter()
        codes = prior.encode(val)
        enc = prior.generate(codes)
        t_enc = (time.perf_counter() - t0) / len(val)
    rows = [("encoder G(I(m))", errors(prior, enc, val), t_enc)]
    term = FidelityTerm(prior, val, torch.ones(val.shape[1]), InversionOptions().position_sigma)
    t0 = time.perf_counter()
    best, _ = refine(codes, lambda c: term(prior.generate(c)) + reg * regulariser(prior, c), iters)
    t_ref = (time.perf_counter() - t0) / len(val) + t_enc
    with torch.no_grad():
        rows.append((f"encoder + L-BFGS ({iters} it.)", errors(prior, prior.generate(best), val), t_ref))
        half = prior.window // 2
        mask = torch.zeros(len(val), prior.window)
        mask[:, :half] = 1
        masked = prior.generate(prior.encode_masked(val, mask))
    lines += format_table(["method", "root", "local", "global", "s/window"],
                          [[name, f"{e['root_mm']:.1f}", f"{e['local_mm']:.1f}", f"{e['global_mm']:.1f}", f"{t:.4f}"]
                           for name, e, t in rows])
    lower = rows[1][1]["root_mm"] < rows[0][1]["root_mm"] and rows[1][1]["local_mm"] < rows[0][1]["local_mm"]
    lines.append(f"   refinement lowers both root and local error: {'yes' if lower else 'NO'}")
    pm, pv = positions(prior, masked), positions(prior, val)
    seen = errors_range(pm, pv, slice(0, half))
    unseen = errors_range(pm, pv, slice(half, None))
    lines.append(f"   masked encoder, first half seen: seen half root {seen[0]:.1f} local {seen[1]:.1f}; "
                 f"unseen half root {unseen[0]:.1f} local {unseen[1]:.1f}")
    return lines


def errors_range(pp: Tensor, pt: Tensor, frames: slice) -> tuple[float, float]:
    return root_position_error_mm(pp[:, frames], pt[:, frames]), local_position_error_mm(pp[:, frames], pt[:, frames])


class WindowAutoencoder(nn.Module):
    """Small convolutional autoencoder of whole windows through a ``code``-dimensional vector;
    ``features`` are those codes."""

    def __init__(self, dim: int, window: int, width: int = 64, code: int = 32):
        super().__init__()
        self.shape = (width, window // 4)
        self.enc = nn.Sequential(nn.Conv1d(dim, width, 5, padding=2), nn.LeakyReLU(0.2),
                                 nn.Conv1d(width, width, 4, stride=2, padding=1), nn.LeakyReLU(0.2),
                                 nn.Conv1d(width, width, 4, stride=2, padding=1), nn.LeakyReLU(0.2),
                                 nn.Flatten(), nn.Linear(width * window // 4, code))
        self.lin = nn.Linear(code, width * window // 4)
        self.dec = nn.Sequential(nn.LeakyReLU(0.2), nn.Upsample(scale_factor=2), nn.Conv1d(width, width, 3, padding=1),
                                 nn.LeakyReLU(0.2), nn.Upsample(scale_factor=2), nn.Conv1d(width, dim, 5, padding=2))

    def forward(self, x: Tensor) -> Tensor:
        h = self.lin(self.enc(x.transpose(1, 2))).reshape(len(x), *self.shape)
        return self.dec(h).transpose(1, 2)

    @torch.no_grad()
    def features(self, x: Tensor) -> np.ndarray:
        return self.enc(x.transpose(1, 2)).numpy()


@torch.enable_grad()
def train_autoencoder(train: Tensor, pose_dim: int, steps: int = 2000, seed: int = 0) -> WindowAutoencoder:
    torch.manual_seed(seed)
    g = torch.Generator().manual_seed(seed)
    ae = WindowAutoencoder(train.shape[-1], train.shape[1])
    opt = torch.optim.Adam(ae.parameters(), lr=1e-3)
    for _ in range(steps):
        b = train[torch.randint(len(train), (32,), generator=g)]
        loss = (ae(b) - b)[..., :pose_dim].pow(2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return ae.eval()


@torch.no_grad()
def sampling(prior, ar_path: Path | None, train: Tensor, val: Tensor, n: int = 512) -> list[str]:
    t0 = time.perf_counter()
    ae = train_autoencoder(train, prior.spec.pose_dim)
    t_ae = time.perf_counter() - t0
    ref = ae.features(val)
    g = torch.Generator().manual_seed(0)
    sets: list[tuple[str, Tensor]] = []
    sets.append(("training windows (floor)", train[torch.randperm(len(train), generator=g)[:n]]))
    t0 = time.perf_counter()
    sets.append(("latent prior samples", prior.generate(prior.sample_wplus(n, g))))
    t_gen = (time.perf_counter() - t0) / n
    notes = [f"latent prior: {t_gen * 1000:.2f} ms per generated window"]
    if ar_path is not None and ar_path.exists():
        ar = load_prior(ar_path)
        if ar.spec != prior.spec:
            notes.append(f"{ar_path.name}: models other features; rollouts skipped")
        else:
            # the two priors normalise with statistics of their own training sets
            ctx = val[torch.randint(len(val), (min(n, 256),), generator=g), :8]
            ctx = renormalised(ctx, prior, ar)
            for temperature in sorted({ar.sample_temperature, 1.0}):
                t0 = time.perf_counter()
                roll = ar.sample(ctx, prior.window, generator=g, temperature=temperature)
                seconds = time.perf_counter() - t0
                sets.append((f"AR prior rollouts, temperature {temperature:g}", renormalised(roll, ar, prior)))
            notes.append(f"{ar_path.name}: {seconds / len(ctx) * 1000:.1f} ms per rollout window "
                         f"(trained on {len(ar.metadata.get('train_clips', []))} clips, "
                         f"{ar.metadata.get('epochs_done')} epochs)")
    noise = torch.randn(n, prior.window, prior.spec.dim, generator=g)
    c = prior.spec.slices()["contacts"]
    noise[..., c] = (noise[..., c] > 0).float()
    sets.append(("Gaussian noise (normalised space)", noise))
    lines = [f"2. Sampling quality: Fréchet distance to {len(val)} held-out windows (autoencoder features, "
             f"{ref.shape[1]} dims; autoencoder trained on {len(train)} training windows in {t_ae:.0f} s)"]
    lines += format_table(["set", "windows", "FD"],
                          [[name, len(x), f"{frechet_distance(ae.features(x), ref):.2f}"] for name, x in sets])
    lines += [f"   {s}" for s in notes]
    return lines


#: Mean horizontal change of the root path (cm) that edits of the other attributes stay under.
ROOT_PATH_BOUND_CM = 10.0


@torch.no_grad()
def semantic(prior) -> list[str]:
    dirs = directions_of(prior)
    scorer = AttributeScorer(prior)
    g = torch.Generator().manual_seed(3)
    w = prior.sample_wplus(256, g)
    base_x = prior.generate(w)
    base = scorer(base_x)
    base_root = scorer.root_path(base_x)
    std = {k: float(v.std()) for k, v in base.items()}
    names = list(base)
    lines = ["3. Semantic editing on 256 sampled motions (scores: gral in [0, 1], root_speed m/s, crouch m; "
             "root path change: mean horizontal distance to the unedited path, cm)",
             "   bound: each other attribute moves less than half as far as the edited one (in std of unedited "
             f"scores), and edits of gral and crouch move the root path less than {ROOT_PATH_BOUND_CM:g} cm on "
             "average (root_speed moves it by design)"]
    blocks: list[tuple[list[list[str]], list[str]]] = []  # per attribute: its table rows, then its verdict
    for name in names:
        if name not in dirs:
            blocks.append(([], [f"   {name}: no direction in the checkpoint"]))
            continue
        rows = []
        means, roots = [], []
        for s in STRENGTHS:
            x = prior.generate(edit_codes(w, dirs[name], s))
            sc = scorer(x)
            means.append({k: float(v.mean()) for k, v in sc.items()})
            root = (scorer.root_path(x) - base_root)[..., [0, 2]].norm(dim=-1).mean() * 100
            roots.append(float(root))
            moved = abs(means[-1][name] - float(base[name].mean())) / std[name]
            other = max(abs(means[-1][k] - float(base[k].mean())) / std[k] for k in names if k != name)
            ratio = "" if s == 0 else f"{other / max(moved, 1e-9):.2f}"
            rows.append([name, f"{s:.1f}", *(f"{means[-1][k]:.3f}" for k in names), f"{float(root):.1f}", ratio])
        seq = [m[name] for m in means]
        mono = all(b > a for a, b in zip(seq, seq[1:]))
        path = "" if name == "root_speed" else (
            f"; root path within {ROOT_PATH_BOUND_CM:g} cm: {'yes' if max(roots) < ROOT_PATH_BOUND_CM else 'NO'}")
        blocks.append((rows, [f"   {name}: classifier accuracy {dirs[name].accuracy:.2f}; score monotonic in "
                              f"strength: {'yes' if mono else 'NO'}{path}"]))
    table = iter(format_table(["edit", "strength", *names, "root cm", "max other/edited"],
                              [r for rows, _ in blocks for r in rows]))
    lines.append(next(table))
    for rows, verdict in blocks:
        lines += [next(table) for _ in rows] + verdict
    classifier = style_classifier_of(prior.metadata)
    styles = [k for k in sorted(dirs) if k.startswith("style:")]
    if classifier is not None and styles:
        lines += style_rows(prior, classifier, [dirs[k] for k in styles], w, scorer, base_x, base, std, base_root)
    return lines


def style_rows(prior, classifier: StyleClassifier, dirs: list[Direction], w: Tensor, scorer: AttributeScorer,
               base_x: Tensor, base: dict[str, Tensor], std: dict[str, float], base_root: Tensor) -> list[str]:
    """Mean probability the style classifier gives each style's edited samples, by strength;
    the computed attributes and the root path are reported, not bounded (a style may move
    them: old people walk slower). ``base_x``, ``base`` and ``base_root``: the unedited
    samples of ``w``, their attribute scores and root paths."""
    base_probs = classifier.probabilities(base_x)
    heldout = ("not measured (no held-out labelled clips)" if classifier.heldout_accuracy is None else
               f"{classifier.heldout_accuracy:.2f} on {classifier.heldout_windows} windows of held-out clips")
    lines = [f"   styles: probability the style classifier gives the style (linear softmax over window "
             f"descriptors, {len(classifier.styles)} styles, fitted on {classifier.train_windows} training "
             f"windows; accuracy {heldout}), by strength " + " ".join(f"{s:g}" for s in STRENGTHS)]
    rows = []
    n_mono = 0
    for d in dirs:
        style = d.name.removeprefix("style:")
        probs, ratio, root = [], 0.0, 0.0
        p0 = base_probs[:, classifier.styles.index(style)]
        for s in STRENGTHS:
            x = prior.generate(edit_codes(w, d, s))
            p = classifier.score(x, style)
            probs.append(float(p.mean()))
            if s != 0:
                sc = scorer(x)
                moved = abs(probs[-1] - float(p0.mean())) / max(float(p0.std()), 1e-12)
                other = max(abs(float(v.mean() - base[k].mean())) / std[k] for k, v in sc.items())
                ratio = max(ratio, other / max(moved, 1e-9))
                root = max(root, float((scorer.root_path(x) - base_root)[..., [0, 2]].norm(dim=-1).mean() * 100))
        mono = all(b > a for a, b in zip(probs, probs[1:]))
        n_mono += mono
        rows.append([style, f"{d.accuracy:.2f}", *(f"{p:.3f}" for p in probs), "yes" if mono else "NO",
                     f"{ratio:.2f}", f"{root:.1f}"])
    lines += format_table(["style", "W acc", *(f"{s:g}" for s in STRENGTHS), "monotonic", "max other/edited",
                           "root cm"], rows)
    lines.append(f"   styles whose probability rises monotonically with strength: {n_mono}/{len(dirs)}")
    return lines


def model_positions(prior, out: Motion, clean: Motion) -> tuple[np.ndarray, np.ndarray]:
    """World joint positions of two motions on the prior's joints at its rate, cut to the
    shorter."""
    codec = Codec.of(prior)
    a, b = codec.model_motion(out).positions(), codec.model_motion(clean).positions()
    n = min(len(a), len(b))
    return a[:n], b[:n]


def model_error_mm(prior, out: Motion, clean: Motion, frames: slice = slice(None)) -> float:
    """Mean world joint position error (mm) on the prior's joints, at the prior's rate."""
    a, b = model_positions(prior, out, clean)
    return float(np.linalg.norm(a[frames] - b[frames], axis=-1).mean() * 1000)


def latent_cases(iters: int) -> list[tuple[str, InversionOptions, bool]]:
    """Section 4's latent rows: label, inversion options, whether the MAP solve of the
    filled frames follows (``problems.latent.solve_unseen``). ``complete --method latent``
    runs the second (the encoder, then the solve), ``inbetween --method latent`` the fourth."""
    return [("latent masked encoder", InversionOptions(), False),
            ("latent masked + MAP solve", InversionOptions(), True),
            (f"latent masked + L-BFGS {iters}", InversionOptions(refine_iters=iters), False),
            (f"latent masked + L-BFGS {iters} + MAP solve", InversionOptions(refine_iters=iters), True)]


def tasks(prior, ar_path: Path | None, data: Path, clips: list[str], iters: int, seconds: float = 8.0) -> list[str]:
    """Denoising and in-betweening of held-out clips, latent inversion against the
    autoregressive MAP tasks (``problems.denoise``, ``problems.inbetween``)."""
    ar = load_prior(ar_path) if ar_path is not None and ar_path.exists() else None
    try:
        from problems.denoise import Denoise
        from problems.inbetween import Inbetween, complete
    except ImportError as e:
        Denoise = Inbetween = complete = None  # noqa: N806
        ar_note = f"autoregressive tasks unavailable ({e})"
    else:
        ar_note = "" if ar is not None else "no autoregressive prior for this data"
    rows: dict[str, list[tuple[float, float]]] = {}

    def record(name: str, err: float, secs: float) -> None:
        rows.setdefault(name, []).append((err, secs))

    for i, name in enumerate(clips):
        full = bvh.load(data / name)
        clean = full[: int(seconds * full.fps)]
        noisy = capture_noise(clean, 0.05, 0.01, seed=i)
        record("denoise: noisy input", model_error_mm(prior, noisy, clean), 0.0)
        for label, opts in (("latent encoder", InversionOptions()),
                            (f"latent + L-BFGS {iters}", InversionOptions(refine_iters=iters))):
            t0 = time.perf_counter()
            out = reconstruct(prior, noisy, opts).motion
            record(f"denoise: {label}", model_error_mm(prior, out, clean), time.perf_counter() - t0)
        if Denoise is not None and ar is not None:
            t0 = time.perf_counter()
            out = Denoise(noisy, ar).solve().motion
            record(f"denoise: AR task default ({ar_path.name})", model_error_mm(prior, out, clean), time.perf_counter() - t0)
        prefix, upto = int(clean.fps), int(2 * clean.fps)  # the second after the first
        if clean.num_frames >= upto:
            after = slice(int(prefix * prior.spec.fps / clean.fps), int(upto * prior.spec.fps / clean.fps))
            for label, opts, solved in latent_cases(iters):
                t0 = time.perf_counter()
                task = LatentTask.completion(clean, prefix, upto, prior, opts)
                out = (task if solved else replace(task, map_options=None)).solve().motion
                record(f"complete 1 s after 1 s: {label}", model_error_mm(prior, out, clean[:upto], after),
                       time.perf_counter() - t0)
            if Inbetween is not None and ar is not None:
                t0 = time.perf_counter()
                out = complete(clean[:prefix], prefix, upto, ar).solve().motion
                record(f"complete 1 s after 1 s: AR task default ({ar_path.name})",
                       model_error_mm(prior, out, clean[:upto], after), time.perf_counter() - t0)
        a, b = int(2.0 * clean.fps), int(3.5 * clean.fps)  # 1.5 s gap
        if clean.num_frames < b + int(0.5 * clean.fps):
            continue  # too short to keep half a second after the gap
        seen = np.ones(clean.num_frames, bool)
        seen[a:b] = False
        gap = slice(int(a * prior.spec.fps / clean.fps), int(b * prior.spec.fps / clean.fps))
        for label, opts, solved in latent_cases(iters):
            t0 = time.perf_counter()
            task = LatentTask(clean, prior, [(0, a), (b, clean.num_frames)], opts)
            out = (task if solved else replace(task, map_options=None)).solve().motion
            record(f"in-between 1.5 s: {label}", model_error_mm(prior, out, clean, gap), time.perf_counter() - t0)
        if Inbetween is not None and ar is not None:
            t0 = time.perf_counter()
            out = Inbetween(clean, [(0, a), (b, clean.num_frames)], ar).solve().motion
            record(f"in-between 1.5 s: AR task default ({ar_path.name})", model_error_mm(prior, out, clean, gap),
                   time.perf_counter() - t0)
    lines = [f"4. Tasks on the first {seconds:g} s of each held-out clip ({len(clips)} clips): mean joint position "
             "error against the clean clip (mm; in-betweening: on the gap frames; completion: on the second "
             "completed) and seconds per clip",
             "   denoising input: rotations turned by N(0, 0.05 rad) per axis, root moved by N(0, 1 cm)",
             "   (in-betweening only on clips of at least 4 s; complete --method latent runs the masked encoder and "
             f"the MAP solve, inbetween --method latent the masked encoder, L-BFGS {iters} and the MAP solve)"]
    lines += format_table(["task and method", "clips", "error mm", "s/clip"],
                          [[name, len(v), f"{np.mean([e for e, _ in v]):.1f}", f"{np.mean([t for _, t in v]):.2f}"]
                           for name, v in rows.items()])
    if ar_note:
        lines.append(f"   {ar_note}")
    return lines


def round_trip_errors(prior, out: Motion, clean: Motion) -> tuple[float, float]:
    """Local joint error (mm: root-relative positions, world axes) and mean horizontal
    root path distance (cm) of ``out`` from ``clean``, at the prior's rate on its joints."""
    a, b = (torch.from_numpy(p) for p in model_positions(prior, out, clean))
    return local_position_error_mm(a, b), float((a[:, 0, [0, 2]] - b[:, 0, [0, 2]]).norm(dim=-1).mean() * 100)


def user_measures(prior, motion: Motion) -> dict[str, float]:
    """Mean hip height and right-hand height (cm) and mean root speed (m/s) of a motion,
    at the prior's rate on its joints."""
    sk = prior.skeleton
    hand = A.right_arm(sk.names, sk.parents)[2]
    pos = Codec.of(prior).model_motion(motion).positions()
    speed = np.linalg.norm(np.diff(pos[:, 0, [0, 2]], axis=0), axis=-1).mean() * prior.spec.fps
    return {"hip_cm": float(pos[:, 0, 1].mean() * 100), "hand_cm": float(pos[:, hand, 1].mean() * 100),
            "speed": float(speed)}


def spread(clips: list[str], n: int) -> list[str]:
    """``n`` clips spread evenly over the list."""
    return [clips[int(i * len(clips) / n)] for i in range(min(n, len(clips)))]


#: Held-out clips shorter than this are left out of section 5.
MIN_USER_SECONDS = 4.0


def user_clips(data: Path, clips: list[str], seconds: float) -> tuple[list[str], list[Motion]]:
    """Section 5's clips: 4 held-out clips of at least ``MIN_USER_SECONDS`` spread over the
    list (their names), cut to their first ``seconds``."""
    names = spread([c for c in clips if bvh.load(data / c).duration >= MIN_USER_SECONDS], 4)
    return names, [m[: int(seconds * m.fps)] for m in (bvh.load(data / name) for name in names)]


def user_figures(prior, ar_path: Path | None, data: Path, clips: list[str], iters: int,
                 seconds: float = 10.0) -> list[str]:
    """Section 5 (see the module docstring)."""
    from problems.denoise import Denoise

    ar = load_prior(ar_path) if ar_path is not None and ar_path.exists() else None
    clips, motions = user_clips(data, clips, seconds)
    rows: dict[str, list[list[float]]] = {}

    def record(name: str, *values: float) -> None:
        rows.setdefault(name, []).append(list(values))

    for i, clip in enumerate(motions):
        for label, opts in (("encoder", InversionOptions()), (f"encoder + L-BFGS {iters}",
                                                               InversionOptions(refine_iters=iters))):
            t0 = time.perf_counter()
            out = reconstruct(prior, clip, opts).motion
            record(f"round trip: {label}", *round_trip_errors(prior, out, clip), time.perf_counter() - t0)
        for level in (0.01, 0.03, 0.05):
            noisy, _ = position_noise(clip, level, seed=i)
            tag = f"denoise {level * 100:g} cm"
            record(f"{tag}: noisy input", model_error_mm(prior, noisy, clip) / 10, 0.0)
            for label, opts in (("latent inversion", InversionOptions()), (f"latent inversion + L-BFGS {iters}",
                                                                            InversionOptions(refine_iters=iters))):
                t0 = time.perf_counter()
                out = LatentTask(noisy, prior, options=opts).solve().motion
                record(f"{tag}: {label}", model_error_mm(prior, out, clip) / 10, time.perf_counter() - t0)
            cases = [("denoise --method latent (MAP, latent prior term)", lambda: Denoise(noisy, LatentDensity(prior)))]
            if ar is not None:
                cases += [("default denoiser (MAP, autoregressive prior)", lambda: Denoise(noisy, ar)),
                          ("the same MAP without a prior term", lambda: Denoise(noisy, ar, prior_weight=0.0))]
            for label, task in cases:
                t0 = time.perf_counter()
                out = task().solve().motion
                record(f"{tag}: {label}", model_error_mm(prior, out, clip) / 10, time.perf_counter() - t0)
    lines = [f"5. What a user sees: the first {seconds:g} s of {len(motions)} held-out clips "
             f"({', '.join(clips)}); {iters} L-BFGS iterations where refined"]
    lines += format_table(["case", "clips", "local mm / error cm", "root path cm", "s/clip"],
                          [[k, len(v), f"{np.mean([r[0] for r in v]):.1f}",
                            f"{np.mean([r[1] for r in v]):.1f}" if len(v[0]) == 3 else "",
                            f"{np.mean([r[-1] for r in v]):.2f}"] for k, v in rows.items()])
    return lines + edit_figures(prior, motions)


def variation_section(prior, ar_path: Path | None, data: Path, clips: list[str], iters: int,
                      seconds: float = 10.0) -> list[str]:
    """Section 6 (see the module docstring)."""
    from priors.score import score_motion

    ar = load_prior(ar_path) if ar_path is not None and ar_path.exists() else None
    names, motions = user_clips(data, clips, seconds)
    lines = [f"6. Variations, interpolation and fusion: the first {seconds:g} s of {', '.join(names)}"]
    return lines + variation_figures(prior, ar, motions, score_motion) + fuse_figures(prior, motions, iters)


def edit_figures(prior, motions: list[Motion]) -> list[str]:
    """Edits at +-2 of each attribute on held-out clips, in user terms."""
    dirs = directions_of(prior)
    classifier = style_classifier_of(prior.metadata)
    codec = Codec.of(prior)
    measure = {"crouch": ("hip_cm", "mean hip height, cm"), "gral": ("hand_cm", "mean right-hand height, cm"),
               "root_speed": ("speed", "mean root speed, percent of -2's")}
    rows = []
    style_moves = []
    for name, d in sorted(dirs.items()):
        if name not in measure and not name.startswith("style:"):
            continue
        moves, paths, slides = [], [], []
        for clip in motions:
            ends = {s: latent_edit(prior, clip, name, s) for s in (-2.0, 0.0, 2.0)}
            pos = {s: codec.model_motion(r.motion).positions() for s, r in ends.items()}
            paths.append(max(float(np.linalg.norm(pos[s][:, 0, [0, 2]] - pos[0.0][:, 0, [0, 2]], axis=-1).mean() * 100)
                             for s in (-2.0, 2.0)))
            slide = {s: float(foot_skating(torch.from_numpy(p), prior.spec.fps, prior.spec.contact_indices()))
                     for s, p in pos.items()}
            slides.append(max(slide[-2.0], slide[2.0]) / max(slide[0.0], 1e-9))
            if name in measure:
                key = measure[name][0]
                lo, hi = (user_measures(prior, ends[s].motion)[key] for s in (-2.0, 2.0))
                moves.append(100 * (hi - lo) / max(abs(lo), 1e-9) if key == "speed" else hi - lo)
            else:
                style = name.split(":", 1)[1]
                lo, hi = (float(classifier.score(clip_windows([codec.features(ends[s].model_motion)], prior.window,
                                                              prior.window // 2), style).mean())
                          if classifier is not None else float("nan") for s in (-2.0, 2.0))
                moves.append(hi - lo)
        if name in measure:
            rows.append([name, goal_of(prior, name).unit, measure[name][1], f"{np.mean(moves):+.1f}",
                         f"{np.mean(paths):.1f}", f"{np.mean(slides):.2f}"])
        else:
            style_moves.append((name, float(np.mean(moves)), float(np.mean(paths)), float(np.mean(slides))))
    lines = ["   edits, strength +2 against -2 (change of the measure; root path: mean horizontal distance from "
             "strength 0, cm, the larger of +-2; feet: foot skating at +-2, the larger, over strength 0's)"]
    lines += format_table(["edit", "unit", "measure", "change", "root path cm", "feet"], rows)
    if style_moves:
        lines.append(f"   styles ({goal_of(prior, style_moves[0][0]).unit}): probability the style classifier gives "
                     "the style, +2 minus -2 (mean over clips): " +
                     ", ".join(f"{n.split(':')[1]} {m:+.2f}" for n, m, *_ in style_moves))
        lines.append(f"   styles raising the probability by at least 0.3: {sum(m >= 0.3 for _, m, *_ in style_moves)} "
                     f"of {len(style_moves)}; root path change up to {max(p for _, _, p, _ in style_moves):.1f} cm; "
                     f"feet sliding {min(f for *_, f in style_moves):.2f}-{max(f for *_, f in style_moves):.2f} "
                     "times strength 0's")
    return lines


def heading_local(prior, motion: Motion) -> np.ndarray:
    """Joint positions (T, J, 3) relative to the root, turned into the root's heading frame,
    on the prior's joints at its rate: a pose that does not depend on where the body stands
    or faces (fuse turns B to continue A's heading)."""
    model = Codec.of(prior).model_motion(motion)
    pos = torch.from_numpy(model.positions())
    yaw = heading_angle(torch.from_numpy(model.rotations[:, 0]))
    turn = R.yaw_quat(-yaw)[:, None].expand(-1, pos.shape[1], -1)
    return R.quat_apply(turn, pos - pos[:, :1]).numpy()


#: Model frames either side of fuse's seam left out of the part errors (its ``blend_frames``).
FUSE_BAND = 8


def fastest(p: np.ndarray) -> np.ndarray:
    """Cm per frame of the fastest joint of positions ``p (T, J, 3)``, per frame step."""
    return np.linalg.norm(np.diff(p, axis=0), axis=-1).max(-1) * 100


def fuse_figures(prior, motions: list[Motion], iters: int) -> list[str]:
    """``fuse`` of each held-out clip's first half with the next clip's second half: how
    far each part is from its input away from the seam (heading-frame local joint error),
    and how fast the fastest joint moves across the seam against the inputs' own fastest
    frames (the plain concatenation jumps there)."""
    rows = []
    for label, opts in (("encoder", InversionOptions()), (f"encoder + L-BFGS {iters}", InversionOptions(refine_iters=iters))):
        err_a, err_b, seam, jump, fast = [], [], [], [], []
        for a, b in zip(motions, motions[1:] + motions[:1]):
            at = min(a.num_frames, b.num_frames) // 2
            res = fuse(prior, a, b, at, opts)
            t, tb = res.metrics["seam_frame_model"], int(round(at * prior.spec.fps / b.fps))
            out, la, lb = (heading_local(prior, m) for m in (res.motion, a, b))
            n = min(len(out) - t, len(lb) - tb)
            err_a.append(np.linalg.norm(out[:t - FUSE_BAND] - la[:t - FUSE_BAND], axis=-1).mean() * 100)
            err_b.append(np.linalg.norm(out[t + FUSE_BAND:t + n] - lb[tb + FUSE_BAND:tb + n], axis=-1).mean() * 100)

            seam.append(fastest(out)[t - FUSE_BAND:t + FUSE_BAND].max())
            jump.append(fastest(np.concatenate((la[:t], lb[tb:tb + 1])))[-1])
            fast.append(np.percentile(np.concatenate((fastest(la), fastest(lb))), 99))
        rows.append([label, f"{np.mean(err_a):.1f} / {np.mean(err_b):.1f}", f"{max(err_a + err_b):.1f}",
                     f"{np.mean(seam):.1f} (max {max(seam):.1f})", f"{np.mean(fast):.1f}", f"{np.mean(jump):.1f}"])
    lines = [f"   fuse (each clip's first half, the next clip's second half; parts judged {FUSE_BAND} frames "
             "away from the seam; heading-frame local joint error; fastest joint in cm per frame)"]
    return lines + format_table(["fuse", "part A / B cm", "worst part cm", "across the seam",
                                 "inputs' 99th pct", "concatenation's jump"], rows)


def naturalness_row(prior, ar, label: str, outs: list[Motion], score_motion, spread_cm: str = "",
                    change_cm: str = "") -> list[object]:
    """One row of section 6's table: mean NLL per frame under the autoregressive prior,
    mean jerk (m/s^3) and foot skating (cm/s) at the prior's rate, over ``outs``."""
    fps, cidx = prior.spec.fps, prior.spec.contact_indices()
    models = [Codec.of(prior).model_motion(m) for m in outs]
    pos = [torch.from_numpy(m.positions()) for m in models]
    nll, in_range = "-", "-"
    if ar is not None:
        nll = f"{np.mean([score_motion(ar, m).nll_per_frame for m in outs]):.1f}"
        known, good, total = naturalness.HumanRange.of_prior(ar), 0, 0
        for m, p in zip(models, pos):
            seconds = naturalness.per_second(ar, m, estimate_ground(p.numpy(), cidx))
            flagged = naturalness.flagged_seconds(naturalness.out_of_range(seconds, known))
            good, total = good + len(seconds) - len(flagged), total + len(seconds)
        in_range = f"{good} of {total}"
    return [label, spread_cm, nll, f"{np.mean([float(jerk(p, fps)) for p in pos]):.0f}",
            f"{np.mean([float(foot_skating(p, fps, cidx)) * 100 for p in pos]):.1f}", in_range, change_cm]


def variation_figures(prior, ar, motions: list[Motion], score_motion) -> list[str]:
    """``vary`` and ``interpolate`` on held-out clips, as generated and settled under the
    autoregressive prior (``problems.latent.settled``) beside the inputs."""
    codec = Codec.of(prior)

    def pairwise_cm(outs: list[Motion]) -> float:
        pos = [codec.model_motion(m).positions() for m in outs]
        pos = [p - p[:, :1] * [1, 0, 1] for p in pos]  # root-relative horizontally, as a viewer compares poses
        return float(np.mean([np.linalg.norm(a - b, axis=-1).mean() * 100
                              for i, a in enumerate(pos) for b in pos[i + 1:]]))

    made, settled_ = {"vary": [], "middle": []}, {"vary": [], "middle": []}
    dist, dist_settled, ends = [], [], []
    for clip in motions:
        outs = vary(prior, clip, 4, 0.3)
        made["vary"] += [r.motion for r in outs]
        dist.append(pairwise_cm([r.motion for r in outs]))
        if ar is not None:
            calm = [settled(r, ar) for r in outs]
            settled_["vary"] += calm
            dist_settled.append(pairwise_cm([r.motion for r in calm]))
    for a, b in zip(motions, motions[1:] + motions[:1]):
        res = interpolate(prior, a, b, 3)
        ends.append((round_trip_errors(prior, res[0].motion, a)[0], round_trip_errors(prior, res[-1].motion, b)[0]))
        made["middle"].append(res[1].motion)
        if ar is not None:
            settled_["middle"].append(settled(res[1], ar))
    change = {k: f"{np.mean([r.metrics['settle_change_cm'] for r in v]):.1f}" for k, v in settled_.items() if v}
    rows = [naturalness_row(prior, ar, "inputs", motions, score_motion),
            naturalness_row(prior, ar, "vary, generated", made["vary"], score_motion, f"{np.mean(dist):.1f}")]
    if ar is not None:
        rows.append(naturalness_row(prior, ar, "vary, settled", [r.motion for r in settled_["vary"]], score_motion,
                                    f"{np.mean(dist_settled):.1f}", change["vary"]))
    rows.append(naturalness_row(prior, ar, "interpolate middle, generated", made["middle"], score_motion))
    if ar is not None:
        rows.append(naturalness_row(prior, ar, "interpolate middle, settled", [r.motion for r in settled_["middle"]],
                                    score_motion, "", change["middle"]))
    lines = ["   vary (4 variations per clip, sigma 0.3) and the middle of interpolate (3 steps, each clip to the next), "
             "as generated and settled under the autoregressive prior; pairwise: mean joint distance between "
             "variations; NLL per frame under the autoregressive prior; jerk m/s^3; skating cm/s; seconds in range: "
             "seconds with every naturalness measure within the held-out data's range (motionopt.naturalness); "
             "change: settled from generated"]
    lines += format_table(["motion", "pairwise cm", "NLL", "jerk", "skating", "seconds in range", "change cm"], rows)
    lines.append(f"   interpolate (3 steps): local joint error of the first end to A {np.mean([e[0] for e in ends]):.1f} "
                 f"mm, of the last end to B {np.mean([e[1] for e in ends]):.1f} mm")
    return lines


SECTIONS = (1, 2, 3, 4, 5, 6)


def bench(path: Path, iters: int, reg: float, sections: tuple[int, ...] = SECTIONS) -> list[str]:
    """The report of one checkpoint: the numbered sections of the module docstring."""
    prior = load_prior(path)
    meta = prior.metadata
    data = data_folder(meta)
    t0 = time.perf_counter()
    train = build_dataset(data, spec=prior.spec, val=[], include=meta["train_clips"]).train
    train_x = [prior.normalizer.normalize(x).float() for x in train.values()]  # as held_out_clips normalises
    val_x = [c.x for c in held_out_clips(prior, data)]
    val_r = clip_windows(val_x, prior.window, prior.window // 2)
    lines = [f"== {path.name}: {meta.get('licence')}",
             f"   {len(meta['train_clips'])} training clips, validation clips {', '.join(meta['validation_clips'])}; "
             f"{meta.get('steps_done')} steps in {meta.get('training_minutes', 0):.0f} min; "
             f"{sum(v.numel() for v in read_checkpoint(path)['state_dict'].values())} parameters, "
             f"{path.stat().st_size / 1e6:.1f} MB; data prepared in {time.perf_counter() - t0:.0f} s"]
    ar = CHECKPOINT_DIR / AR_FOR[path.name] if path.name in AR_FOR else None
    if 1 in sections:
        lines += reconstruction(prior, val_r, iters, reg)
    if 2 in sections:
        lines += sampling(prior, ar, clip_windows(train_x, prior.window, 8), clip_windows(val_x, prior.window, 8))
    if 3 in sections:
        lines += semantic(prior)
    if 4 in sections:
        lines += tasks(prior, ar, data, meta["validation_clips"], iters)
    if 5 in sections:
        lines += user_figures(prior, ar, data, meta["validation_clips"], iters)
    if 6 in sections:
        lines += variation_section(prior, ar, data, meta["validation_clips"], iters)
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("checkpoints", nargs="*", type=Path)
    ap.add_argument("--refine-iters", type=int, default=200)
    ap.add_argument("--reg", type=float, default=InversionOptions().reg_weight)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--sections", type=int, nargs="+", choices=SECTIONS, default=SECTIONS,
                    help="the sections to run (default all); a partial run writes no results file")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    paths = args.checkpoints or shipped_checkpoints(SHIPPED_LATENT)
    if not paths:
        raise SystemExit("no latent checkpoint: train one with `motionopt train-latent` (see README)")
    out = []
    for p in paths:
        t0 = time.perf_counter()
        block = bench(p, args.refine_iters, args.reg, tuple(args.sections))
        block += [f"   (benchmark of {p.name}: {time.perf_counter() - t0:.0f} s, torch threads "
                  f"{torch.get_num_threads()})", ""]
        print("\n".join(block), flush=True)
        out += block
        if not args.checkpoints and tuple(args.sections) == SECTIONS:  # written after each checkpoint, so a long run leaves its figures as it goes
            RESULTS.parent.mkdir(parents=True, exist_ok=True)
            RESULTS.write_text("\n".join(out) + "\n")


if __name__ == "__main__":
    main()
