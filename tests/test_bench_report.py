"""torchakvf.bench.report: the bench's report.md."""
from __future__ import annotations

from torchakvf.bench.report import budget_lines


def test_budget_report_says_when_every_budget_ran_one_mesh_per_batch():
    """The CPU planner never groups meshes with several workers: a sweep whose every budget
    ran as many batches as meshes says that its ratios compare one plan with itself."""
    def sweep(batches):
        rows = [dict(budget=b, batches=n, seconds=1.0, one_at_a_time_seconds=1.0, ratio=1.0, comparable=True,
                     cpu_ratio=1.0, stage_ratios={"akvf": 1.0, "segment": 1.0}, seconds_each=[1.0])
                for b, n in zip((4000, 80000), batches)]
        return dict(meshes=3, faces=30, mesh_ids=[1, 2, 3], baseline_run="one_at_a_time", rows=rows)

    note = "Every budget ran one mesh per batch"
    assert note in "\n".join(budget_lines(sweep([3, 3])))
    assert note not in "\n".join(budget_lines(sweep([3, 1])))
