"""Result tables in the column layout of the paper's tables, next to the paper's own numbers.

The runner's report.md has one column per group label, sorted by name.  The paper orders and
abbreviates its columns differently (Table II: the 15 Human3.6M actions; Table III: HumanEva-I
Walking and Jogging of subjects S1-S3), so this module maps group labels to the paper's columns and
writes `table_paper_layout.md` into the run directory.  "Avg" is the mean over the columns, as in
the paper; when the test split lacks some columns (a subset of subjects or actions) it is the mean
over those present, and the table says so.
"""

from __future__ import annotations

import dataclasses
import pathlib
from collections.abc import Mapping

import numpy as np

from jaxpose.formats.outputs import atomic_output
from jaxpose.training.run_directory import RunDirectory


@dataclasses.dataclass(frozen=True)
class PaperTable:
    """One of the paper's per-group tables."""

    name: str
    """The paper's table number, e.g. "Table II"."""
    caption: str
    """What the numbers are (metric, data, protocol)."""
    columns: tuple[tuple[str, tuple[str, ...]], ...]
    """(column header, group labels that fill it): several labels where sources name a group differently."""
    references: Mapping[str, tuple[float, ...]]
    """The paper's rows to compare with: one value per column, then Avg."""
    metric: str = "p_mpjpe"
    """The metric of the paper's table (a key of `jaxpose.training.evaluation.summarize`)."""


# Column order and headers of the paper's Table II; group labels are `jaxpose.datasets.h36m.sequence_action` names.
H36M_TABLE_II = PaperTable(
    name="Table II",
    caption="Human3.6M, P-MPJPE (mm) per action (Protocol II, rigid alignment), test subjects",
    columns=(
        ("Dir.", ("Directions",)),
        ("Dis.", ("Discussion",)),
        ("Eat", ("Eating",)),
        ("Greet", ("Greeting",)),
        ("Phone", ("Phoning",)),
        ("Photo", ("Photo",)),
        ("Pose", ("Posing",)),
        ("Purch.", ("Purchases",)),
        ("Sit", ("Sitting",)),
        ("SitD", ("SittingDown",)),
        ("Smoke", ("Smoking",)),
        ("Wait", ("Waiting",)),
        ("WalkD", ("WalkDog",)),
        ("Walk", ("Walking",)),
        ("WalkT", ("WalkTogether",)),
    ),
    references={
        "Paper: ours (self-supervised)": (
            49.4, 51.7, 61.7, 56.5, 64.9, 67.1, 51.6, 52.1, 83.9, 111.3, 60.5, 54.7, 56.9, 45.9, 53.6, 62.0,
        ),
        "Paper: Martinez et al. (supervised)": (
            39.5, 43.2, 46.4, 47.0, 51.0, 56.0, 41.4, 40.6, 56.5, 69.4, 49.2, 45.0, 38.0, 49.0, 43.1, 47.7,
        ),
    },
)

# The paper's Table III (its header prints "S1 S3 S3" under Walking; the protocol is S1, S2, S3).
# Group labels are "<action> <subject>"; VideoPose3D's files name the walking sequences "Walking".
HUMANEVA_TABLE_III = PaperTable(
    name="Table III",
    caption="HumanEva-I, P-MPJPE (mm) per action and subject, Validate partition",
    columns=tuple(
        (f"{header} {subject}", tuple(f"{label} {subject}" for label in labels))
        for header, labels in (("Walking", ("Walk", "Walking")), ("Jogging", ("Jog", "Jogging")))
        for subject in ("S1", "S2", "S3")
    ),
    references={
        "Paper: ours (self-supervised)": (59.2, 60.3, 52.2, 38.2, 61.7, 81.3, 58.9),
        "Paper: Martinez et al. (supervised)": (19.7, 17.4, 46.8, 26.9, 18.2, 18.6, 24.6),
    },
)


def _cells(table: PaperTable, summary: Mapping, metric: str) -> list[float | None]:
    """One value per column (None where the test split has no such group)."""
    groups = summary.get("groups", {})
    values = []
    for _, labels in table.columns:
        present = [groups[label][metric] for label in labels if label in groups]
        values.append(present[0] if present else None)
    return values


def render(table: PaperTable, results: Mapping[str, Mapping], metric: str, title: str, with_references: bool) -> str:
    """A markdown table: one row per method of `results` (method -> `summarize` result), then the
    paper's rows if `with_references`."""
    header = ["Method", *(name for name, _ in table.columns), "Avg"]
    lines = [f"**{title}**", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    missing: set[str] = set()
    for method, summary in results.items():
        values = _cells(table, summary, metric)
        missing |= {name for (name, _), value in zip(table.columns, values) if value is None}
        present = [value for value in values if value is not None]
        average = f"{np.mean(present):.1f}" if present else "-"
        cells = ["-" if value is None else f"{value:.1f}" for value in values]
        lines.append("| " + " | ".join([method, *cells, average]) + " |")
    if with_references:
        for method, values in table.references.items():
            lines.append("| " + " | ".join([method, *(f"{value:.1f}" for value in values)]) + " |")
    if missing:
        absent = [name for name, _ in table.columns if name in missing]
        lines += ["", f"The test split has no samples for {', '.join(absent)}: our Avg is over the other columns."]
    return "\n".join(lines)


def write(table: PaperTable, results: Mapping[str, Mapping], run: RunDirectory) -> pathlib.Path:
    """Write the run's `RunDirectory.paper_table` (table_paper_layout.md): the paper's metric with its reference rows, then
    MPJPE (no alignment) in the same layout.  Returns the path."""
    parts = [
        render(table, results, table.metric, f"{table.name} layout: {table.caption}", with_references=True),
        render(
            table,
            results,
            "mpjpe",
            f"{table.name} layout, MPJPE (mm, root-relative, no alignment; not reported in the paper)",
            with_references=False,
        ),
    ]
    with atomic_output(run.paper_table) as temporary:
        temporary.write_text("\n\n".join(parts) + "\n")
    return run.paper_table
