"""Tracking as a user runs it: few particles at a blind start, the overlay of an uncalibrated run."""

import math

import numpy as np
import pytest
import torch

from clips import Clip
from torch_atr.config import load_config
from torch_atr.data.synthetic import SceneConfig, SyntheticSequence
from torch_atr.tracking import Tracker, TrackerConfig
from torch_atr.tracking.blob import BOX_COLUMNS, BlobTracker
from torch_atr.tracking.initialise import best_hypotheses, hypothesis_shares


@pytest.mark.parametrize("lonely", [False, True])
def test_fewer_particles_than_hypotheses_go_to_each_class_best_first_against_brute_force(lonely):
    """n particles over the K best hypotheses: equal shares in best_hypotheses' order when n >= K;
    fewer than K go to the classes' best hypotheses (best first), then their second best, ... The
    reference sorts by (rank within the class, score), one hypothesis at a time. ``lonely``: class 2
    has a single finite hypothesis, so it keeps fewer than count // C and the classes' shares of the
    best differ in size (a rank counted from a class's end, not its start, then differs by class)."""
    g = torch.Generator().manual_seed(0)
    log_lik = torch.randn(300, generator=g, dtype=torch.float64)
    log_lik[:40] = -math.inf
    classes = torch.randint(0, 6, (300,), generator=g)
    if lonely:
        finite_2 = ((classes == 2) & log_lik.isfinite()).nonzero()[:, 0]
        log_lik[finite_2[1:]] = -math.inf
    best = best_hypotheses(log_lik, 16, classes)
    K = best.shape[0]
    per_class = torch.bincount(classes[best], minlength=6).tolist()
    assert per_class == ([2, 2, 1, 2, 2, 2] if lonely else [2] * 6)
    rank = {i: sum(classes[j] == classes[i] for j in best.tolist()[:p]) for p, i in enumerate(best.tolist())}
    ordered = sorted(best.tolist(), key=lambda i: (rank[i], -float(log_lik[i])))
    for n in range(1, 2 * K + 3):
        got = hypothesis_shares(best, log_lik, n, classes).tolist()
        assert got == (ordered[:n] if n < K else [best.tolist()[j % K] for j in range(n)]), n
    assert hypothesis_shares(best, log_lik, 1, classes).tolist() == [int(log_lik.argmax())]
    plain = best_hypotheses(log_lik, 16)  # without classes: the best first already
    assert hypothesis_shares(plain, log_lik, 3).tolist() == plain[:3].tolist()


def test_a_single_particle_starts_blind_on_the_best_hypothesis(model):
    """One particle used to start on the first class's best hypothesis (a tank's), whatever the blob:
    the SUV's first frame was a pickup. It starts on the best of all, an SUV."""
    seq = SyntheticSequence("isuzu_rodeo", SceneConfig(frames=1))
    tracker = Tracker(model, seq.camera, load_config(TrackerConfig, None, ["filter.particles=1"]), seed=0)
    row = tracker.run(seq, progress=False).rows[0]
    assert row["lost"] == 0 and row["class"] == "suv"


def test_an_uncalibrated_rows_silhouette_lies_on_its_own_frames_blob(model):
    """tracker.silhouette_at(row) places a row's estimate after its frame (the overlay video did so
    after the run); the blob tracker laid every one on the last frame's blob, 34 px from its own at
    the start of this SUV driving by. Each row now holds its blob's box (the mask's, by NumPy) and its silhouette is the
    one the run placed on that frame."""
    seq = Clip(SyntheticSequence("isuzu_rodeo", SceneConfig(frames=20)), camera=False)
    tracker = BlobTracker(model, load_config(TrackerConfig, None, ["filter.particles=100"]), seed=0)
    result = tracker.run(seq, progress=False)
    assert len(result.snapshots) == 6
    for shot in result.snapshots:
        row = result.rows[shot["frame"]]
        rows, cols = np.nonzero(shot["mask"])
        assert [row[k] for k in BOX_COLUMNS] == [cols.min(), rows.min(), cols.max(), rows.max()]
        placed = tracker.silhouette_at(row, shot["mask"].shape).numpy()
        assert placed.any() and np.array_equal(placed, shot["silhouette"])
