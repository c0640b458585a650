"""Dataset building on a tiny folder of the shipped CMU excerpts."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import torch

from motionopt.dataset import Normalizer, build_dataset, default_validation, find_bvh

DATA = Path(__file__).parent / "data"
CMU = sorted(DATA.glob("cmu-*.bvh"))


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    """The CMU excerpts, one per sub-folder as in ../shared/data/cmu."""
    root = tmp_path_factory.mktemp("cmu")
    for path in CMU:
        (root / path.stem.split("-")[1]).mkdir()
        shutil.copy(path, root / path.stem.split("-")[1] / path.name)
    return root


@pytest.fixture(scope="module")
def dataset(folder):
    return build_dataset(folder, val=["salsa/*"])


def test_clips_are_split_by_clip(dataset):
    assert list(dataset.train) == ["martial/cmu-martial-03-step.bvh"]
    assert list(dataset.val) == ["salsa/cmu-salsa-01-steps.bvh"]
    assert not set(dataset.train) & set(dataset.val)


def test_clips_are_resampled_to_the_prior_rate_on_its_joints(dataset):
    assert dataset.spec.fps == 30.0 and len(dataset.spec.joints) == 21
    assert dataset.skeleton.names == dataset.spec.joints
    # 240 frames at 120 fps and 150 frames at 60 fps: 2.0 s and 2.48 s
    assert len(dataset.train["martial/cmu-martial-03-step.bvh"]) == 60
    assert len(dataset.val["salsa/cmu-salsa-01-steps.bvh"]) == 75
    assert dataset.num_train_frames == 60 and dataset.seconds_to_build > 0


def test_frame_rate_overrides_change_the_clip_length(folder):
    ds = build_dataset(folder, val=[], fps_overrides={"salsa/*": 120.0})
    assert len(ds.train["salsa/cmu-salsa-01-steps.bvh"]) == 38  # the same frames read as 1.24 s


def test_normalizer_standardises_training_features(dataset):
    norm = dataset.normalizer
    contacts = dataset.spec.slices()["contacts"]
    x = torch.cat(list(dataset.train.values()))
    z = norm.normalize(x)
    moving = x.std(0) > 1e-3
    moving[contacts] = False
    torch.testing.assert_close(z.mean(0)[moving], torch.zeros(int(moving.sum()), dtype=z.dtype), rtol=0, atol=1e-9)
    torch.testing.assert_close(z.std(0)[moving], torch.ones(int(moving.sum()), dtype=z.dtype), rtol=0, atol=1e-9)
    assert torch.equal(z[:, contacts], x[:, contacts])  # labels stay 0/1
    torch.testing.assert_close(norm.denormalize(z), x)
    assert (norm.std >= 1e-3).all()  # constant features do not blow up
    refit = Normalizer.fit(list(dataset.train.values()), dataset.spec)
    torch.testing.assert_close(refit.mean, norm.mean)


def test_windows_overlap_and_are_normalised(dataset):
    w = dataset.windows("train", length=20, stride=10)
    assert w.shape == (5, 20, dataset.spec.dim) and w.dtype == torch.float32
    x = dataset.normalizer.normalize(dataset.train["martial/cmu-martial-03-step.bvh"]).float()
    torch.testing.assert_close(w[1], x[10:30])
    assert dataset.windows("val", length=75, stride=1).shape == (1, 75, dataset.spec.dim)
    with pytest.raises(ValueError, match="at least 100 frames"):
        dataset.windows("val", length=100, stride=1)


def test_default_validation_holds_out_the_last_clip_of_each_folder(folder):
    files = find_bvh(folder)
    assert default_validation(files, folder) == ["martial/cmu-martial-03-step.bvh", "salsa/cmu-salsa-01-steps.bvh"]
    flat = [Path(f"/x/{i:02d}.bvh") for i in range(25)]
    assert default_validation(flat, Path("/x")) == ["09.bvh", "19.bvh"]


def test_bad_folders_are_refused(folder, tmp_path):
    with pytest.raises(FileNotFoundError, match="no .bvh files"):
        build_dataset(tmp_path)
    with pytest.raises(ValueError, match="no training clips"):
        build_dataset(folder, val=["*"])
    with pytest.raises(ValueError, match="cmu-martial-03-step.bvh: .* does not match"):
        build_dataset(DATA)  # two skeletons in one folder: CMU clips do not fit the spec of the Bandai one
