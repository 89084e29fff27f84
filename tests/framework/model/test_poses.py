import numpy as np
import pytest

from rigslim.errors import InputError
from rigslim.model.poses import FrameSplit, Poses, farthest_poses, parse_frames, sample_clip_frames, thin_examples


def test_slice_spec_matches_python():
    assert parse_frames("0:457:45", 457) == list(range(0, 457, 45))
    assert parse_frames("5:457:7", 457) == list(range(5, 457, 7))
    assert parse_frames("1,3,2", 10) == [1, 2, 3]
    assert parse_frames([0, "4:6"], 10) == [0, 4, 5]
    assert parse_frames(":3", 10) == [0, 1, 2]


@pytest.mark.parametrize("spec", ["0:500:5", "12", "a:b", "0:10:0", "", [], "1:2:3:4"])
def test_bad_specs(spec):
    with pytest.raises(InputError):
        parse_frames(spec, 10)


def test_split_drops_overlap():
    s = FrameSplit.from_specs("0:457:45", "5:457:7", 457)
    assert s.dropped == [180]
    assert 180 not in s.test and len(s.test) == 64 and len(s.examples) == 11
    with pytest.raises(InputError, match="every test frame"):
        FrameSplit.from_specs("0:10", "2,3", 10)


def test_poses_select_and_validate():
    T = np.zeros((4, 2, 3, 4))
    p = Poses(T, frames=[10, 11, 12, 13])
    assert list(p.select([12, 10]).frames) == [12, 10]
    with pytest.raises(InputError):
        Poses(np.zeros((4, 2, 3, 3)))
    T[0, 0, 0, 0] = np.inf
    with pytest.raises(InputError):
        Poses(T)


@pytest.mark.parametrize("n", [2, 3, 7, 16, 29, 200])
def test_clip_sampling_alternates_validation_and_test(n):
    """The frames between examples go alternately to validation and test: disjoint, all used, balanced, and
    every test frame has a validation or example frame next to it."""
    ex, val, test = sample_clip_frames([n, 321], 24)[0]
    assert sorted(ex + val + test) == list(range(n)) and len(set(ex + val + test)) == n
    steps = set(np.diff(ex).tolist()) or {3}
    assert ex[0] == 0 and len(steps) == 1 and min(steps) >= 3
    if n == 2:
        assert (ex, val, test) == ([0], [], [1])
        return
    assert 0 <= len(val) - len(test) <= 1
    rest = [f for f in range(n) if f not in set(ex)]
    assert val == rest[0::2] and test == rest[1::2]
    near = set(ex) | set(val)
    assert all(f - 1 in near or f + 1 in near for f in test)


def test_short_clip_has_as_many_validation_as_test_frames():
    # 16 frames, 3 examples (step 6): the first-half rule gave 9 validation and 4 test frames
    ex, val, test = sample_clip_frames([16, 484], 24)[0]
    assert ex == [0, 6, 12] and val == [1, 3, 5, 8, 10, 13, 15] and test == [2, 4, 7, 9, 11, 14]


def _covering_radius(X: np.ndarray, chosen) -> float:
    return float(np.max(np.min(np.linalg.norm(X[:, None] - X[list(chosen)][None], axis=2), axis=1)))


def test_farthest_poses_covers_within_twice_the_best_radius():
    """Gonzalez's bound, against the exact k-centre optimum by enumeration on small inputs."""
    from itertools import combinations

    rng = np.random.default_rng(3)
    for _ in range(20):
        X = rng.normal(size=(9, 4)) * rng.uniform(0.1, 3.0, size=4)
        for k in (1, 2, 3, 4):
            chosen = farthest_poses(X, k)
            assert len(chosen) == k == len(set(chosen)) and chosen[0] == 0 and chosen == sorted(chosen)
            best = min(_covering_radius(X, c) for c in combinations(range(len(X)), k))
            assert _covering_radius(X, chosen) <= 2 * best + 1e-12
    assert farthest_poses(np.array([[0.0], [1.0], [2.0], [10.0], [11.0]]), 2) == [0, 4]
    assert farthest_poses(np.zeros((3, 2)), 5) == [0, 1, 2]


def test_thin_examples_keeps_distinct_motions_and_holds_the_others_out():
    """20 clips in 10 identical pairs (a jump to the left and the same to the right), 30 frames each, 24
    examples: the shares (3 per clip, 60) are thinned to 48; every distinct example pose keeps at least one
    example, a frame dropped from the examples becomes a validation frame, the test frames do not change."""
    sampled = sample_clip_frames([30] * 20, 24)
    assert sum(len(ex) for ex, _, _ in sampled) == 60

    def describe(clip, frames):         # clips 2i and 2i+1 move alike; frames differ within a clip
        return np.array([[clip // 2, f] for f in frames], float)

    thinned = thin_examples(sampled, describe, 48)
    assert sum(len(ex) for ex, _, _ in thinned) == 48
    kept = {(c // 2, f) for c, (ex, _, _) in enumerate(thinned) for f in ex}
    assert kept == {(c // 2, f) for c, (ex, _, _) in enumerate(sampled) for f in ex}   # all 30 distinct poses
    for (ex0, val0, te0), (ex, val, te) in zip(sampled, thinned, strict=True):
        assert te == te0 and sorted(ex + val) == sorted(ex0 + val0) and not set(ex) & set(val)
    assert thin_examples(sampled, describe, 60) == sampled
