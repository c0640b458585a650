"""Zero-phase linear smoothers along time, and the choice among them by estimated risk.

Denoising picks, for each joint, the smoother of least Stein unbiased risk estimate
(SURE) for the clip's noise level, from a family of Butterworth low-passes and
Savitzky-Golay filters: no clean signal is needed, and since each is linear the risk
needs only its output and the trace of its matrix. Smoothers act on (T, K) arrays in
O(T): no (T, T) matrix is formed, so hour-long captures cost memory in proportion.
``gaussian_smooth`` smooths torch tensors, batched (degraded training copies, hip sway).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import torch
import torch.nn.functional as Fn
from scipy.ndimage import correlate1d
from scipy.signal import butter, filtfilt, savgol_filter
from threadpoolctl import threadpool_limits

#: Frames at each end of a clip where a smoother's matrix differs from its interior.
_EDGE = 256


def aligned_quaternions(q: np.ndarray) -> np.ndarray:
    """Quaternions (T, J, 4) with signs flipped so consecutive frames agree (q ~ -q): the
    form in which rotations can be smoothed or fitted linearly along time."""
    q = q.copy()
    for t in range(1, len(q)):
        q[t, (q[t] * q[t - 1]).sum(-1) < 0] *= -1
    return q


@dataclass(frozen=True)
class Smoother:
    """A linear, time-invariant (away from the ends) smoother of (T, K) arrays."""

    label: str
    apply: Callable[[np.ndarray], np.ndarray]
    min_frames: int

    def trace(self, n: int) -> float:
        """Trace of its (n, n) matrix (effective degrees of freedom): exact, from a
        matrix of at most ``2 * _EDGE`` frames whose middle diagonal fills the interior."""
        return _trace(self, n)


@lru_cache(maxsize=4096)
def _trace(smoother: Smoother, n: int) -> float:
    m = min(n, 2 * _EDGE)
    s = smoother.apply(np.eye(m))
    return float(np.trace(s) + (n - m) * s[m // 2, m // 2])


def butterworth(cutoff_hz: float, fps: float, order: int = 2) -> Smoother:
    """Zero-phase (forward-backward) Butterworth low-pass; order 2's gentle roll-off suits
    motion spectra, which fade out gradually."""
    b, a = butter(order, min(cutoff_hz / (fps / 2), 0.99))
    pad = 3 * max(len(a), len(b))
    return Smoother(f"Butterworth {cutoff_hz:g} Hz", lambda y: np.ascontiguousarray(filtfilt(b, a, y, axis=0)), pad + 1)


@dataclass(frozen=True)
class _Constant(Smoother):
    """The clip's mean at every frame: its matrix has trace 1 at any length."""

    def trace(self, n: int) -> float:
        return 1.0


def constant() -> Smoother:
    """Every frame replaced by the clip's mean: the smoother for a joint that does not move
    (Bandai's ground joint joint_Root, whose noisy turns would move the whole body)."""
    return _Constant("constant (the clip's mean)", lambda y: np.repeat(y.mean(axis=0, keepdims=True), len(y), axis=0),
                     2)


def savitzky_golay(window: int, order: int) -> Smoother:
    """Local polynomial fit of ``order`` over ``window`` frames (odd); keeps peaks that a
    low-pass of the same smoothing would flatten."""
    return Smoother(f"Savitzky-Golay {window} frames, order {order}",
                    lambda y: savgol_filter(y, window, order, axis=0), window)


@lru_cache(maxsize=16)
def denoising_family(fps: float) -> tuple[Smoother, ...]:
    """Butterworth order 2 at 1-12 Hz, Savitzky-Golay filters of orders 2-5 over 0.15-2 s
    and the constant: the candidates each joint chooses from. The mix beats either kind
    alone on held-out clips at 1-5 cm of noise (bench/tasks.py); the constant wins for a
    joint that does not move. Windows step by 1/15 s (2 frames at 30 fps), so that a 120
    fps clip has as many candidates as a 30 fps one."""
    lows = [butterworth(fc, fps) for fc in np.arange(1.0, 12.01, 0.5)]
    windows = range(max(5, 2 * int(0.075 * fps) + 1), 2 * int(fps) + 2, 2 * max(1, round(fps / 30)))
    fits = [savitzky_golay(w, o) for w in windows for o in (2, 3, 4, 5) if o < w - 1]
    return tuple(lows + fits + [constant()])


def least_risk(y: np.ndarray, sigma: float, family: tuple[Smoother, ...] | list[Smoother]) -> list[Smoother]:
    """For each column group of ``y`` (T, G, K) carrying white noise of std ``sigma``,
    the smoother of least SURE: |y - S y|^2 + 2 sigma^2 K tr(S) (plus a constant); the
    simplest, the constant, wherever its SURE is within one standard error of the least
    (sigma^2 sqrt(2 K T) for noise alone). A joint that never moves, such as Bandai's
    ground joint, otherwise got a 59-frame fit by chance on one held-out file in three,
    whose slow wobble a metre below the body doubled the whole body's jitter."""
    n, groups, k = y.shape
    flat = y.reshape(n, groups * k)
    usable = [s for s in family if n >= s.min_frames]
    if not usable:
        raise ValueError(f"no smoother of the family fits a clip of {n} frames")
    with threadpool_limits(1, user_api="blas"):  # many small fits: BLAS threads only spin
        risks = np.stack([((flat - s.apply(flat)) ** 2).reshape(n, groups, k).sum(axis=(0, 2))
                          + 2 * sigma ** 2 * k * s.trace(n) for s in usable])
    best = risks.argmin(axis=0)
    c = next((i for i, s in enumerate(usable) if isinstance(s, _Constant)), None)
    if c is not None:
        best = np.where(risks[c] <= risks.min(axis=0) + sigma ** 2 * np.sqrt(2 * k * n), c, best)
    return [usable[i] for i in best]


def gaussian_smooth(x: torch.Tensor, sigma: torch.Tensor | float) -> torch.Tensor:
    """``x`` (B, T, K) smoothed along time by a Gaussian of ``sigma`` frames, one for all
    or one per batch entry (B,); the ends are held (replicate padding), out to 3 sigma."""
    B, T, K = x.shape
    sigma = torch.as_tensor(sigma, dtype=x.dtype, device=x.device).expand(B)
    half = int(torch.ceil(3 * sigma.max()))
    t = torch.arange(-half, half + 1, dtype=x.dtype, device=x.device)
    kernel = torch.exp(-0.5 * (t[None] / sigma[:, None]) ** 2)
    kernel = kernel / kernel.sum(-1, keepdim=True)  # (B, 2 half + 1)
    h = Fn.pad(x.transpose(1, 2), (half, half), mode="replicate")  # (B, K, T + 2 half)
    smooth = Fn.conv1d(h.reshape(1, B * K, -1), kernel.repeat_interleave(K, 0)[:, None], groups=B * K)
    return smooth.reshape(B, K, T).transpose(1, 2)


def smoothstep(x: np.ndarray) -> np.ndarray:
    """3x^2 - 2x^3 of ``x`` clipped to [0, 1]: blend weights that leave 0 and reach 1
    with zero slope, so a correction faded in by them adds no jump in velocity."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def local_linear(y: np.ndarray, sigma: float) -> np.ndarray:
    """``y`` (T, K) smoothed by a Gaussian-weighted local line fit (LOESS of degree 1) of
    width ``sigma`` frames. Unlike a low-pass filter it reproduces linear trends exactly,
    up to the clip's ends, so a steady drift is removed whole."""
    r = max(1, int(np.ceil(4 * sigma)))
    offsets = np.arange(-r, r + 1, dtype=float)
    g = np.exp(-0.5 * (offsets / sigma) ** 2)

    def window_sum(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
        return correlate1d(values, weights, axis=0, mode="constant", cval=0.0)

    ones = np.ones((len(y), 1))
    m0, m1, m2 = (window_sum(ones, g * offsets ** k) for k in range(3))
    y0, y1 = window_sum(y, g), window_sum(y, g * offsets)
    det = m0 * m2 - m1 ** 2
    slope = np.where(det > 1e-12, (m0 * y1 - m1 * y0) / np.where(det > 1e-12, det, 1.0), 0.0)
    return (y0 - slope * m1) / m0
