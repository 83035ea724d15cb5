"""Hypothesis profiles of the fuzz suite (tests/test_fuzz.py).

"ci" runs with the default suite: few cases, derandomized so a run is reproducible, and under
60 s on 2 cores. "large" runs with ``pytest -m slow``: random cases, at least 10,000 in all.
Each fuzz test scales ``max_examples`` by its own weight. Time and memory are bounded by the
tests themselves (a SIGALRM timer and RLIMIT_DATA), so Hypothesis's deadline is off: it is
flaky on a shared machine and cannot stop a hang anyway.
"""

import os
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

SHIPPED_CHECKPOINT = Path(__file__).resolve().parents[1] / "checkpoints" / "default.pt"

settings.register_profile("ci", max_examples=30, derandomize=True, deadline=None, database=None, print_blob=True,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
settings.register_profile("large", max_examples=2000, deadline=None, print_blob=True,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@pytest.fixture(autouse=True)
def _close_figures():
    """Close the figures a test drew: pyplot keeps every open figure, and warns past 20."""
    yield
    pyplot = sys.modules.get("matplotlib.pyplot")
    if pyplot is not None:
        pyplot.close("all")


@pytest.fixture(scope="module")
def model():
    """The shipped checkpoint's model, one per test module (a Tracker moves it to its device). A
    module that needs another model defines its own ``model`` fixture."""
    from torch_atr.model import GenerativeShapeModel

    return GenerativeShapeModel.from_checkpoint(SHIPPED_CHECKPOINT)


@pytest.fixture
def disk_events(monkeypatch):
    """The fsyncs and renames a test makes, in order: ("fsync", the path synced) and ("replace", src, dst)."""
    events = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        events.append(("fsync", os.path.realpath(f"/proc/self/fd/{fd}")))
        real_fsync(fd)

    def replace(src, dst):
        events.append(("replace", str(src), str(dst)))
        real_replace(src, dst)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    return events
