"""``torchakvf bench --budgets``: batched against one mesh at a time at several face budgets, on
the same meshes in the same run (see :mod:`torchakvf.bench.run`)."""
from __future__ import annotations

import logging

from ..errors import TorchAKVFError

log = logging.getLogger("torchakvf.bench")

__all__ = ["check_budgets", "budget_sweep"]


def check_budgets(budgets) -> list:
    """Budgets as a sorted list of distinct ints >= 1 (a comma string or a sequence; None: [])."""
    if budgets is None:
        return []
    if isinstance(budgets, str):
        budgets = [b for b in budgets.split(",") if b.strip()]
    out = []
    for b in budgets:
        try:
            v = int(str(b).strip())
        except ValueError:
            raise TorchAKVFError(f"--budgets must be integers >= 1 separated by commas, got {b!r}") from None
        if v < 1:
            raise TorchAKVFError(f"--budgets must be integers >= 1 separated by commas, got {v}")
        out.append(v)
    return sorted(set(out))


def budget_sweep(meshes, baseline_every: int, budgets: list, runs: dict, notes: list, run_one,
                 repeats: int = 1, checkpoint=lambda: None) -> dict:
    """Batched against one at a time at each face budget, on the same meshes (see the module
    notes). Adds the runs ``budget_B`` (and ``one_at_a_time`` if the baselines did not run it)
    to ``runs``; returns the report's ``budget_sweep``.

    repeats : the one-at-a-time run and every budget's run are repeated, interleaved (one,
        B1, B2, ..., one, B1, ...), and each is timed by its fastest repetition (the least
        disturbed by other load); ``runs`` keeps the first repetition.
    run_one : ``run_one(name, meshes, batch_faces) -> run dict`` (a torchakvf run)
    checkpoint : called after each run (writes the partial report)"""
    subset = meshes[::baseline_every] if baseline_every else list(meshes)
    everything = len(subset) == len(meshes)
    default = runs["batched"]["batch_faces"]
    # budget 1 is the one-at-a-time run itself
    rows_budgets = sorted((set(budgets) | ({default} if everything else set())) - {1})
    seconds = {b: [] for b in [1] + rows_budgets}        # 1: the one-at-a-time run
    cpu = {b: [] for b in seconds}
    stage_s = {b: [] for b in seconds}
    failed = {b: set() for b in seconds}
    names = {1: "one_at_a_time"}
    for rep in range(int(repeats)):
        for budget in [1] + rows_budgets:
            if rep == 0 and budget == 1 and "one_at_a_time" in runs:
                run = runs["one_at_a_time"]       # the baselines' own run, on these meshes
            elif rep == 0 and budget == default and everything:
                names[budget], run = "batched", runs["batched"]   # no rerun of run (a)
            else:
                name = names.setdefault(budget, "one_at_a_time" if budget == 1 else f"budget_{budget}")
                run = run_one(name if rep == 0 else f"{name} (repeat {rep + 1})", subset, budget)
                if rep == 0:
                    runs[name] = run
                checkpoint()
            seconds[budget].append(run["wall_seconds"])
            cpu[budget].append(run.get("cpu_seconds"))
            stage_s[budget].append(run["stage_seconds"])
            failed[budget] |= set(run["failed"])
    one_s = min(seconds[1])
    sweep = {"mesh_ids": [m.mesh_id for m in subset], "meshes": len(subset),
             "faces": sum(m.faces for m in subset), "baseline_run": "one_at_a_time",
             "repeats": int(repeats),
             "ratio": ("one_at_a_time seconds / budget_B seconds (>= 1: batching at least as fast); "
                       "each the fastest of its repeats"),
             "cpu_ratio": ("the same with CPU seconds (this process and its workers): what "
                           "other processes' load does not inflate"),
             "one_at_a_time_seconds_each": seconds[1], "one_at_a_time_cpu_seconds_each": cpu[1],
             "rows": []}
    for budget in rows_budgets:
        name = names[budget]
        comparable = failed[budget] == failed[1]
        if not comparable:
            notes.append(f"run {name} failed on other meshes than one_at_a_time: its ratio is not comparable")
        sec = min(seconds[budget])
        row = {"budget": budget, "run": name, "batches": runs[name]["batches"], "seconds": sec,
               "seconds_each": seconds[budget], "one_at_a_time_seconds": one_s,
               "ratio": one_s / sec if sec > 0 else None, "stage_ratios": {}, "comparable": comparable}
        c1, cb = cpu[1], cpu[budget]
        row["cpu_seconds_each"] = cb
        row["cpu_ratio"] = (min(c1) / min(cb) if None not in c1 + cb and min(cb) > 0 else None)
        for stage in ("akvf", "segment"):
            t = min(x[stage] for x in stage_s[budget])
            row["stage_ratios"][stage] = min(x[stage] for x in stage_s[1]) / t if t > 0 else None
        sweep["rows"].append(row)
        log.info("bench: budget %d: %d batches, %.2f s; one at a time %.2f s: %.2fx (CPU time %.2fx)",
                 budget, row["batches"], sec, one_s, row["ratio"] or 0.0, row["cpu_ratio"] or 0.0)
    return sweep
