"""The batch planner: which meshes share a batch, for the corpus runner, the evaluation and
the bench alike.

A batch is packed into one :class:`~torchakvf.mesh.MeshBatch` and solved together; its face
total stays under a budget (a mesh above the budget is a batch alone). Each mesh's answer
depends on that mesh alone, so the grouping changes no answer, only the time:

* :func:`plan_batches`: corpus runs (``torchakvf segment``, ``features``): sorted by size,
  consecutive meshes cut by the budget.
* :func:`prediction_batches`: evaluation and bench predictions, whose meshes need different
  numbers of k's: sorted by (k's, faces), balanced over several workers, heaviest first.
"""
from __future__ import annotations

from typing import Callable, NamedTuple, Sequence

from ..mesh.coarse import DECIMATE_ABOVE

__all__ = ["DEFAULT_BATCH_FACES", "BATCHED_BATCH_FACES", "default_batch_faces", "MemoryBudget",
           "solve_bytes", "batch_bytes_budget", "cut_by_bytes", "FREE_MEMORY_SHARE", "DEFAULT_CPU_BATCH_BYTES",
           "cut_by_budget", "plan_batches",
           "solved_face_counts", "batches_per_worker", "make_batches", "balanced_batches",
           "mesh_work", "heaviest_first", "prediction_batches"]

#: Default face budget per batch. On the CPU the padded batched work (every mesh iterates
#: until the batch's slowest converges) costs more than it saves, so the budget only groups
#: small meshes (a PSB-size mesh runs about alone); on CUDA batching amortizes kernel
#: launches. See docs/design.md.
DEFAULT_BATCH_FACES = {"cpu": 20_000, "cuda": 1_000_000}


#: Face cap of a batch solved as one (the batched path): the padded arrays' bytes against the
#: device's memory (:class:`MemoryBudget`) size such a batch; this only bounds the host memory
#: of one batch's meshes.
BATCHED_BATCH_FACES = 1_000_000
#: Share of the device's free memory a batch's padded solver arrays (:func:`solve_bytes`) may
#: take: the rest holds the operator, the factor, the allocator's fragmentation and the
#: round's untangling and k-means arrays.
FREE_MEMORY_SHARE = 0.5
#: Bytes of a batch's padded solver arrays on the CPU by default: a batched run there tests the
#: accelerator's path; a few meshes per batch keep batches coming for the host workers.
DEFAULT_CPU_BATCH_BYTES = 256 * 2**20
#: Edges per face of a closed triangle mesh (E = 3F/2); meshes with boundary have a little more.
EDGES_PER_FACE = 1.5


def solve_bytes(edges_max: int, count: int, n: int) -> int:
    """Bytes of a batched solve's padded arrays: ``count`` meshes padded to ``edges_max`` edges,
    n eigenpairs plus the solver's room for spurious modes
    (:data:`~torchakvf.solvers.akvf_solver.SPURIOUS_MARGIN`), as
    :func:`~torchakvf.solvers.lobpcg.working_bytes` counts them from the arrays it allocates."""
    from ..solvers.akvf_solver import SPURIOUS_MARGIN
    from ..solvers.lobpcg import working_bytes

    return working_bytes([int(edges_max)] * int(count), int(n) + SPURIOUS_MARGIN)


def batch_bytes_budget(device, given: int | None = None) -> int:
    """Bytes a batch's padded arrays may take on ``device``: ``given``, else on CUDA
    :data:`FREE_MEMORY_SHARE` of ``torch.cuda.mem_get_info``'s free memory, on the CPU
    :data:`DEFAULT_CPU_BATCH_BYTES`."""
    if given is not None:
        return int(given)
    if str(device).startswith("cuda"):
        import torch

        free, _ = torch.cuda.mem_get_info(torch.device(device))
        return int(FREE_MEMORY_SHARE * free)
    return DEFAULT_CPU_BATCH_BYTES


class MemoryBudget(NamedTuple):
    """A batched solve's memory budget: ``bytes`` for the padded arrays of ``n`` eigenpairs."""

    bytes: int
    n: int

    def fits(self, faces: Sequence[int]) -> bool:
        """Whether meshes of these (solved) face counts fit as one batch."""
        edges = int(EDGES_PER_FACE * max(faces)) + 1
        return solve_bytes(edges, len(faces), self.n) <= self.bytes


def cut_by_bytes(items: Sequence, faces: Callable, memory: MemoryBudget) -> list[list]:
    """Consecutive ``items`` grouped into batches whose padded arrays fit ``memory``
    (``faces(item)``: the faces solved); an item alone above it is a batch alone (the solve
    then says whether it fits). The order is kept."""
    batches: list[list] = []
    cur: list = []
    for it in items:
        if cur and not memory.fits([faces(x) for x in cur] + [faces(it)]):
            batches.append(cur)
            cur = []
        cur.append(it)
    if cur:
        batches.append(cur)
    return batches


def default_batch_faces(device, coarse_faces: int | None = None, batched: bool | None = None) -> int:
    """The face budget of a batch by default: a batch solved as one (``batched``, or by the
    device's default: every device but the CPU) :data:`BATCHED_BATCH_FACES`, its size then set
    by memory (:class:`MemoryBudget`); otherwise :data:`DEFAULT_BATCH_FACES` for the device; on
    the CPU with decimation to about ``coarse_faces`` faces (evaluation, bench), one decimated
    mesh per batch (the cores are used by worker processes instead, and a batch re-solves
    every mesh when one of them needs more eigenpairs)."""
    if batched is None:
        batched = not str(device).startswith("cpu")
    if batched:
        return BATCHED_BATCH_FACES
    if coarse_faces and str(device).startswith("cpu"):
        return int(DECIMATE_ABOVE * coarse_faces)
    kind = str(device).split(":")[0]
    return DEFAULT_BATCH_FACES.get(kind, DEFAULT_BATCH_FACES["cpu"])


def cut_by_budget(items: Sequence, cost: Callable, budget: int) -> list[list]:
    """Consecutive ``items`` grouped into batches of at most ``budget`` (``cost(item)`` each, in
    faces); an item above the budget is a batch alone. The order is kept."""
    batches: list[list] = []
    cur: list = []
    total = 0
    for it in items:
        c = cost(it)
        if cur and total + c > budget:
            batches.append(cur)
            cur, total = [], 0
        cur.append(it)
        total += c
    if cur:
        batches.append(cur)
    return batches


def plan_batches(items: Sequence, batch_faces: int) -> list[list]:
    """A corpus run's batches: ``items`` (with ``.cost``, faces, and ``.key``) sorted by face
    count (then key) and cut into batches under ``batch_faces`` faces."""
    return cut_by_budget(sorted(items, key=lambda it: (it.cost, it.key)), lambda it: it.cost, batch_faces)


def solved_face_counts(faces_of: dict, coarse_faces) -> dict:
    """{mesh id: faces of the mesh the solver sees}: the input's, or about ``coarse_faces`` for
    a mesh that will be decimated (the face budget of a batch counts what is solved)."""
    if not coarse_faces:
        return dict(faces_of)
    return {i: (f if f <= DECIMATE_ABOVE * coarse_faces else int(coarse_faces)) for i, f in faces_of.items()}


def batches_per_worker(device) -> int | None:
    """None on the CPU: one mesh per batch where several workers share the meshes (a CPU batch
    is solved one mesh at a time inside, so its size gains nothing and only sets how finely the
    work is shared; see docs/design.md); 1 elsewhere (on a GPU batching is the gain)."""
    return None if str(device).startswith("cpu") else 1


def make_batches(plans, faces_of: dict, budget: int, *, workers: int = 1, work_of: dict | None = None,
                 per_worker: int | None = 1) -> list:
    """Plans (with ``.mesh_id``) grouped into batches of at most ``budget`` faces (``faces_of``:
    by mesh id); a mesh larger than the budget is a batch alone.

    One worker: consecutive plans (the caller's order groups meshes alike, which keeps the
    batch's padding small). Several workers, with ``work_of`` (estimated work by mesh id):
    batches of equal work instead, at least one per worker, still under the budget, so that no
    worker is left with the meshes of the most k's. With ``per_worker``, at least that many
    batches per worker (where there are meshes enough), for a finer share of the work; None:
    one mesh per batch (:func:`batches_per_worker`)."""
    consecutive = cut_by_budget(plans, lambda p: faces_of[p.mesh_id], budget)
    if workers <= 1 or work_of is None or len(plans) <= 1:
        return consecutive
    wanted = len(plans) if per_worker is None else workers * max(1, int(per_worker))
    count = max(len(consecutive), min(wanted, len(plans)))
    return balanced_batches(plans, faces_of, budget, work_of, count)


def balanced_batches(plans, faces_of: dict, budget: int, work_of: dict, count: int) -> list:
    """``count`` batches (more where the budget needs them) of about equal work: the plans,
    heaviest first, each into the lightest batch it fits in under ``budget`` faces (a new batch
    where it fits in none). Each batch keeps the plans' given order; empty batches are dropped."""
    index = {id(p): i for i, p in enumerate(plans)}
    bins: list = [[] for _ in range(count)]
    work, faces = [0.0] * count, [0] * count
    for p in sorted(plans, key=lambda p: (-work_of[p.mesh_id], index[id(p)])):
        f = faces_of[p.mesh_id]
        fits = [j for j in range(len(bins)) if not bins[j] or faces[j] + f <= budget]
        if not fits:
            bins.append([]), work.append(0.0), faces.append(0)
            fits = [len(bins) - 1]
        j = min(fits, key=lambda j: (work[j], j))
        bins[j].append(p)
        work[j] += work_of[p.mesh_id]
        faces[j] += f
    return [sorted(b, key=lambda p: index[id(p)]) for b in bins if b]


def mesh_work(faces_of: dict, ks_of: dict) -> dict:
    """{mesh id: estimated work}: faces x (1 + k's to segment); the parts are cut on the
    input's faces once per k (``faces_of``: input faces, ``ks_of``: k's still to segment)."""
    return {i: faces_of[i] * (1 + ks_of[i]) for i in ks_of}


def heaviest_first(batches: list, faces_of: dict, ks_of: dict) -> list:
    """The batches in the order to hand them to workers: the most work first (longest
    processing time first, so that no worker finishes a long mesh alone at the end), ties in
    the given order. Work is :func:`mesh_work` summed over a batch's meshes. The batches
    themselves are not changed."""
    per_mesh = mesh_work(faces_of, ks_of)
    work = [sum(per_mesh[p.mesh_id] for p in b) for b in batches]
    return [batches[i] for i in sorted(range(len(batches)), key=lambda i: -work[i])]


def prediction_batches(plans, faces_of: dict, ks_of: dict, budget: int, *, coarse_faces=None,
                       workers: int = 1, device="cpu", memory: MemoryBudget | None = None) -> list:
    """The batches of an evaluation's (or the bench's) predictions, in the order to run them.

    plans : objects with ``.mesh_id``
    faces_of : {mesh id: input faces}; ks_of : {mesh id: number of k's still to segment}
    budget : faces per batch, counted on the meshes as solved (decimated to about
        ``coarse_faces`` faces where they will be)

    Sorted by (k's, faces, id): a batch's meshes then need about the same number of
    segmentation rounds and have similar sizes (little padding); then cut by
    :func:`make_batches` and handed out :func:`heaviest_first`. With ``memory`` (a batched
    solve), each batch is cut further so that its padded arrays fit (:func:`cut_by_bytes`)."""
    order = sorted(plans, key=lambda p: (ks_of[p.mesh_id], faces_of[p.mesh_id], p.mesh_id))
    solved = solved_face_counts(faces_of, coarse_faces)
    batches = make_batches(order, solved, int(budget), workers=int(workers),
                           work_of=mesh_work(faces_of, ks_of), per_worker=batches_per_worker(device))
    if memory is not None:
        batches = [b for batch in batches for b in cut_by_bytes(batch, lambda p: solved[p.mesh_id], memory)]
    return heaviest_first(batches, faces_of, ks_of)
