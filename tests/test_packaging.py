"""The oldest versions .ci/oldest tests against are the lower bounds pyproject.toml states."""

import re
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _name(text: str) -> str:
    return re.sub(r"[-_.]+", "-", text).lower()


def _release(version: str) -> tuple[int, ...]:
    """1.0 and 1.0.0 alike: trailing zeros dropped."""
    parts = [int(p) for p in version.split(".")]
    while len(parts) > 1 and parts[-1] == 0:
        parts.pop()
    return tuple(parts)


def test_oldest_pins_are_the_lower_bounds_of_every_dependency():
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    bounds = {}
    for spec in project["dependencies"] + project["optional-dependencies"]["dev"]:
        match = re.fullmatch(r"([A-Za-z0-9_.\-]+)>=([0-9.]+)", spec.replace(" ", ""))
        assert match, f"pyproject.toml: {spec!r} is not NAME>=VERSION"
        bounds[_name(match[1])] = match[2]
    pins = {}
    for line in (REPO / ".ci" / "oldest-requirements.txt").read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            name, version = line.split("==")
            pins[_name(name)] = version
    assert set(pins) == set(bounds) - {"torch"}  # torch: the CPU build on disk, installed first
    for name, version in pins.items():
        # The pin is a release of the bound (numpy 1.24 -> 1.24.4, opencv 4.10 -> 4.10.0.84).
        assert _release(version)[:len(_release(bounds[name]))] == _release(bounds[name]), (name, version, bounds[name])
