"""Forward kinematics against a plain numpy reference, and its gradients."""
from __future__ import annotations


import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from motionopt import bvh
from motionopt.kinematics import fk
from clips import DATA, CMU_120, BANDAI_30



def numpy_fk(parents, quats, root, local_t):
    """World positions and rotation matrices by 4x4 homogeneous transforms, frame by frame."""
    t, j = quats.shape[:2]
    mats = Rotation.from_quat(quats.reshape(-1, 4), scalar_first=True).as_matrix().reshape(t, j, 3, 3)
    pos = np.zeros((t, j, 3))
    grot = np.zeros((t, j, 3, 3))
    for f in range(t):
        world = [None] * j
        for k in range(j):
            local = np.eye(4)
            local[:3, :3] = mats[f, k]
            local[:3, 3] = root[f] if parents[k] == -1 else local_t[f, k]
            world[k] = local if parents[k] == -1 else world[parents[k]] @ local
            pos[f, k] = world[k][:3, 3]
            grot[f, k] = world[k][:3, :3]
    return pos, grot


@pytest.mark.parametrize("name", [CMU_120, BANDAI_30])
def test_fk_matches_numpy_reference_on_real_clips(name):
    m = bvh.load(DATA / name)
    local_t = m.local_translations()
    ref_pos, ref_rot = numpy_fk(m.skeleton.parents, m.rotations, m.root, local_t)
    pos, grot = fk(m.skeleton.parents, torch.from_numpy(m.rotations), torch.from_numpy(m.root),
                   torch.from_numpy(m.skeleton.offsets),
                   None if m.translations is None else torch.from_numpy(m.translations),
                   return_global_rotations=True)
    assert np.abs(pos.numpy() - ref_pos).max() < 1e-6  # metres
    got_rot = Rotation.from_quat(grot.reshape(-1, 4).numpy(), scalar_first=True).as_matrix()
    np.testing.assert_allclose(got_rot, ref_rot.reshape(-1, 3, 3), atol=1e-9)
    np.testing.assert_allclose(m.positions(), ref_pos, atol=1e-9)


def random_skeleton(n_joints: int, seed: int):
    rng = np.random.default_rng(seed)
    parents = np.array([-1] + [int(rng.integers(0, j)) for j in range(1, n_joints)])
    offsets = rng.normal(0, 0.3, size=(n_joints, 3))
    return parents, offsets


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-9), (torch.float32, 1e-5)])
def test_fk_random_skeleton_matches_reference(dtype, tol):
    parents, offsets = random_skeleton(12, seed=1)
    rng = np.random.default_rng(2)
    quats = Rotation.random(10 * 12, random_state=3).as_quat(scalar_first=True).reshape(10, 12, 4)
    root = rng.normal(size=(10, 3))
    ref, _ = numpy_fk(parents, quats, root, np.broadcast_to(offsets, (10, 12, 3)))
    got = fk(parents, torch.as_tensor(quats, dtype=dtype), torch.as_tensor(root, dtype=dtype),
             torch.as_tensor(offsets, dtype=dtype))
    assert got.dtype == dtype
    assert np.abs(got.double().numpy() - ref).max() < tol


def test_fk_batched_equals_unbatched():
    parents, offsets = random_skeleton(6, seed=4)
    quats = torch.as_tensor(Rotation.random(3 * 5 * 6, random_state=5).as_quat(scalar_first=True)).reshape(3, 5, 6, 4)
    root = torch.randn(3, 5, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(6))
    off = torch.as_tensor(offsets)
    batched = fk(parents, quats, root, off)
    single = torch.stack([torch.stack([fk(parents, quats[b, t], root[b, t], off) for t in range(5)]) for b in range(3)])
    torch.testing.assert_close(batched, single, rtol=0, atol=1e-12)


def test_fk_gradcheck_float64():
    parents, offsets = random_skeleton(4, seed=7)
    rng = np.random.default_rng(8)
    quats = torch.as_tensor(Rotation.random(3 * 4, random_state=9).as_quat(scalar_first=True).reshape(3, 4, 4),
                            dtype=torch.float64).requires_grad_(True)
    root = torch.as_tensor(rng.normal(size=(3, 3))).requires_grad_(True)
    off = torch.as_tensor(offsets).requires_grad_(True)
    trans = torch.as_tensor(rng.normal(size=(3, 4, 3))).requires_grad_(True)

    def positions_and_rotations(q, r, o):
        pos, grot = fk(parents, q, r, o, return_global_rotations=True)
        return pos, grot

    assert torch.autograd.gradcheck(positions_and_rotations, (quats, root, off))
    assert torch.autograd.gradcheck(lambda q, r, t: fk(parents, q, r, off.detach(), t), (quats, root, trans))


def test_fk_refuses_parents_out_of_order():
    rot = torch.zeros(3, 4, dtype=torch.float64)
    rot[:, 0] = 1
    with pytest.raises(ValueError, match="before their children"):
        fk([-1, 2, 0], rot, torch.zeros(3, dtype=torch.float64), torch.zeros(3, 3, dtype=torch.float64))
    with pytest.raises(ValueError, match="parents for"):
        fk([-1, 0], rot, torch.zeros(3, dtype=torch.float64), torch.zeros(3, 3, dtype=torch.float64))
