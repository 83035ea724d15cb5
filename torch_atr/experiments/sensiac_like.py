"""The thesis's SENSIAC experiments (chapter 6.2) regenerated on the simulator.

Every test-split vehicle (three tanks, three APCs, an SUV, a pick-up, as SENSIAC's eight) drives
its circle at every range; each sequence is simulated once and tracked with each of Methods
I–IV from the same frames, the same noises and the same seed. One sequence is one job: jobs run
in worker processes and each writes its result file into ``OUT/sequences/`` when done, so an
interrupted run picks up where it stopped. :func:`aggregate` turns the results into the thesis's
tables: recognition per class group and range (Table 6.1), mean errors per range (Fig. 6.8) and
the identity over time at 1000 m (Fig. 6.10).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import re
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from torch_atr.cli import REPO, in_repo
from torch_atr.config import ConfigError, load_config
from torch_atr.data.sequence import Sequence
from torch_atr.io import atomic_write_text
from torch_atr.tracking import METHODS, TrackerConfig
from torch_atr.tracking.filter import column
from torch_atr.validate import show
from torch_atr.vehicles.specs import SPLITS

log = logging.getLogger(__name__)

TEST_VEHICLES = tuple(spec.name for spec in SPLITS["test"])
RANGES_M = (1000.0, 1500.0, 2000.0, 2500.0, 3000.0, 3500.0)
GROUPS = ("tank", "apc", "suv", "pickup")  # Table 6.1's columns (SENSIAC has no car or minivan)
RESULT_FORMAT = "torch_atr.sensiac_like_sequence"
GRID_SCENE_KEYS = ("range_m", "circle_diameter_m", "frames", "seed")  # set by the grid, not by scene overrides
HELDOUT_PREFIX = "heldout:"  # a vehicle name for a held-out mesh: heldout:PATH, PATH as in the manifest


@dataclass(frozen=True)
class SensiacLikeConfig:
    """One experiment: the grid of vehicles × ranges × methods and the tracker's settings."""

    vehicles: tuple[str, ...] = TEST_VEHICLES
    ranges_m: tuple[float, ...] = RANGES_M
    methods: tuple[str, ...] = METHODS
    frames: int = 150  # per sequence; the default grid finishes in ~10 min on 2 cores
    circle_diameter_m: float = 100.0  # the circle driven; FULL's fits the frame at 1000 m
    init: str = "blind"  # or "truth", the thesis's start
    particles: int = 1000
    seed: int = 0  # the scene's and the tracker's
    checkpoint: str = "checkpoints/default.pt"
    tracker: tuple[str, ...] = field(default_factory=tuple)  # extra TrackerConfig overrides, key=value
    scene: tuple[str, ...] = field(default_factory=tuple)  # SceneConfig overrides: night=false, occluder_width_m=3

    def __post_init__(self) -> None:
        if not self.vehicles or not self.ranges_m or not self.methods:
            raise ConfigError("an experiment needs at least one vehicle, range and method")
        bad = [m for m in self.methods if m not in METHODS]
        if bad:
            raise ConfigError(f"methods: unknown {bad}; expected some of {METHODS}")
        if self.init not in ("blind", "truth"):
            raise ConfigError(f"init must be 'blind' or 'truth'; got {show(self.init)}")
        if not 0 < self.circle_diameter_m <= 1e4:
            raise ConfigError(f"circle_diameter_m must be in (0, 10000]; got {self.circle_diameter_m}")
        for name, top in (("frames", 100_000), ("particles", 10_000_000)):
            if not 1 <= getattr(self, name) <= top:
                raise ConfigError(f"{name} must be in [1, {top}]; got {show(getattr(self, name))}")
        grid = [o for o in self.scene if o.split("=", 1)[0].strip() in GRID_SCENE_KEYS]
        if grid:
            raise ConfigError(f"scene: {grid[0]!r} sets the grid itself; use the experiment's own options for "
                              f"{', '.join(GRID_SCENE_KEYS)}")
        from torch_atr.data.synthetic import SceneConfig

        load_config(SceneConfig, None, list(self.scene), what="--scene")  # fails here, naming the key, not in a worker
        for range_m in self.ranges_m:  # as does a range the scene refuses (at most 100 km, beyond the circle)
            scene(range_m, self)
        for method in self.methods:  # so do the tracker's: a bad key failed once every worker had built its scene
            load_config(TrackerConfig, None, self.tracker_overrides(method))
        for vehicle in self.vehicles:  # and the inputs, before a run folder is made
            check_vehicle(vehicle)
        resolve_checkpoint(self.checkpoint)
        for key in ("vehicles", "ranges_m"):  # one job each: a repeat ran twice and weighed twice in the means
            object.__setattr__(self, key, tuple(dict.fromkeys(getattr(self, key))))
        # Results are filed by job_name: two jobs of one name would share a file (the second overwriting
        # the first, a resume reading one for both).
        seen: dict[str, tuple[str, float]] = {}
        for job in ((v, r) for v in self.vehicles for r in self.ranges_m):
            name = job_name(*job, self)
            if seen.setdefault(name, job) != job:
                raise ConfigError(f"vehicles and ranges_m: {show(seen[name])} and {show(job)} would share the result "
                                  f"file {show(name)}; rename one (or give ranges that differ in their first 6 digits)")

    def tracker_overrides(self, method: str) -> list[str]:
        return [f"filter.particles={self.particles}", f"filter.method={method}", f"init.mode={self.init}",
                *self.tracker]


QUICK = {"vehicles": ("t_72",), "ranges_m": (1000.0, 2500.0), "frames": 24, "particles": 300}  # the CI-sized run
# The thesis's sequence length. 1000 frames at 5 m/s drive 167 m: more than a lap of a 50 m circle,
# which stays in the 64 m wide view at 1000 m (the 100 m circle leaves it after ~300 frames).
FULL = {"frames": 1000, "circle_diameter_m": 50.0}


def mean_or_none(values: list) -> float | None:
    """The mean of the values that are not None; None when none is (an error no frame had)."""
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else None


def pooled_frames_per_second(metrics: list[dict]) -> float:
    """Frames per second over sequences: their frames over their seconds (``metrics.json``'s "frames" and
    "frames_per_second" each), not the mean of their rates, which two sequences at 100 and 10 frames/s
    put at 55 where they ran at 18.2."""
    seconds = sum(m["frames"] / m["frames_per_second"] for m in metrics)
    return float(sum(m["frames"] for m in metrics) / seconds) if seconds > 0 else math.nan


def job_name(vehicle: str, range_m: float, cfg: SensiacLikeConfig) -> str:
    """The result file's stem for one sequence (a held-out mesh's path flattened)."""
    return re.sub(r"[^A-Za-z0-9_.-]", "_", f"{vehicle}_{range_m:g}m_{cfg.init}_seed{cfg.seed}")


def heldout_names() -> tuple[str, ...]:
    """Every held-out manifest entry as an experiment vehicle name, ``heldout:PATH``."""
    from torch_atr.vehicles.catalog import read_manifest

    return tuple(HELDOUT_PREFIX + e.path for e in read_manifest())


def _heldout_entries(name: str) -> list:
    """The manifest entry of ``heldout:PATH``, in a list; ``ConfigError`` where the manifest lacks it."""
    from torch_atr.vehicles.catalog import read_manifest

    entries = [e for e in read_manifest() if HELDOUT_PREFIX + e.path == name]
    if not entries:
        raise ConfigError(f"vehicles: {name!r} is not in the held-out manifest; expected one of "
                          f"{', '.join(heldout_names())}")
    return entries


def load_experiment_vehicle(name: str):
    """The vehicle of an experiment name: ``heldout:PATH`` loads that manifest entry (its class,
    axes and scale from the manifest); anything else is left to the simulator (a catalog name)."""
    if not name.startswith(HELDOUT_PREFIX):
        return name
    from torch_atr.vehicles.catalog import load_heldout_meshes

    return load_heldout_meshes(entries=_heldout_entries(name))[0]


def check_vehicle(name: str) -> None:
    """``ConfigError`` unless the simulator can load the experiment vehicle ``name``: a
    ``heldout:PATH`` of the manifest (not loaded), a catalog name or a vehicle file."""
    if name.startswith(HELDOUT_PREFIX):
        _heldout_entries(name)
        return
    from torch_atr.data.synthetic import resolve_vehicle

    try:
        resolve_vehicle(name)
    except ValueError as exc:
        raise ConfigError(f"vehicles: {exc}") from exc


def resolve_checkpoint(checkpoint: str) -> Path:
    """The checkpoint file: a relative path as given if it exists from here, else from the
    repository root (so the default, ``checkpoints/default.pt``, is found from any folder), as
    ``track.py`` resolves it. ``FileNotFoundError`` where neither place holds it, InputError for a
    folder or a device, as ``track.py`` names them."""
    from torch_atr.model.generative import checkpoint_file

    path = in_repo(checkpoint)
    if not path.exists():
        where = "" if Path(checkpoint).is_absolute() else f" (neither from {Path.cwd()} nor from {REPO})"
        raise FileNotFoundError(f"checkpoint not found: {checkpoint}{where}")
    return checkpoint_file(path)


_WORKER: dict = {}  # per worker process: the model and Method IV's templates, loaded once


def worker_model(checkpoint: str):
    """The checkpoint's model, loaded once per process (workers run many sequences)."""
    from torch_atr.model.generative import load_checkpoint

    if _WORKER.get("checkpoint") != checkpoint:
        _WORKER.clear()
        model, extra = load_checkpoint(resolve_checkpoint(checkpoint))
        _WORKER.update(checkpoint=checkpoint, model=model, extra=extra)
    return _WORKER["model"]


def worker_templates(checkpoint: str):
    """Method IV's training templates of the checkpoint's catalog, rendered once per process."""
    from torch_atr.training import trained_catalog, training_templates

    if "templates" not in _WORKER:
        model = worker_model(checkpoint)
        _WORKER["templates"] = training_templates(model, trained_catalog(_WORKER["extra"]))
    return _WORKER["templates"]


def scene(range_m: float, cfg: SensiacLikeConfig):
    """The simulator's scene of one sequence: the default night scene with ``cfg.scene``'s
    overrides, the vehicle driving ``cfg.circle_diameter_m`` at ``range_m``."""
    from torch_atr.data.synthetic import SceneConfig

    grid = [f"range_m={range_m!r}", f"circle_diameter_m={cfg.circle_diameter_m!r}", f"frames={cfg.frames}",
            f"seed={cfg.seed}"]
    return load_config(SceneConfig, None, [*cfg.scene, *grid])


def run_sequence(vehicle: str, range_m: float, cfg: SensiacLikeConfig) -> dict:
    """Simulate one sequence and track it with every method of ``cfg``; the result file's content.

    Runs on one CPU thread: torch's parallel reductions round differently with another thread
    count, so pinning it makes a result the same whichever backend and ``--workers`` ran it.

    Returns {"format", "vehicle", "class", "range_m", "config", "methods": {method: {"metrics":
    ``run_summary``, "alpha": α̂ per frame, "time_s"}}, "wall_s"}.
    """
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return _run_sequence(vehicle, range_m, cfg)
    finally:
        torch.set_num_threads(threads)


def _run_sequence(vehicle: str, range_m: float, cfg: SensiacLikeConfig) -> dict:
    import torch

    from torch_atr.data.synthetic import SyntheticSequence
    from torch_atr.tracking import Tracker
    from torch_atr.tracking.job import run_summary

    start = time.perf_counter()
    model = worker_model(cfg.checkpoint)
    seq = SyntheticSequence(load_experiment_vehicle(vehicle), scene(range_m, cfg))
    frames = FrameCache(seq)  # simulated once, tracked by every method
    out = {"format": RESULT_FORMAT, "vehicle": vehicle, "class": seq.vehicle.cls, "range_m": range_m,
           "config": dataclasses.asdict(cfg), "methods": {}}
    for method in cfg.methods:
        tracker_cfg = load_config(TrackerConfig, None, cfg.tracker_overrides(method))
        tracker = Tracker(worker_model(cfg.checkpoint), seq.camera, tracker_cfg, seed=cfg.seed,
                          templates=worker_templates(cfg.checkpoint) if method == "IV" else None)
        with torch.no_grad():
            result = tracker.run(frames, progress=False, snapshots=0)
        out["methods"][method] = {"metrics": run_summary(result, model, min(60, cfg.frames // 2)),
                                  "alpha": [json_number(a) for a in column(result.rows, "alpha")],
                                  "time_s": [json_number(t) for t in column(result.rows, "time_s")]}
    out["wall_s"] = time.perf_counter() - start
    return out


def json_number(x: float) -> float | None:
    """A JSON number: None for NaN."""
    return None if math.isnan(x) else round(float(x), 5)


class FrameCache(Sequence):
    """A simulated sequence's frames and truth, made once and kept in memory (every method tracks
    the same frames); warm-up frames come from the simulator."""

    def __init__(self, seq):
        self.seq, self.name, self.fps, self.camera, self.meta = seq, seq.name, seq.fps, seq.camera, seq.meta
        self.camera_height_m = seq.camera_height_m
        self._frames = [seq.frame(i) for i in range(len(seq))]
        self._truths = [seq.truth(i) for i in range(len(seq))]

    def __len__(self) -> int:
        return len(self._frames)

    def _read_frame(self, i: int):
        return self._frames[i].copy()

    def _truth(self, i: int):
        return self._truths[i]

    def warmup_frames(self, n: int):
        return self.seq.warmup_frames(n)


def _write(result: dict, path: Path) -> None:
    atomic_write_text(json.dumps(result) + "\n", path)


def kept_results(folder: Path, fmt: str, cfg) -> dict[str, dict]:
    """The results an earlier run of ``cfg`` left in ``folder``, by file stem: every ``*.json`` but
    hidden ones (macOS's ``._NAME.json`` beside each file copied to a FAT or exFAT drive is not a
    result), each a JSON object (NaN allowed, as ``json.dumps`` writes it) of format ``fmt`` and of
    ``cfg``'s configuration. Another file there (damaged, put there by hand, of another seed, start
    or experiment) raises ConfigError naming it: use another ``--out``."""
    config = json.loads(json.dumps(dataclasses.asdict(cfg)))
    kept = {}
    for path in sorted(folder.glob("*.json")):
        if path.name.startswith("."):
            continue
        try:
            result = json.loads(path.read_text(encoding="utf-8"))
        except (ValueError, RecursionError) as exc:  # UnicodeDecodeError, JSONDecodeError, a 5000-digit integer
            raise ConfigError(f"{path} is not a result file ({type(exc).__name__}: {exc}); remove it or use another "
                              "--out") from None
        if not isinstance(result, dict):
            raise ConfigError(f"{path} is not a result file (a JSON {type(result).__name__}); remove it or use "
                              "another --out")
        if result.get("format") != fmt or result.get("config") != config:
            raise ConfigError(f"{path} holds a result of another configuration; use another --out")
        kept[path.stem] = result
    return kept


def run_all(cfg: SensiacLikeConfig, out: Path, workers: int = 0, progress: bool = True,
            ray_address: str | None = None) -> list[dict]:
    """Run every sequence not already in ``out/sequences`` (resumable), ``workers`` at a time
    (0: one per core; 1: in this process), or as tasks of the Ray cluster at ``ray_address``
    ("local": a Ray instance started here). Returns every sequence's result, the grid's order.

    A result file from another configuration is refused (``ConfigError`` naming it): use another
    ``out``. Each result is written as soon as its sequence finishes.
    """
    from tqdm import tqdm

    folder = out / "sequences"
    folder.mkdir(parents=True, exist_ok=True)
    wanted = [(v, r) for v in cfg.vehicles for r in cfg.ranges_m]
    kept = kept_results(folder, RESULT_FORMAT, cfg)  # every file, not only the grid's: another seed's has another name
    done = {job: kept[job_name(*job, cfg)] for job in wanted if job_name(*job, cfg) in kept}
    todo = [job for job in wanted if job not in done]
    log.info("%d sequences: %d done before, %d to run", len(wanted), len(done), len(todo))
    runs = _on_ray(todo, cfg, ray_address) if ray_address else in_processes(todo, cfg, workers or os.cpu_count() or 1)
    with tqdm(total=len(todo), desc="sequences", unit="seq", disable=not progress) as bar:
        for job, result in runs:
            _write(result, folder / f"{job_name(*job, cfg)}.json")
            done[job] = result
            bar.update()
    return [done[job] for job in wanted]


def in_processes(todo: list[tuple], cfg, workers: int, run=None):
    """(job, result) as the jobs finish, ``run(*job, cfg)`` in ``workers`` processes at a time
    (1: here); ``run`` defaults to :func:`run_sequence` and must be picklable (module level).
    A failed job, Ctrl-C or a consumer that stops cancels the jobs not started."""
    run = run_sequence if run is None else run
    if workers == 1 or len(todo) <= 1:
        for job in todo:
            yield job, run(*job, cfg)
        return
    with ProcessPoolExecutor(max_workers=workers) as pool:
        futures = {pool.submit(run, *job, cfg): job for job in todo}
        try:
            for future in as_completed(futures):
                yield futures[future], future.result()
        finally:  # else leaving the block waits for every job, each result then thrown away
            pool.shutdown(cancel_futures=True)


def _on_ray(todo: list[tuple[str, float]], cfg: SensiacLikeConfig, address: str):
    """(job, result) as the sequences finish, one Ray task (one CPU) each. Every node needs
    torch_atr installed and the checkpoint at ``cfg.checkpoint`` (an absolute path is safest)."""
    try:
        import ray
    except ImportError as exc:
        raise ConfigError("--ray needs Ray: pip install -e \".[ray]\"") from exc
    if not hasattr(ray, "remote"):  # a folder named ray in the working folder, imported in its place
        raise ConfigError(f"--ray needs Ray: 'import ray' found the folder {list(ray.__path__)[0]}, not the package "
                          "(pip install -e \".[ray]\", or run from another folder)")
    started = not ray.is_initialized()
    if started:
        ray.init(address=None if address == "local" else address, include_dashboard=False, log_to_driver=False)
    try:
        task = ray.remote(num_cpus=1)(run_sequence)
        pending = {task.remote(*job, cfg): job for job in todo}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            yield pending.pop(ready[0]), ray.get(ready[0])
    finally:
        if started:
            ray.shutdown()


def aggregate(results: list[dict], cfg: SensiacLikeConfig) -> dict:
    """The experiment's tables from the sequences' results (``results.json``'s "aggregate").

    Returns {"recognition": {group: {range: {method: % of frames}}} (Table 6.1: its groups, then
    any other class the vehicles run belong to, a car say), "errors": {measure: {range: {method:
    mean over the vehicles with an estimate}}} (Fig. 6.8), "frames_per_second": {method: all frames
    over all seconds}}; groups and ranges without a sequence are left out of recognition, as are
    vehicles of a class the model does not know. A vehicle never tracked counts as 0 % recognised
    but has no errors, so an error mean can cover fewer vehicles than its range ran (the report
    says how many).
    """
    # A vehicle of a class the model does not know ("unknown" meshes too) has no recognition (None), not 0 %.
    scored = [r for r in results if r["methods"][cfg.methods[0]]["metrics"]["recognition_accuracy"] is not None]
    present = {r["class"] for r in scored}
    recognition: dict = {}
    for group in [g for g in GROUPS if g in present] + sorted(present - set(GROUPS)):
        for range_m in cfg.ranges_m:
            cell = [r for r in scored if r["class"] == group and r["range_m"] == range_m]
            if cell:
                recognition.setdefault(group, {})[f"{range_m:g}"] = {
                    m: 100 * float(np.mean([r["methods"][m]["metrics"]["recognition_accuracy"] for r in cell]))
                    for m in cfg.methods}
    errors: dict = {}
    for measure in ("horizontal_error_m", "range_error_m", "aspect_error_rad"):
        for range_m in cfg.ranges_m:
            cell = [r for r in results if r["range_m"] == range_m]
            values = {m: [r["methods"][m]["metrics"][measure] for r in cell] for m in cfg.methods}
            errors.setdefault(measure, {})[f"{range_m:g}"] = {
                m: mean_or_none(vs) for m, vs in values.items()}
    fps = {m: pooled_frames_per_second([r["methods"][m]["metrics"] for r in results]) for m in cfg.methods}
    return {"recognition": recognition, "errors": errors, "frames_per_second": fps}
