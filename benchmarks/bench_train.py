"""Default training end to end: wall time, peak RSS and the time of each stage.

    python benchmarks/bench_train.py [--config configs/default.yaml] [key=value ...]

Runs ``train.py`` in a child process (so the peak RSS is that process's alone) into a temporary
folder and prints the figures the README quotes; targets from issue 3: < 2 minutes, < 1.5 GB.
A config or override that train.py refuses is reported as its one-line error.
"""

from __future__ import annotations

import argparse
import json
import logging
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from torch_atr.cli import run_main
from torch_atr.config import ConfigError

from benchlib import REPO

TRAIN_ERROR = "train.py: error: "  # how train.py's run_main reports a user error, on its last line


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default=str(REPO / "configs/default.yaml"),
                        help="train.py's YAML config (default: the repository's configs/default.yaml)")
    parser.add_argument("overrides", nargs="*", help="key=value overrides for train.py (model.ridge=1e-3)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, str(REPO / "train.py"), "--config", str(Path(args.config).resolve()),
               f"checkpoint={tmp}/model.pt", f"log_dir={tmp}/runs", "name=bench", *args.overrides]
        start = time.perf_counter()
        child = subprocess.run(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        wall = time.perf_counter() - start
        if child.returncode:
            last = (child.stderr.splitlines() or [""])[-1]
            if last.startswith(TRAIN_ERROR):
                raise ConfigError(f"train.py: {last[len(TRAIN_ERROR):]}")
            sys.stderr.write(child.stderr)
            raise SystemExit(f"train.py failed with exit status {child.returncode}; its output is above")
        peak_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
        report = json.loads((Path(tmp) / "runs/bench/report.json").read_text())
    logging.info("train.py end to end: %.1f s wall, peak RSS %.0f MB (targets: < 120 s, < 1500 MB)", wall, peak_mb)
    for stage, seconds in report["timings_s"].items():
        logging.info("  %-12s %6.1f s", stage, seconds)
    logging.info("train IoU %.3f, held-out IoU %.3f", report["train_iou"]["all"], report["held_out_iou"]["all"])


if __name__ == "__main__":
    run_main(main)
