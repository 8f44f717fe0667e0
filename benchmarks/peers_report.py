"""The peers' benchmark's report (`benchmarks.peers`): its report.json as markdown tables, the accuracy per
condition (as it is, and the mean and range over occlusion seeds) and the timing per camera count."""

from __future__ import annotations

import numpy as np

from benchmarks.peers_scores import BUCKETS


def _number(value, digits: int = 1) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def accuracy_tables(result: dict) -> list[str]:
    conditions = result["conditions"]
    occluded = [c for c in conditions if c.startswith("occluded")]
    groups = {"As it is": ["as it is"], f"Occluded ({len(occluded)} seeds: mean, and min-max of the overall MPJPE)": occluded}
    lines = []
    for title, members in groups.items():
        if not members or not all(m in conditions for m in members):
            continue
        first = conditions[members[0]]
        lines += [f"### {title}", "", f"Instants: {first['instants']} per condition; the ground truth's limb spread"
                  f" {_number(np.mean([conditions[m]['ground_truth_limb_spread_mm'] for m in members]))} mm.", ""]  # fmt: skip
        header = ["method", "MPJPE (covered %)", "MPJPE, agreeing joints", "P-MPJPE (complete instants)", "accel. error mm/frame²",
                  "limb spread mm", *[f"{b} views: covered %, MPJPE" for b in BUCKETS], "instants with a gap"]  # fmt: skip
        lines += ["| " + " | ".join(header) + " |", "|---" * len(header) + "|"]
        for method in first["methods"]:
            rows = [conditions[m]["methods"].get(method) for m in members]
            if any(r is None for r in rows):
                continue
            mean = lambda key: None if any(r[key] is None for r in rows) else float(np.mean([r[key] for r in rows]))  # noqa: E731
            overall = _number(mean("mpjpe_mm"))
            if len(rows) > 1 and mean("mpjpe_mm") is not None:
                overall += f" ({min(r['mpjpe_mm'] for r in rows):.1f}-{max(r['mpjpe_mm'] for r in rows):.1f})"
            cells = [method, f"{overall}, {_number(mean('covered_pct'), 0)}%", _number(mean("mpjpe_agreeing_mm")),
                     f"{_number(mean('p_mpjpe_mm'))} ({sum(r['complete_frames'] for r in rows)})",
                     _number(mean("accel_error_mm_per_frame2"), 2), _number(mean("limb_spread_mm"))]  # fmt: skip
            for b in BUCKETS:
                buckets = [r["buckets"][b] for r in rows]
                if not sum(x["cells"] for x in buckets):
                    cells.append("no cells")
                    continue
                covered = np.mean([x["covered_pct"] or 0 for x in buckets])
                errors = [x["mpjpe_mm"] for x in buckets if x["mpjpe_mm"] is not None]
                cells.append(f"{covered:.0f}%, {_number(float(np.mean(errors)) if errors else None)}")
            cells.append(str(sum(r["instants_with_a_gap"] for r in rows)))
            lines.append("| " + " | ".join(cells) + " |")
        lines += ["", "The world error split: per recording and joint, its mean over the instants (the offset) and what varies",
                  "about it (mm):", "", "| method | MPJPE | offset | about the offset |", "|---|---|---|---|"]  # fmt: skip
        for method in first["methods"]:
            rows = [conditions[m]["methods"].get(method) for m in members]
            if all(r is not None and r.get("offset_mm") is not None for r in rows):
                split = [_number(float(np.mean([r[key] for r in rows]))) for key in ("mpjpe_mm", "offset_mm", "about_offset_mm")]
                lines.append("| " + " | ".join([method, *split]) + " |")
        lines.append("")
    return lines


def timing_table(result: dict) -> list[str]:
    lines = [f"Synthetic rig, one recording of {result['frames']} frames, detector noise x{result['noise_scale']:g},"
             f" outliers {result['outlier_rate']:.0%}; frames per second (wall / process CPU time), first call with"
             " compilation, then the median of the warm calls:", "",
             "| cameras | method | first call fps | warm fps (median) | warm calls | MPJPE mm | note |",
             "|---|---|---|---|---|---|---|"]  # fmt: skip
    for count, row in result["cameras"].items():
        for method, entry in row.items():
            times = np.array(entry["times"], float).reshape(-1, 2)
            frames = result["frames"]
            first = f"{frames / times[0, 0]:.1f} / {frames / times[0, 1]:.1f}" if len(times) else "-"
            warm = f"{frames / np.median(times[1:, 0]):.1f} / {frames / np.median(times[1:, 1]):.1f}" if len(times) > 1 else "-"
            cells = [str(count), method, first, warm, str(max(len(times) - 1, 0)), _number(entry["mpjpe_mm"]), entry["problem"]]
            lines.append("| " + " | ".join(cells) + " |")
    return lines


def report_markdown(report: dict) -> str:
    lines = ["# Peers side by side", "", report["setup"], ""]
    if "accuracy" in report:
        lines += ["## Accuracy", "", *accuracy_tables(report["accuracy"]), *[f"- {p}" for p in report["accuracy"]["problems"]], ""]
    if "timing" in report:
        lines += ["## Timing", "", *timing_table(report["timing"]), ""]
    return "\n".join(lines)
