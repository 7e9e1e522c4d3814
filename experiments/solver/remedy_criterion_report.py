"""Summarise remedy_criterion.py's CSVs (decimated as eval solves, and full resolution) as the
markdown tables of experiments/results/remedy_choice.md.

    python3 experiments/solver/remedy_criterion_report.py /tmp/remedy_auto.csv /tmp/remedy_auto_full.csv
"""
from __future__ import annotations

import csv
import sys
from collections import defaultdict


def load(path: str) -> list[dict]:
    with open(path) as fh:
        return list(csv.DictReader(fh))


def decisions(rows: list[dict], title: str) -> list[str]:
    by_cat = defaultdict(list)
    for r in rows:
        by_cat[r["category"]].append(r)
    out = [f"### {title}", "", "| category | meshes | smooth | none | meshes given none |", "|---|---:|---:|---:|---|"]
    for cat, rs in by_cat.items():
        none = [r["mesh"].replace("builtin:", "") for r in rs if r["auto"] == "none"]
        out.append(f"| {cat} | {len(rs)} | {len(rs) - len(none)} | {len(none)} | {', '.join(none)} |")
    psb = [r for r in rows if r["category"] != "builtin"]
    smooth = sum(r["auto"] == "smooth" for r in psb)
    out += ["", f"PSB: {smooth} of {len(psb)} meshes ({100 * smooth / max(len(psb), 1):.1f}%) get \"smooth\".", ""]
    return out


def separation(rows: list[dict]) -> list[str]:
    """How well each geometric statistic separates the meshes auto gives "none" from the others."""
    out = ["| statistic | range on meshes given none | range on meshes given smooth |", "|---|---|---|"]
    for key in ("negative_fraction", "below_floor_fraction", "min_angle_deg", "max_angle_defect"):
        for_none = [float(r[key]) for r in rows if r["auto"] == "none"]
        for_smooth = [float(r[key]) for r in rows if r["auto"] == "smooth"]
        out.append(f"| {key} | {min(for_none):.4g} .. {max(for_none):.4g} "
                   f"| {min(for_smooth):.4g} .. {max(for_smooth):.4g} |")
    return out + [""]


def cost(rows: list[dict]) -> list[str]:
    psb = [r for r in rows if r["category"] != "builtin"]
    tot = {k: sum(float(r[k]) for r in psb) for k in ("seconds_none", "seconds_auto", "seconds_smooth")}
    return [f"Operator assembly summed over the {len(psb)} PSB meshes, one process: "
            f"\"none\" {tot['seconds_none']:.1f} s, "
            f"\"smooth\" {tot['seconds_smooth']:.1f} s, \"auto\" {tot['seconds_auto']:.1f} s "
            f"(auto / smooth = {tot['seconds_auto'] / tot['seconds_smooth']:.2f}).", ""]


def main() -> None:
    lines = []
    for path, title in zip(sys.argv[1:], ("decimated to about 4000 faces (as eval solves them)", "full resolution")):
        rows = load(path)
        lines += decisions(rows, title) + separation(rows) + cost(rows)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
