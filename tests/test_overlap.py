"""torchakvf.pipeline.overlap: the host/device overlap of a batched run. Every item is finished
once, with what its cut returned, whether the host stages run in this process or in host
workers; a failing solve is bisected; a failed prepare or cut fails its item alone; a
programming error ends the run; the stage seconds add up as documented."""
from __future__ import annotations

import pytest
from helpers.overlapjobs import ToyJob

from torchakvf.pipeline.overlap import OverlapTimes, run_overlapped

BATCHES = [[1, 2, 3], [4, 5], [6]]


def _run(job, workers, batches=BATCHES):
    done = {}

    def finish(item, prep, error, result):
        assert item not in done
        done[item] = (None if prep is None else prep.mesh, error, result)

    times = run_overlapped(batches, job, workers, "cpu", finish)
    return done, times


@pytest.mark.parametrize("workers", [1, 2])
def test_every_item_finished_once_with_its_cut(workers):
    done, times = _run(ToyJob(), workers)
    assert done == {i: (i, None, 10 * i + 1) for i in range(1, 7)}
    assert times.workers == workers - 1 and times.batches == 3 and times.bisections == 0
    # the toy's own seconds: 0.5 per prepare, 1 + 2 per solve, 0.25 per cut
    assert times.prepare == pytest.approx(3.0) and times.stages["akvf"] == pytest.approx(3.0)
    assert times.stages["rounds"] == pytest.approx(6.0) and times.host["cut"] == pytest.approx(1.5)


def test_a_failing_solve_is_bisected_until_the_culprit_fails_alone():
    job = ToyJob(poison={2})
    done, times = _run(job, 1)
    assert done[2][1] == "RuntimeError: factorization failed" and done[2][0] == 2
    assert {i: done[i][2] for i in (1, 3, 4, 5, 6)} == {1: 11, 3: 31, 4: 41, 5: 51, 6: 61}
    # [1, 2, 3] -> [1, 2] + [3] -> [1] + [2]
    assert job.solved[:4] == [[1, 2, 3], [1, 2], [1], [2]] and times.bisections == 2
    assert times.stages["akvf"] == pytest.approx(4.0)   # only the solves that succeeded count


def test_a_failed_prepare_or_cut_fails_its_item_alone():
    done, _ = _run(ToyJob(bad_prepare={4}, bad_cut={6}), 2)
    assert done[4] == (None, "ValueError: cannot read 4", None)
    assert done[6] == (6, "ValueError: cannot cut 6", None)
    assert all(done[i][2] == 10 * i + 1 for i in (1, 2, 3, 5))


def test_a_programming_error_ends_the_run():
    with pytest.raises(TypeError, match="a bug"):
        _run(ToyJob(bug={5}), 1)


def test_record_adds_up():
    t = OverlapTimes(workers=1, batches=2, wall=10.0, stages={"pack": 1.0, "akvf": 3.0}, wait_prepare=0.5,
                     wait_cut=1.5, prepare=4.0, host={"cut": 2.0, "write": 1.0})
    rec = t.record()
    assert rec["solve"] == 4.0 and rec["other"] == 10.0 - 4.0 - 2.0 and rec["host_share"] == 0.2
    assert {"pack", "akvf", "cut", "write", "prepare", "wait_cut", "workers"} <= set(rec)
    assert "batched: 2 batches" in t.line() and "host share 20%" in t.line()
