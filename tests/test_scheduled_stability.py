"""Rate-bounded stability certificates of scheduled loops (lpvflow.validate.scheduled_stability)."""

import numpy as np
import pytest

from lpvflow.errors import ModelError
from lpvflow.validate.scheduled_stability import (
    largest_certified_rate,
    scheduled_stability,
    triangular_blocks,
)

BASE = np.array([[0.7, 2.0], [0.0, 0.7]])  # stable, far from normal
RANGE = np.linspace(0.0, np.pi / 2, 9)


def rotation(p: float) -> np.ndarray:
    return np.array([[np.cos(p), -np.sin(p)], [np.sin(p), np.cos(p)]])


def rotating(p: float) -> np.ndarray:
    """R(p) BASE R(p)ᵀ: the same stable eigenvalues at every p, eigenvectors turning with p."""
    return rotation(p) @ BASE @ rotation(p).T


def test_fast_switching_destabilizes_what_slow_motion_keeps_stable():
    # frozen-stable everywhere, but jumping between the ends of the range every sample diverges
    assert max(np.max(np.abs(np.linalg.eigvals(rotating(p)))) for p in np.linspace(0, np.pi / 2, 50)) < 1
    assert np.max(np.abs(np.linalg.eigvals(rotating(np.pi / 2) @ rotating(0.0)))) > 1
    slow = scheduled_stability(rotating, RANGE, 0.01)
    assert slow.certified, slow.reason
    assert slow.blocks[0].margin > 0 and slow.blocks[0].t > 0
    fast = scheduled_stability(rotating, RANGE, None)
    assert not fast.certified and "not certified at ν = any" in fast.reason


def test_ladder_stops_at_the_first_failure():
    ladder = largest_certified_rate(rotating, RANGE, [0.01, 0.05, None])
    assert ladder.largest == 0.05
    assert [r.certified for r in ladder.results] == [True, True, False]
    assert largest_certified_rate(rotating, RANGE, [None]).largest == 0.0  # nothing certified
    assert ladder.seconds > 0


def test_certificate_rejects_a_perturbed_system():
    result = scheduled_stability(rotating, RANGE, 0.01)
    assert result.margin(rotating)[0] > 0
    # the same storage for a loop pushed outside the unit circle (eigenvalues 1.01) cannot decrease
    margin, _ = result.margin(lambda p: rotating(p) + 0.31 * np.eye(2))
    assert margin < 0


def test_random_stable_scheduled_systems_are_certified_at_a_slow_rate():
    rng = np.random.default_rng(3)
    cases = 0
    while cases < 3:
        A0, A1 = (0.6 * M / np.max(np.abs(np.linalg.eigvals(M))) for M in rng.normal(size=(2, 3, 3)))
        frozen = max(np.max(np.abs(np.linalg.eigvals((1 - p) * A0 + p * A1))) for p in np.linspace(0, 1, 41))
        if frozen > 0.9:
            continue
        cases += 1
        result = scheduled_stability(lambda p, A0=A0, A1=A1: (1 - p) * A0 + p * A1, [0.0, 0.5, 1.0], 0.001)
        assert result.certified, result.reason


def test_block_triangular_split():
    # states 0, 2: the rotating system; states 1, 3: an autonomous stable pair driving it
    auto = np.array([[0.5, 0.1], [0.0, 0.6]])

    def loop(p: float) -> np.ndarray:
        A = np.zeros((4, 4))
        A[np.ix_([1, 3], [1, 3])] = auto
        A[np.ix_([0, 2], [0, 2])] = rotating(p)
        A[0, 1] = 0.3  # the autonomous block drives the rotating one
        return A

    blocks = triangular_blocks([loop(p) for p in RANGE])
    # 3 drives 1 (auto[0, 1]), 1 drives the rotating pair: each block comes after those driving it
    assert [sorted(b.tolist()) for b in blocks] == [[3], [1], [0, 2]]
    slow, fast = scheduled_stability(loop, RANGE, 0.01), scheduled_stability(loop, RANGE, None)
    assert slow.certified and len(slow.blocks) == 3
    assert not fast.certified and "block of 2 states" in fast.reason


def test_the_first_failing_block_ends_the_attempt_at_that_rate():
    """The rotating pair drives a stable scalar state: at any jump the pair is not certified, and the block
    after it (certifiable) is not tried; at a slow rate both are certified."""
    def loop(p: float) -> np.ndarray:
        A = np.zeros((3, 3))
        A[np.ix_([0, 2], [0, 2])] = rotating(p)
        A[1, 1], A[1, 0] = 0.5, 0.3
        return A

    assert [sorted(b.tolist()) for b in triangular_blocks([loop(p) for p in RANGE])] == [[0, 2], [1]]
    slow, fast = scheduled_stability(loop, RANGE, 0.01), scheduled_stability(loop, RANGE, None)
    assert slow.certified and len(slow.blocks) == 2
    assert not fast.certified and len(fast.blocks) == 1 and fast.blocks[0].margin <= 0
    assert fast.reason.startswith("not certified at ν = any per sample: block of 2 states (margin ")
    assert fast.reason.endswith("; 1 later block(s) not tried")


def test_bad_input_is_one_line():
    for call in (lambda: scheduled_stability(rotating, RANGE, -0.1),
                 lambda: scheduled_stability(rotating, RANGE[::-1], 0.1),
                 lambda: largest_certified_rate(rotating, RANGE, [0.1, 0.01]),
                 lambda: largest_certified_rate(rotating, RANGE, [None, 0.01]),
                 lambda: scheduled_stability(lambda p: 1.01 * np.eye(2), RANGE, 0.1)):
        with pytest.raises(ModelError) as info:
            call()
        assert "\n" not in str(info.value)
