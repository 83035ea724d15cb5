"""Default training end to end: wall time, peak RSS and the time of each stage.

    python benchmarks/bench_train.py [--config configs/default.yaml] [key=value ...]

Runs ``train.py`` in a child process (so the peak RSS is that process's alone) into a temporary
folder and prints the figures the README quotes; targets from issue 3: < 2 minutes, < 1.5 GB.
"""

import argparse
import json
import logging
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default=str(REPO / "configs/default.yaml"))
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, str(REPO / "train.py"), "--config", args.config, f"checkpoint={tmp}/model.pt",
               f"log_dir={tmp}/runs", "name=bench", *args.overrides]
        start = time.perf_counter()
        subprocess.run(cmd, check=True, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        wall = time.perf_counter() - start
        peak_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
        report = json.loads((Path(tmp) / "runs/bench/report.json").read_text())
    logging.info("train.py end to end: %.1f s wall, peak RSS %.0f MB (targets: < 120 s, < 1500 MB)", wall, peak_mb)
    for stage, seconds in report["timings_s"].items():
        logging.info("  %-12s %6.1f s", stage, seconds)
    logging.info("train IoU %.3f, held-out IoU %.3f", report["train_iou"]["all"], report["held_out_iou"]["all"])


if __name__ == "__main__":
    main()
