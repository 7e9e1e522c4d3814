"""The reports of ``torchakvf bench``: report.json, report.md and the stdout summary."""
from __future__ import annotations

import datetime as _dt
import json
import math
import os
import platform
from pathlib import Path

from ..io.outputs import atomic_write_bytes
from .runs import STAGES

__all__ = ["REPORT_JSON", "REPORT_MD", "report_header", "write_bench_reports", "summary_lines", "budget_lines"]

REPORT_JSON = "report.json"
REPORT_MD = "report.md"


def report_header(psb_root, out, settings, options, n_akvf: int, command_line: dict | None) -> dict:
    """The report's header: what was run and where (``settings``: the checked
    :class:`~torchakvf.bench.run.BenchSettings`; ``options``: the SegmentOptions; ``command_line``:
    the command's options as given)."""
    import torch

    from .. import __version__
    from ..evaluate.settings import changed_options

    device = settings.device
    env = {"torchakvf": __version__, "torch": torch.__version__, "python": platform.python_version(),
           "platform": platform.platform(), "cpu_count": os.cpu_count(),
           "torch_threads": torch.get_num_threads()}
    if str(device).startswith("cuda"):
        env["cuda_device"] = torch.cuda.get_device_name(torch.device(device))
    categories = settings.categories
    if isinstance(categories, str):
        categories = [c.strip() for c in categories.split(",") if c.strip()]
    segment_kwargs = changed_options(options)
    if settings.coarse_faces:
        segment_kwargs["coarse_faces"] = settings.coarse_faces
    return {
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "options": dict(command_line) if command_line is not None else None,
        "settings": {"psb": str(psb_root), "out": str(out), "device": str(device), "seed": int(options.seed),
                     "batch_faces": int(settings.batch_faces), "baseline_every": int(settings.baseline_every),
                     "limit": settings.limit, "categories": categories, "protocol": "by-segmentation",
                     "remedy": options.remedy, "n_akvf": n_akvf, "n_fields": settings.n_fields,
                     "segment_kwargs": dict(sorted(segment_kwargs.items())),
                     "budgets": list(settings.budgets), "repeats": int(settings.repeats)},
        "environment": env,
        "units": {"seconds": "wall seconds (time.perf_counter)", "faces": "faces of the input file",
                  "memory": "MiB (2**20 bytes)",
                  "ratio": "baseline seconds / torchakvf seconds on the same meshes, this run"},
        "runs": {},
        "notes": [],
    }


# ---- reports ------------------------------------------------------------------------------

def _f(v, digits=2) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return f"{v:,.{digits}f}"


_DESCRIPTIONS = {
    "batched": "torchakvf, harness path, batches of <= {bf} faces, every selected mesh",
    "one_at_a_time": "torchakvf, harness path, face budget 1 (one mesh per batch), baseline subset",
    "scipy": ("torchakvf/scipy_reference/: eigsh once per mesh + numpy untangle + numpy k-means "
              "per k (load and clean-up: torchakvf's)"),
    "batched_subset": "torchakvf, batches of <= {bf} faces, the meshes compared with the baselines",
}


def _describe(name: str, run: dict, settings: dict) -> str:
    if name in _DESCRIPTIONS:
        return _DESCRIPTIONS[name].format(bf=settings["batch_faces"])
    # budget_B: a run of the face-budget sweep
    return f"torchakvf, batches of <= {run['batch_faces']} faces, the budget sweep's meshes"


def budget_lines(sweep: dict) -> list:
    L = ["\n## Batched vs one at a time, by face budget (same meshes, this run)\n"]
    L.append(f"{sweep['meshes']} meshes ({sweep['faces']:,} faces; ids "
             f"{', '.join(map(str, sweep['mesh_ids']))}), each run once one mesh per batch "
             f"(run {sweep['baseline_run']}) and once per budget (runs budget_B; a budget counts "
             "the faces solved, i.e. decimated faces under coarse_faces)"
             + (f"; {sweep['repeats']} repetitions, interleaved, each run timed by its fastest"
                if sweep.get("repeats", 1) > 1 else "") + ".\n")
    L.append("| face budget | batches | batched s | one at a time s | ratio | CPU-time ratio | akvf ratio | "
             "segment ratio | batched s, each repeat |")
    L.append("|---:|---:|---:|---:|---:|---:|---:|---:|---|")
    for row in sweep["rows"]:
        flag = "" if row["comparable"] else " (not comparable: other failures)"
        L.append(f"| {row['budget']:,} | {row['batches']} | {_f(row['seconds'])} | "
                 f"{_f(row['one_at_a_time_seconds'])} | **{_f(row['ratio'])}**{flag} | "
                 f"{_f(row.get('cpu_ratio'))} | "
                 f"{_f(row['stage_ratios'].get('akvf'))} | {_f(row['stage_ratios'].get('segment'))} | "
                 f"{', '.join(_f(x) for x in row.get('seconds_each', []))} |")
    if sweep.get("one_at_a_time_seconds_each"):
        L.append(f"\none at a time s, each repeat: {', '.join(_f(x) for x in sweep['one_at_a_time_seconds_each'])}")
    if sweep["rows"] and all(row["batches"] == sweep["meshes"] for row in sweep["rows"]):
        L.append("\nEvery budget ran one mesh per batch, the plan of the one-at-a-time run: on the CPU "
                 "with several workers the meshes are never grouped (a CPU batch is solved one mesh "
                 "at a time inside; `torchakvf.pipeline.batches.batches_per_worker`), so these "
                 "ratios show the machine's run-to-run noise.")
    L.append("\nratio = one-at-a-time seconds / batched seconds (>= 1: batching at least as fast); "
             "CPU-time ratio: the same with the CPU seconds of this process and its workers (other "
             "processes' load does not inflate them; on a GPU the wall ratio is the one that counts); "
             "stage ratios compare summed stage seconds.")
    return L


def _markdown(r: dict) -> str:
    L = ["# torchakvf bench\n"]
    L += _header_lines(r)
    L += _run_lines(r)
    L += _by_k_lines(r)
    L += _comparison_lines(r.get("comparison"))
    if r.get("budget_sweep"):
        L.extend(budget_lines(r["budget_sweep"]))
    L += _trouble_lines(r)
    return "\n".join(L) + "\n"


def _header_lines(r: dict) -> list:
    s = r["settings"]
    sel = r["selection"]
    L = []
    if r.get("partial"):
        L.append(f"**Partial report:** the bench has not finished (stopped, or still running); "
                 f"these are the runs done after {_f(r.get('wall_seconds'), 1)} s.\n")
    L.append(f"- created {r['created']}; torchakvf {r['environment']['torchakvf']}, torch "
             f"{r['environment']['torch']} ({r['environment']['torch_threads']} threads, "
             f"{r['environment']['cpu_count']} CPUs), device {s['device']}"
             + (f" ({r['environment']['cuda_device']})" if "cuda_device" in r["environment"] else ""))
    L.append(f"- PSB {s['psb']}: {sel['meshes']} meshes, {sel['faces']:,} faces, "
             f"{sel['predictions']} (mesh, k) predictions (protocol by-segmentation: every distinct "
             f"human segment count; meshes without ground truth, at the harness's default k: "
             f"{sel['meshes_without_ground_truth']})")
    L.append(f"- settings: seed {s['seed']}, batch_faces {s['batch_faces']}, baseline every "
             f"{s['baseline_every']}, limit {s['limit'] or 'none'}, categories "
             f"{','.join(s['categories']) if s['categories'] else 'all'}, remedy {s['remedy']}, "
             f"{s['n_akvf']} AKVFs per mesh, segment {s['segment_kwargs']}")
    L.append(f"- wall time {_f(r['wall_seconds'], 1)} s (plan {_f(sel['plan_seconds'], 1)} s, "
             f"warm-up {_f(r.get('warm_up_seconds'), 1)} s, neither part of a run); peak RSS "
             f"{_f(r['peak_memory']['ru_maxrss_mib'], 0)} MiB"
             + (f" in this process, {_f(r['peak_memory']['worker_maxrss_mib'], 0)} MiB in the "
                f"largest worker, at most {_f(r['peak_memory']['total_rss_bound_mib'], 0)} MiB in "
                f"all" if r["peak_memory"].get("worker_maxrss_mib") else "")
             + (f", CUDA peak allocated {_f(r['peak_memory']['cuda_max_memory_allocated_mib'], 0)} MiB"
                if r["peak_memory"]["cuda_max_memory_allocated_mib"] is not None else ""))
    return L


def _run_lines(r: dict) -> list:
    s = r["settings"]
    L = ["\n## Runs\n"]
    L.append("| run | meshes ok | faces | wall s | meshes/s | faces/s | load s | pack s | akvf s | "
             "segment s | write s | other s | workers | peak RSS MiB | CUDA peak MiB |")
    L.append("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for name, run in r["runs"].items():
        if "skipped" in run:
            L.append(f"| {name} | skipped | | | | | | | | | | | | | |")
            continue
        st = run["stage_seconds"]
        L.append(f"| {name} | {run['meshes_ok']}/{run['meshes']} | {run['faces_ok']:,} | "
                 f"{_f(run['wall_seconds'])} | {_f(run['meshes_per_second'], 3)} | "
                 f"{_f(run['faces_per_second'], 0)} | "
                 + " | ".join(_f(st[x]) for x in STAGES)
                 + f" | {run.get('workers', 1)} | {_rss_cell(run)} | {_f(run['cuda_max_memory_allocated_mib'], 0)} |")
    L.append("")
    for name, run in r["runs"].items():
        if "skipped" in run:
            L.append(f"- **{name}**: {run['skipped']}")
        else:
            how = "one mesh at a time, CPU" if run["kind"] == "scipy" else f"{run['batches']} batch(es)"
            L.append(f"- **{name}**: {_describe(name, run, s)} ({how})")
    L.append("\nStages: load = reading files; pack = clean-up, packing, transfer to the device; "
             "akvf = operator + eigensolve (once per batch, shared by every k); segment = "
             "untangling + spherical k-means + boundaries; write = prediction files; other = the "
             "rest of the wall time. Stage seconds add up over the workers (with W workers they "
             "can sum to W x the wall time). Peak RSS is ru_maxrss after the run: the process's "
             "peak so far, which never goes down; with workers, 'main + W x worker' where worker "
             "is the largest worker's peak so far: a bound on the run's resident total.")
    return L


def _by_k_lines(r: dict) -> list:
    L = ["\n## Untangle + cluster seconds by k\n"]
    names = [n for n, run in r["runs"].items() if "skipped" not in run]
    ks = sorted({int(k) for n in names for k in r["runs"][n]["segment_seconds_by_k"]})
    L.append("| k | " + " | ".join(f"{n}: predictions | {n}: s | {n}: s/prediction" for n in names) + " |")
    L.append("|---:|" + "---:|---:|---:|" * len(names))
    for k in ks:
        cells = []
        for n in names:
            v = r["runs"][n]["segment_seconds_by_k"].get(str(k))
            if v is None:
                cells += ["-", "-", "-"]
            else:
                per = v["seconds"] / v["predictions"] if v["predictions"] else None
                cells += [str(v["predictions"]), _f(v["seconds"]), _f(per, 3)]
        L.append(f"| {k} | " + " | ".join(cells) + " |")
    L.append("\nA round of a batch segments every mesh at one k each; its time is charged to "
             "the k's by face share (meshes padded with k = 1 charge nothing).")
    return L


def _comparison_lines(c: dict | None) -> list:
    L = ["\n## Baselines / torchakvf (same meshes, this run)\n"]
    if c is None:
        L.append("No baselines were run (--baseline-every 0).")
    else:
        L.append(f"Baseline subset: every M-th selected mesh (M = {c['baseline_every']}), "
                 f"{len(c['subset_ids'])} meshes; {c['meshes']} compared "
                 f"({c['faces']:,} faces; ids {', '.join(map(str, c['mesh_ids'])) or '-'}); "
                 f"torchakvf time from run {c['torchakvf_run']} on exactly those meshes.\n")
        L.append("| baseline | baseline s | torchakvf s | ratio | akvf ratio | segment ratio |")
        L.append("|---|---:|---:|---:|---:|---:|")
        for name in ("one_at_a_time", "scipy"):
            v = c["ratios"].get(name)
            if v is None:
                L.append(f"| {name} | - | - | {'skipped' if name == 'scipy' else '-'} | - | - |")
                continue
            L.append(f"| {name} | {_f(v['baseline_seconds'])} | {_f(v['torchakvf_seconds'])} | "
                     f"**{_f(v['ratio'])}** | {_f(v['stage_ratios'].get('akvf'))} | "
                     f"{_f(v['stage_ratios'].get('segment'))} |")
        L.append("\nratio = baseline seconds / torchakvf seconds (> 1: torchakvf faster); a "
                 "baseline's seconds are its per-mesh seconds summed over the compared meshes.")
        if c["excluded"]:
            L.append("\nExcluded from the comparison (failed in some run):")
            for i, why in c["excluded"].items():
                L.append(f"- {i}: {why}")
    return L


def _trouble_lines(r: dict) -> list:
    """Failures, unconverged eigensolves, inputs left out and notes."""
    L = []
    fails = [(n, i, e) for n, run in r["runs"].items() for i, e in run.get("failed", {}).items()]
    if fails:
        L.append("\n## Failures\n")
        for n, i, e in fails:
            L.append(f"- {n}, mesh {i}: {e}")
    slow = [(n, i, v) for n, run in r["runs"].items() for i, v in run.get("unconverged", {}).items()]
    if slow:
        L.append("\n## Eigensolves that did not converge\n")
        for n, i, v in slow:
            L.append(f"- {n}, mesh {i}: largest eigenpair residual {v:.3g}")
    if r.get("problems"):
        L.append("\n## Inputs left out\n")
        L.extend(f"- {line}" for line in r["problems"])
    if r["notes"]:
        L.append("\n## Notes\n")
        for note in r["notes"]:
            L.append(f"- {note}")
    return L


def _jsonable(obj):
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    return obj


def _rss_cell(run: dict) -> str:
    if run.get("worker_maxrss_mib") is None:
        return _f(run.get("ru_maxrss_mib"), 0)
    return (f"{_f(run['ru_maxrss_mib'], 0)} + {run['workers']} x {_f(run['worker_maxrss_mib'], 0)}"
            f" <= {_f(run['total_rss_bound_mib'], 0)}")


def write_bench_reports(out: Path, report: dict) -> None:
    clean = _jsonable(report)
    atomic_write_bytes(out / REPORT_JSON, (json.dumps(clean, indent=1) + "\n").encode())
    atomic_write_bytes(out / REPORT_MD, _markdown(clean).encode())


def summary_lines(report: dict, out: Path) -> list:
    """The short stdout summary of a report."""
    a = report["runs"]["batched"]
    L = [f"torchakvf bench: {a['meshes_ok']}/{a['meshes']} meshes, {a['faces_ok']:,} faces, "
         f"{report['selection']['predictions']} predictions in {_f(a['wall_seconds'], 1)} s: "
         f"{_f(a['meshes_per_second'], 3)} meshes/s, {_f(a['faces_per_second'], 0)} faces/s "
         f"(batches of <= {a['batch_faces']} faces, {a['device']}, {a.get('workers', 1)} "
         f"worker(s)); peak RSS {_f(report['peak_memory']['total_rss_bound_mib'], 0)} MiB at most"]
    c = report.get("comparison")
    if c is not None:
        parts = []
        for name in ("one_at_a_time", "scipy"):
            v = c["ratios"].get(name)
            parts.append(f"{name} {_f(v['ratio'])}x" if v else f"{name} skipped")
        L.append(f"  baseline / torchakvf on {c['meshes']} meshes: " + ", ".join(parts))
    sweep = report.get("budget_sweep")
    if sweep:
        L.append(f"  one at a time / batched on {sweep['meshes']} meshes, by face budget: "
                 + ", ".join(f"{row['budget']}: {_f(row['ratio'])}x (CPU time {_f(row.get('cpu_ratio'))}x)"
                             for row in sweep["rows"]))
    for note in report["notes"]:
        L.append(f"  note: {note}")
    L.append(f"  wrote {out / REPORT_MD} and {out / REPORT_JSON}")
    return L
