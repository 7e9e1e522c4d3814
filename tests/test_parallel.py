"""map_batches: worker processes give what the inline loop gives; failures are isolated."""
from __future__ import annotations

import os

import pytest

from torchakvf.pipeline.parallel import default_workers, map_batches


def square_or_fail(batch, offset):
    """Module-level (pickled by name to spawned workers). Fails on any item < 0."""
    if any(x < 0 for x in batch):
        raise ValueError(f"negative item in {batch}")
    return [x * x + offset for x in batch], os.getpid()


def _collect(outcomes):
    done, split, failed = {}, [], {}
    for o in outcomes:
        if o.split:
            split.append(tuple(o.batch))
        elif o.error is not None:
            failed[tuple(o.batch)] = o.error
        else:
            done[tuple(o.batch)] = o.result[0]
    return done, split, failed


@pytest.mark.parametrize("workers", [1, 2])
def test_results_failures_and_retries(workers):
    batches = [[1, 2], [3, -4, 5], [6]]
    done, split, failed = _collect(map_batches(batches, square_or_fail, (10,), workers=workers))
    assert done == {(1, 2): [11, 14], (3,): [19], (5,): [35], (6,): [46]}
    assert split == [(3, -4, 5), (3, -4)]
    assert list(failed) == [(-4,)] and "ValueError: negative item" in failed[(-4,)]


def test_workers_are_other_processes_and_the_environment_is_restored():
    before = {v: os.environ.get(v) for v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    pids = {o.result[1] for o in map_batches([[1], [2], [3], [4]], square_or_fail, (0,), workers=2)}
    assert os.getpid() not in pids and 1 <= len(pids) <= 2
    assert {v: os.environ.get(v) for v in before} == before


def test_default_workers():
    assert default_workers("cuda") == 1
    assert 1 <= default_workers("cpu") <= 8


def index_bug(batch):
    """Module-level: a programming error on item 13 (not a bad input)."""
    if 13 in batch:
        return [][1]
    return batch


@pytest.mark.parametrize("workers", [1, 2])
def test_programming_errors_are_not_bad_items(workers):
    """An IndexError from our code ends the map with its traceback; it is not split and
    retried, nor reported as one item's failure."""
    seen = []
    with pytest.raises(IndexError):
        for o in map_batches([[1], [13, 2], [3]], index_bug, workers=workers):
            seen.append(o)
    assert not any(o.split or o.error for o in seen)


def test_fatal_errors_end_the_map():
    with pytest.raises(ValueError, match="negative"):
        list(map_batches([[1], [-1, 2]], square_or_fail, (0,), fatal=(ValueError,)))


@pytest.mark.parametrize("workers", [1, 2])
def test_a_failed_batch_is_bisected_and_nothing_finished_is_lost(workers):
    """16 items, two bad: each bad item ends alone; a good item is run at most
    1 + log2(16) = 5 times (never 16 single runs), and every good item's result comes back once."""
    batch = list(range(1, 17))
    batch[5], batch[12] = -6, -13
    outcomes = list(map_batches([batch], square_or_fail, (0,), workers=workers))
    runs = {x: sum(x in o.batch for o in outcomes) for x in batch}
    done, split, failed = _collect(outcomes)
    assert sorted(failed) == [(-13,), (-6,)]
    results = sorted(v for r in done.values() for v in r)
    assert results == sorted(x * x for x in batch if x > 0)
    assert max(runs.values()) <= 5 and runs[-6] == runs[-13] == 5
    assert sum(len(b) == 1 for b in done) <= 2     # good items alone only beside a culprit
    assert len(outcomes) <= 1 + 2 * 2 * 4          # at most 2 log2(16) runs per culprit
