"""Shared test settings: one torch thread (CI machines have 2 cores and several test
processes may share them; one thread is faster there and results are repeatable)."""
import torch

torch.set_num_threads(1)
