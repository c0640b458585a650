"""Where the solver's windows go and what each is conditioned on.

``free_window_starts`` lays windows over the free frames; ``WindowWalk`` opens them in
order, each after the frames before it as the sequence holds them at that moment (the
prior's context, the last solved frames and the root state before them). The driver
walks the sequence it is solving; ``diagnostics.energies_at`` walks a given one.
"""
from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from ..features import RootStart, advance
from ..objective import MAPObjective
from .window import BASIS_SIZE, Window

#: Solved frames decoded with each window (their positions give its first velocities
#: and accelerations); the root state is advanced up to the first of them.
LEAD_FRAMES = 2


def free_window_starts(free: np.ndarray, window: int, overlap: int) -> list[int]:
    """Start frames of the windows that cover every free frame, stepping by window - overlap;
    past a stretch of fixed frames the next window starts at the next free frame."""
    idx = np.nonzero(free)[0]
    if len(idx) == 0:
        return []
    starts, s = [], int(idx[0])
    step = window - overlap
    while True:
        starts.append(s)
        if s + window > idx[-1]:
            break
        s += step
        nxt = idx[idx >= s]
        s = int(nxt[0]) if len(nxt) and nxt[0] > s + window else s
    return starts


class WindowWalk:
    """The windows of one solve, opened in order of ``starts``.

    Keeps the root state up to the frame before the current window's lead frames, so
    each ``open`` advances it over the frames since the last one only (the sequence
    before a window must not change after the window opens)."""

    def __init__(self, objective: MAPObjective, free: np.ndarray, start: RootStart, window: int, overlap: int,
                 basis: int = BASIS_SIZE):
        self.objective = objective
        self.basis = basis
        self.free = free
        self.window = window
        self.starts = free_window_starts(free, window, overlap)
        self._committed = 0          # the root state is known up to this frame
        self._root_state = start     # the state before frame `_committed`
        self._contacts = torch.full((len(free), objective.spec.num_contacts), float("nan"))

    def open(self, x: Tensor, s: int) -> Window:
        """The window from frame ``s`` of the sequence ``x (N, D)``, conditioned on its frames before ``s``."""
        obj = self.objective
        norm, spec = obj.prior.normalizer, obj.spec
        e = min(s + self.window, len(x))
        lead_from = max(s - LEAD_FRAMES, 0)
        if lead_from > self._committed:
            self._root_state = advance(self._root_state, norm.denormalize(x[self._committed:lead_from].double()), spec)
            self._committed = lead_from
        lead_raw = norm.denormalize(x[self._committed:s].double()).float()
        context = x[max(0, s - obj.prior.receptive_field):s]
        return Window(obj, x[s:e], np.arange(s, e), self.free[s:e], context, lead_raw, self._root_state, self.basis)

    def rebase(self, win: Window) -> None:
        """``win.rebase``, keeping the contact weights of frames an earlier window fixed,
        and recording the weights of the others for the windows after it."""
        rows = torch.from_numpy(win.frames)
        win.rebase(self._contacts[rows])
        self._contacts[rows] = win.contacts.to(self._contacts)
