"""torchakvf.pipeline.batches: the one batch planner (corpus runs, evaluation, bench)."""
from __future__ import annotations

from helpers.faketask import FakeTask
from helpers.meshfiles import write_off

from torchakvf import shapes
from torchakvf.pipeline.runner import run_corpus


def test_batches_go_to_the_workers_heaviest_first():
    from types import SimpleNamespace as NS

    from torchakvf.pipeline.batches import heaviest_first
    p = {i: NS(mesh_id=i) for i in range(5)}
    faces = {0: 100, 1: 5000, 2: 300, 3: 300, 4: 1000}
    ks = {0: 1, 1: 0, 2: 9, 3: 9, 4: 2}
    batches = [[p[0]], [p[1], p[4]], [p[2]], [p[3]]]
    # work: 200, 5000 + 3000 = 8000, 3000, 3000 (ties keep their order)
    order = heaviest_first(batches, faces, ks)
    assert [[q.mesh_id for q in b] for b in order] == [[1, 4], [2], [3], [0]]
    assert sorted(map(id, order)) == sorted(map(id, batches))       # the same batches, moved


def test_batches_of_several_workers_balance_the_work_under_the_budget():
    from types import SimpleNamespace as NS

    from torchakvf.pipeline.batches import balanced_batches, make_batches, mesh_work
    p = [NS(mesh_id=i) for i in range(6)]
    faces = {i: 100 for i in range(6)}
    ks = {0: 0, 1: 1, 2: 2, 3: 3, 4: 4, 5: 9}
    work = mesh_work(faces, ks)
    assert work == {0: 100, 1: 200, 2: 300, 3: 400, 4: 500, 5: 1000}
    ids = lambda bs: [[q.mesh_id for q in b] for b in bs]             # noqa: E731
    # one worker: consecutive plans, 300 faces per batch (work 600 and 1900)
    assert ids(make_batches(p, faces, 300)) == [[0, 1, 2], [3, 4, 5]]
    assert ids(make_batches(p, faces, 300, workers=1, work_of=work)) == [[0, 1, 2], [3, 4, 5]]
    # two workers, two batches: heaviest first into the lightest batch with room (ties: the
    # first): 5 -> A 1000, 4 -> B 500, 3 -> B 900, 2 -> B 1200 (full), 1 -> A 1200, 0 -> A 1300
    assert ids(make_batches(p, faces, 300, workers=2, work_of=work)) == [[0, 1, 5], [2, 3, 4]]
    # no budget to speak of: still one batch per worker, not one batch
    assert ids(make_batches(p, faces, 10 ** 6, workers=2, work_of=work)) == [[0, 1, 5], [2, 3, 4]]
    # a mesh that fits in no batch opens one: 2 batches of <= 200 faces cannot hold 6 meshes
    # (5 -> A, 4 -> B, 3 -> B full, 2 -> A full, 1 -> C, 0 -> C)
    assert ids(balanced_batches(p, faces, 200, work, 2)) == [[2, 5], [3, 4], [0, 1]]
    # more workers than meshes: one mesh per batch
    assert sorted(ids(make_batches(p, faces, 10 ** 6, workers=8, work_of=work))) == [[i] for i in range(6)]
    # several batches per worker (the CPU's finer share): 2 workers x 2 = 4 batches, heaviest
    # first into the lightest: 5 -> A 1000, 4 -> B 500, 3 -> C 400, 2 -> D 300, 1 -> D (300,
    # the lightest) 500, 0 -> C (400) 500
    assert ids(make_batches(p, faces, 10 ** 6, workers=2, work_of=work, per_worker=2)) == [[5], [4], [0, 3], [1, 2]]
    # never more batches than meshes
    assert (sorted(ids(make_batches(p, faces, 10 ** 6, workers=2, work_of=work, per_worker=4)))
            == [[i] for i in range(6)])
    # None: one mesh per batch, whatever the budget; heaviest first (each into an empty batch)
    assert (ids(make_batches(p, faces, 10 ** 6, workers=2, work_of=work, per_worker=None))
            == [[i] for i in (5, 4, 3, 2, 1, 0)])
    # ... but one worker keeps the budget's consecutive batches (nothing to share)
    assert ids(make_batches(p, faces, 10 ** 6, workers=1, work_of=work, per_worker=None)) == [list(range(6))]


def test_cpu_batches_are_one_mesh_each_with_several_workers():
    import torch

    from torchakvf.pipeline.batches import batches_per_worker
    assert batches_per_worker("cpu") is batches_per_worker(torch.device("cpu")) is None
    assert batches_per_worker("cuda") == batches_per_worker("cuda:1") == 1


def test_batches_sorted_by_size_under_face_budget(tmp_path):
    sizes = {"s1": 1, "s2": 2, "s3": 3}   # icosphere levels: 80, 320, 1280 faces
    paths = []
    for name, lvl in sizes.items():
        s = shapes.icosphere(lvl)
        paths.append(write_off(tmp_path / "in" / f"{name}.off", s.vertices, s.faces))
    task = FakeTask()
    run_corpus(list(reversed(paths)), tmp_path / "out", task, batch_faces=500)
    assert task.batches == [["s1", "s2"], ["s3"]]      # the 1280-face mesh alone, over budget


def test_batched_batches_fit_the_memory_budget(monkeypatch):
    """On the batched path a batch's padded arrays fit the budget: on CUDA a share of the
    simulated free memory, on the CPU the configured bytes; the face budget only caps it."""
    import torch

    from torchakvf.pipeline import batches as B

    per_mesh = B.solve_bytes(int(1.5 * 4000) + 1, 1, 36)
    assert B.solve_bytes(6001, 3, 36) == 3 * per_mesh            # linear in the meshes
    assert B.solve_bytes(12001, 1, 36) > 1.9 * per_mesh          # and about in the padded edges
    monkeypatch.setattr(torch.cuda, "mem_get_info", lambda device=None: (int(10.5 * per_mesh / B.FREE_MEMORY_SHARE),
                                                                        80 * 2**30))
    assert B.batch_bytes_budget("cuda") == int(10.5 * per_mesh)
    assert B.batch_bytes_budget("cpu") == B.DEFAULT_CPU_BATCH_BYTES
    assert B.batch_bytes_budget("cuda", given=123) == 123
    assert B.default_batch_faces("cpu", 4000, batched=True) == B.BATCHED_BATCH_FACES
    assert B.default_batch_faces("cuda", 4000) == B.BATCHED_BATCH_FACES
    assert B.default_batch_faces("cpu", 4000) < B.BATCHED_BATCH_FACES

    class P:
        def __init__(self, i):
            self.mesh_id = i

    plans = [P(i) for i in range(25)]
    faces = {i: 4000 for i in range(25)}
    memory = B.MemoryBudget(B.batch_bytes_budget("cuda"), 36)
    got = B.prediction_batches(plans, faces, {i: 1 for i in range(25)}, B.BATCHED_BATCH_FACES,
                               coarse_faces=4000, workers=1, device="cuda", memory=memory)
    assert sorted(len(b) for b in got) == [5, 10, 10]
    assert all(memory.fits([4000] * len(b)) for b in got)
    faces[24] = 40_000                      # padded to the largest: it goes alone
    got = B.cut_by_bytes(plans, lambda p: faces[p.mesh_id], memory)
    assert [len(b) for b in got] == [10, 10, 4, 1]
