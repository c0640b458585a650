"""Naturalness per second: each second of a task's output measured against the range of
held-out mocap its prior's checkpoint carries, and warnings that name the seconds."""
from __future__ import annotations

import numpy as np
import pytest

from motionopt import bvh
from motionopt.features import to_model_motion
from motionopt.naturalness import HumanRange, flagged_seconds, out_of_range, per_second, spans, summary_line, warnings_for
from priors.checkpoint import CHECKPOINT_DIR, load_prior_cached

from clips import BANDAI_30, DATA, shared_excerpt


@pytest.fixture(scope="module")
def prior():
    return load_prior_cached(CHECKPOINT_DIR / "bandai-locomotion-ccnet.pt")


def test_the_shipped_priors_carry_the_range_of_their_held_out_data(prior):
    known = HumanRange.of_prior(prior)
    assert known is not None and 0.5 < known.hip_low < known.hip_high < 1.2
    assert 0 < known.lowest_high < 0.1 and 0 < known.skating_high < 2
    assert HumanRange.of_prior(load_prior_cached(CHECKPOINT_DIR / "cmu-ccnet.pt")) is not None


def test_a_held_out_walk_stays_in_range_and_a_lifted_one_is_named_by_its_seconds(prior):
    walk = to_model_motion(shared_excerpt("bandai/dataset-1_walk_normal_001.bvh", 0, 180), prior.spec)
    ground = float(walk.positions()[:, prior.spec.contact_indices(), 1].min())
    known = HumanRange.of_prior(prior)
    seconds = per_second(prior, walk, ground)
    assert [s["second"] for s in seconds] == [0, 1, 2, 3, 4, 5]
    bad = out_of_range(seconds, known)
    assert not bad["hips"] and not bad["floating"] and len(bad["skating"]) <= 1
    # seconds 2 and 3 lifted 20 cm: the hips and the feet leave the range there, and only there
    lifted = walk.root.copy()
    lifted[60:120, 1] += 0.2
    seconds = per_second(prior, walk.with_frames(walk.rotations, lifted, None), ground)
    bad = out_of_range(seconds, known)
    assert bad["hips"] == [2.0, 3.0] and bad["floating"] == [2.0, 3.0]
    assert flagged_seconds(bad) == sorted({s for found in bad.values() for s in found})
    assert {2.0, 3.0} <= set(flagged_seconds(bad)) and flagged_seconds(out_of_range(seconds, None)) == []
    text = warnings_for(seconds, known)
    assert any(w.startswith("output: hip height leaves") and w.endswith("in seconds 2-3 (of seconds 0-5)")
               for w in text)
    assert "4 of 6 seconds within" in summary_line(seconds, known)


def test_without_a_range_the_seconds_are_measured_but_not_judged(prior):
    walk = to_model_motion(bvh.load(DATA / BANDAI_30), prior.spec)
    seconds = per_second(prior, walk, 0.0)
    assert len(seconds) == int(round(walk.num_frames / prior.spec.fps))
    assert all(np.isfinite(s["hip_height_m"]) for s in seconds)
    assert out_of_range(seconds, None) == {} and warnings_for(seconds, None) == []
    assert "carries no data range" in summary_line(seconds, None)


def test_spans_join_consecutive_seconds():
    assert spans([0.0, 1.0, 2.0, 3.0, 7.0, 9.0, 10.0]) == "0-3, 7, 9-10"
    assert spans([]) == ""
