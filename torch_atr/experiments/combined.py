"""One report of every experiment: ``python -m torch_atr.experiments all --out DIR``.

Each experiment runs into ``DIR/<name>/`` as it would alone (resumable). ``DIR/report.md``
then holds their reports one after another, headings moved one level down and figure links
pointing into the sub-folders; ``DIR/results.json`` (format ``torch_atr.experiments_report``)
says where each experiment's own ``results.json`` is and which format it has.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import torch_atr
from torch_atr.io import atomic_write_text

COMBINED_FORMAT = "torch_atr.experiments_report"
EXPERIMENTS = ("sensiac-like", "unseen", "visible", "studies")  # the order of the report
_LINK = re.compile(r"\]\((?!https?:|#|/)([^)]+)\)")  # a relative link target in Markdown


def nest_report(text: str, folder: str) -> str:
    """A sub-report's Markdown as a section of the combined one: every heading one level deeper
    (outside code fences) and every relative link prefixed with ``folder/``."""
    lines, fenced = [], False
    for line in text.splitlines():
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced and line.startswith("#"):
            line = "#" + line
        lines.append(line if fenced else _LINK.sub(lambda m: f"]({folder}/{m.group(1)})", line))
    return "\n".join(lines)


def write_combined_report(out: Path, names: tuple[str, ...], wall_s: float) -> None:
    """``report.md`` and ``results.json`` of ``out`` from its sub-folders' reports, atomically.

    Raises ``FileNotFoundError`` naming the sub-report that is missing.
    """
    sections, index = [], {}
    for name in names:
        folder = out / name
        report, results = folder / "report.md", folder / "results.json"
        for path in (report, results):
            if not path.is_file():
                raise FileNotFoundError(f"{path}: the {name} experiment wrote no report; run it again")
        sections.append(nest_report(report.read_text(encoding="utf-8"), name))
        index[name] = {"results": f"{name}/results.json",
                       "format": json.loads(results.read_text(encoding="utf-8")).get("format")}
    head = ["# The thesis's experiments on the simulator", "",
            f"{len(names)} experiments ({', '.join(names)}); torch_atr {torch_atr.__version__}; "
            f"wall time {wall_s:.0f} s for this run (sequences kept from an earlier run are not re-run). "
            "Each section is its experiment's own report; its folder holds its figures, sequences and results.json.",
            ""]
    atomic_write_text("\n".join(head) + "\n" + "\n\n".join(sections) + "\n", out / "report.md")
    summary = {"format": COMBINED_FORMAT, "torch_atr_version": torch_atr.__version__, "wall_s": wall_s,
               "experiments": index}
    atomic_write_text(json.dumps(summary, indent=1) + "\n", out / "results.json")
