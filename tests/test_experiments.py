"""python -m torch_atr.experiments sensiac-like, CI-sized: every method, resumable, a report that
agrees with its sequences."""

import dataclasses
import json
import os
import re
import sys
import types
from pathlib import Path

import numpy as np
import pytest
import torch

from torch_atr.data.synthetic import SyntheticSequence
from torch_atr.experiments.__main__ import main
from torch_atr.experiments.report import REPORT_FORMAT, THESIS_TABLE_6_1
from torch_atr.io import RUN_CLAIM, write_claim
from torch_atr.experiments.sensiac_like import FULL, RANGES_M, TEST_VEHICLES, SensiacLikeConfig, scene
from torch_atr.pose import body_to_world

QUICK = ["sensiac-like", "--quick", "--workers", "1", "--frames", "16", "--particles", "200"]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("exp") / "quick"
    agg = main([*QUICK, "--out", str(out)])
    return out, agg


def test_the_quick_run_reports_every_method_and_range(run):
    out, agg = run
    names = {p.name for p in out.iterdir()}
    assert {"report.md", "results.json", "errors_by_range.png", "identity_1000m.png", "sequences"} <= names
    results = json.loads((out / "results.json").read_text())
    assert results["format"] == "torch_atr.sensiac_like_report" and len(results["sequences"]) == 2
    for seq in results["sequences"]:
        assert set(seq["methods"]) == {"I", "II", "III", "IV"}
        for method in seq["methods"].values():
            assert len(method["alpha"]) == 16 and method["metrics"]["frames"] == 16
    # The aggregate is the mean of its sequences (one vehicle: equal to it).
    for seq in results["sequences"]:
        r = f"{seq['range_m']:g}"
        for m, method in seq["methods"].items():
            assert agg["recognition"]["tank"][r][m] == pytest.approx(100 * method["metrics"]["recognition_accuracy"])
            assert agg["errors"]["range_error_m"][r][m] == pytest.approx(method["metrics"]["range_error_m"])
    report = (out / "report.md").read_text()
    assert "| 1000 (thesis, SENSIAC) | " + "/".join(map(str, THESIS_TABLE_6_1["1000"]["tank"])) in report


def test_a_second_run_resumes_without_re_running(run):
    out, agg = run
    stamps = {p.name: p.stat().st_mtime_ns for p in (out / "sequences").iterdir()}
    again = main([*QUICK, "--out", str(out)])
    assert {p.name: p.stat().st_mtime_ns for p in (out / "sequences").iterdir()} == stamps
    assert again == agg


def test_other_configs_and_foreign_folders_are_refused(run, tmp_path):
    out, _ = run
    with pytest.raises(ValueError, match="another configuration"):
        main([*QUICK[:-2], "--particles", "100", "--out", str(out)])
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    with pytest.raises(OSError, match="not an experiment's folder"):
        main([*QUICK, "--out", str(foreign)])
    assert os.listdir(foreign) == ["notes.txt"]


def test_another_seed_or_start_is_refused_not_added_beside_the_run(run):
    """The result files are named by seed and start: another seed's found none of its own and ran,
    mixing two runs in one folder and replacing the first's report."""
    out, _ = run
    before = sorted(os.listdir(out / "sequences"))
    report = (out / "report.md").read_text()
    for other in (["--seed", "1"], ["--init", "truth"]):
        with pytest.raises(ValueError, match="another configuration; use another --out"):
            main([*QUICK, *other, "--out", str(out)])
    assert sorted(os.listdir(out / "sequences")) == before and (out / "report.md").read_text() == report


@pytest.mark.parametrize("damage", ['{"format": "torch_atr.sensiac_like_seq', "[1, 2]", "\udcff",
                                    '{"seed": ' + "1" * 5000 + "}"])  # past int's 4300 digits: a bare ValueError
def test_a_damaged_result_file_is_named(run, tmp_path, damage):
    """A result file cut short, or not a JSON object, raised json's bare error (or an AttributeError)
    naming no file: the resume names it."""
    import shutil

    out = shutil.copytree(run[0], tmp_path / "run")
    damaged = sorted((out / "sequences").glob("*.json"))[0]
    damaged.write_text(damage, encoding="utf-8", errors="surrogateescape")
    with pytest.raises(ValueError, match=f"{re.escape(str(damaged))} is not a result file"):
        main([*QUICK, "--out", str(out)])


def test_hidden_files_in_sequences_are_not_result_files(run, tmp_path):
    """macOS's ._NAME.json beside each file copied to an exFAT drive (binary, not JSON) stopped the
    resume with "is not a result file"; hidden files are not results."""
    import shutil

    out = shutil.copytree(run[0], tmp_path / "run")
    for path in sorted((out / "sequences").glob("*.json")):
        (path.parent / f"._{path.name}").write_bytes(b"\x00\x05\x16\x07\x00\x02\x00\x00Mac OS X        ")
    assert main([*QUICK, "--out", str(out)]) == run[1]


def test_another_experiment_is_refused_a_runs_folder_finished_or_not(run, tmp_path):
    """The visible band run into a SENSIAC-like folder ran and replaced its report and results.json."""
    import shutil

    out, _ = run
    visible = ["visible", "--quick", "--workers", "1", "--frames", "2", "--particles", "20", "--methods", "I"]
    finished = shutil.copytree(out, tmp_path / "finished")
    with pytest.raises(OSError, match="holds another experiment's report .*format torch_atr.sensiac_like_report"):
        main([*visible, "--out", str(finished)])
    interrupted = _interrupted(out, tmp_path / "interrupted")
    with pytest.raises(OSError, match="holds another experiment's unfinished run .*torch_atr.sensiac_like_report"):
        main([*visible, "--out", str(interrupted)])
    for folder in (finished, interrupted):
        assert sorted(os.listdir(folder / "sequences")) == sorted(os.listdir(out / "sequences"))
    assert sorted(os.listdir(finished)) == sorted(os.listdir(out))
    assert sorted(os.listdir(interrupted)) == [RUN_CLAIM, "sequences"]
    assert (finished / "report.md").read_text() == (out / "report.md").read_text()


def _interrupted(run: Path, folder: Path) -> Path:
    """A copy of a finished run as its interruption left it: the claim and sequences/, no report."""
    import shutil

    shutil.copytree(run / "sequences", folder / "sequences")
    shutil.copy(run / RUN_CLAIM, folder)
    return folder


def test_a_users_folder_holding_sequences_is_not_taken_for_an_interrupted_run(tmp_path):
    """Any folder with a sequences/ subfolder passed for an experiment's interrupted run: a user's
    report.md and results.json beside their own sequences/ were replaced without a word."""
    mine = tmp_path / "mydata"
    (mine / "sequences").mkdir(parents=True)
    (mine / "report.md").write_text("my notes")
    (mine / "results.json").write_text('{"mine": 1}')
    with pytest.raises(OSError, match=re.escape(f"{mine} exists and is not an experiment's folder")):
        main([*QUICK, "--out", str(mine)])
    assert sorted(os.listdir(mine)) == ["report.md", "results.json", "sequences"]
    assert (mine / "report.md").read_text() == "my notes" and not any((mine / "sequences").iterdir())
    track_run = tmp_path / "track_run"  # the claim file is shared with track.py: its run is not an experiment's
    track_run.mkdir()
    write_claim(track_run, "tracking run")
    with pytest.raises(OSError, match=re.escape(f"{track_run} exists and is not an experiment's folder")):
        main([*QUICK, "--out", str(track_run)])


def test_an_interrupted_run_is_not_claimed_by_an_experiment_of_another_layout(run, tmp_path):
    """The studies run into an interrupted SENSIAC-like folder (sequences/, no results.json) ran,
    wrote its report there, and the SENSIAC-like run was then refused its own folder; so did
    sensiac-like into an interrupted studies folder and all into either."""
    from torch_atr.experiments.studies import STUDIES_FORMAT

    out, _ = run
    sensiac = _interrupted(out, tmp_path / "sensiac")
    studies = tmp_path / "studies"
    (studies / "baseline" / "sequences").mkdir(parents=True)
    write_claim(studies, STUDIES_FORMAT)
    cases = [(["studies", "--quick"], sensiac, REPORT_FORMAT), (["all", "--quick"], sensiac, REPORT_FORMAT),
             (QUICK, studies, STUDIES_FORMAT), (["all", "--quick"], studies, STUDIES_FORMAT)]
    for argv, folder, theirs in cases:
        with pytest.raises(OSError, match=re.escape(f"unfinished run ({folder / RUN_CLAIM}: {theirs})")):
            main([*argv, "--out", str(folder)])
    assert sorted(os.listdir(sensiac)) == [RUN_CLAIM, "sequences"]
    assert sorted(os.listdir(studies)) == [RUN_CLAIM, "baseline"]
    assert sorted(os.listdir(sensiac / "sequences")) == sorted(os.listdir(out / "sequences"))


def _job_or_fail(name: str, _: float, folder) -> str:
    """A job for in_processes: "fail" raises; any other leaves a file ``name`` in ``folder``."""
    import time

    if name == "fail":
        raise ValueError("this job fails")
    time.sleep(0.2)
    (folder / name).write_text(name)
    return name


def test_a_failed_sequence_cancels_the_sequences_not_started(tmp_path):
    """A failure (or Ctrl-C) in a run of worker processes waited for every sequence still queued to
    run to its end, each result then thrown away."""
    from torch_atr.experiments.sensiac_like import in_processes

    todo = [("fail", 0.0), *((f"job{i}", 0.0) for i in range(40))]
    with pytest.raises(ValueError, match="this job fails"):
        for _ in in_processes(todo, tmp_path, 2, run=_job_or_fail):
            pass
    assert len(os.listdir(tmp_path)) <= 8  # those running or already handed to the 2 workers' queue: not 40


def _frames_with_vehicle_in_view(vehicle: str, cfg: SensiacLikeConfig, range_m: float) -> np.ndarray:
    """Whether each frame's whole vehicle (its convex hull's vertices, projected) lies in the image."""
    seq = SyntheticSequence(vehicle, scene(range_m, cfg))
    hull = torch.as_tensor(np.asarray(seq.vehicle.mesh.convex_hull.vertices))
    cam = seq.camera
    last = torch.tensor([cam.width - 1.0, cam.height - 1.0], dtype=hull.dtype)
    inside = []
    for i in range(len(seq)):
        R, t = body_to_world(seq.pose(i))
        uv, _ = cam.project(hull @ R.T + t)
        inside.append(bool(((uv >= 0) & (uv <= last)).all()))
    return np.array(inside)


def test_full_runs_keep_every_vehicle_in_view_for_a_whole_lap():
    cfg = SensiacLikeConfig(**FULL)
    near = min(RANGES_M)
    for vehicle in TEST_VEHICLES:
        assert _frames_with_vehicle_in_view(vehicle, cfg, near).all(), vehicle
    sc = scene(near, cfg)
    assert sc.frames / sc.fps * sc.speed_mps / sc.radius_m > 2 * np.pi  # every aspect is seen
    # The default 100 m circle would lose the vehicle within the 1000 frames (the check can fail).
    wide = dataclasses.replace(cfg, circle_diameter_m=100.0)
    assert not _frames_with_vehicle_in_view("t_72", wide, near).all()


def test_unseen_meshes_are_tracked_and_reported_by_class(tmp_path):
    out = tmp_path / "unseen"
    agg = main(["unseen", "--quick", "--workers", "1", "--frames", "12", "--particles", "200", "--out", str(out)])
    results = json.loads((out / "results.json").read_text())
    assert results["format"] == "torch_atr.unseen_report"
    by_mesh = {r["vehicle"]: r for r in results["sequences"]}
    tank, truck = by_mesh["heldout:tank/quaternius_tank1.obj"], by_mesh["heldout:truck/gazebo_fire_truck.obj"]
    assert (tank["class"], truck["class"]) == ("tank", "unknown")  # the manifest's classes
    accuracy = tank["methods"]["I"]["metrics"]["recognition_accuracy"]
    assert agg["meshes"][tank["vehicle"]]["recognition"]["1000"]["I"] == pytest.approx(100 * accuracy)
    assert agg["classes"] == {"tank": {"1000": {"I": pytest.approx(100 * accuracy)}}}
    assert agg["meshes"][truck["vehicle"]]["recognition"]["1000"]["I"] is None
    report = (out / "report.md").read_text()
    assert "| truck/gazebo_fire_truck.obj | " + ", ".join(truck["methods"]["I"]["metrics"]["best_matches"]) in report
    with pytest.raises(ValueError, match="not in the held-out manifest"):
        main(["unseen", "--quick", "--vehicles", "heldout:tank/nope.obj", "--workers", "1", "--out",
              str(tmp_path / "bad")])


def test_the_unseen_report_names_a_catalog_vehicle_whole(tmp_path):
    """``unseen --vehicles t_72 heldout:tank/...``: every name lost its first 8 characters, the
    length of "heldout:", so the catalog T-72's row was named "" (made-up results: nothing is tracked)."""
    from torch_atr.experiments.report import MEASURES
    from torch_atr.experiments.unseen import write_unseen_report

    cfg = SensiacLikeConfig(vehicles=("t_72", "heldout:tank/quaternius_tank1.obj"), ranges_m=(1000.0,), methods=("I",))
    metrics = {"recognition_accuracy": 0.5, "best_matches": ["t_72", "m1a1"], **{k: 1.0 for k, _ in MEASURES}}
    results = [{"vehicle": name, "class": "tank", "range_m": 1000.0, "methods": {"I": {"metrics": metrics}}}
               for name in cfg.vehicles]
    write_unseen_report(tmp_path, cfg, results, wall_s=1.0)
    report = (tmp_path / "report.md").read_text()
    for shown in ("t_72", "tank/quaternius_tank1.obj"):
        assert f"\n| {shown} | tank | 50 |" in report, shown


def test_the_unseen_reports_best_matches_are_at_the_nearest_range(tmp_path):
    """Ranges listed far first: the per-mesh best matches were the first range's (3000 m), the
    docstring's "nearest range" is 1000 m."""
    from torch_atr.experiments.report import MEASURES
    from torch_atr.experiments.unseen import write_unseen_report

    mesh = "heldout:tank/quaternius_tank1.obj"
    cfg = SensiacLikeConfig(vehicles=(mesh,), ranges_m=(3000.0, 1000.0), methods=("I",))
    matches = {3000.0: ["m4_sherman", "t_55"], 1000.0: ["m1a2_abrams", "m2_bradley"]}
    results = [{"vehicle": mesh, "class": "tank", "range_m": r, "methods": {"I": {"metrics": {
        "recognition_accuracy": 0.5, "best_matches": matches[r], **{k: 1.0 for k, _ in MEASURES}}}}}
        for r in cfg.ranges_m]
    write_unseen_report(tmp_path, cfg, results, wall_s=1.0)
    row = next(line for line in (tmp_path / "report.md").read_text().splitlines()
               if line.startswith("| tank/quaternius_tank1.obj | tank |"))
    assert row.endswith("| m1a2_abrams, m2_bradley |"), row


def test_two_jobs_that_would_share_a_result_file_are_refused(monkeypatch):
    """Results are filed as job_name (a held-out path with '/' and ' ' flattened to '_') and tabled by
    f"{range:g}": 'a b.obj' and 'a_b.obj', or 1000 and 1000.0000001 m, shared a file (the second
    overwrote the first; a resume read one for both)."""
    from torch_atr.config import ConfigError
    from torch_atr.experiments import sensiac_like

    with pytest.raises(ConfigError, match=r"^vehicles and ranges_m: \('t_72', 1000.0\) and \('t_72', 1000.0000001\) "
                                          r"would share the result file 't_72_1000m_blind_seed0'"):
        SensiacLikeConfig(vehicles=("t_72",), ranges_m=(1000.0, 1000.0000001))
    monkeypatch.setattr(sensiac_like, "check_vehicle", lambda vehicle: None)  # two manifest entries, say
    with pytest.raises(ConfigError, match=r"\('heldout:car/a b.obj', 1000.0\) and \('heldout:car/a_b.obj', 1000.0\)"):
        SensiacLikeConfig(vehicles=("heldout:car/a b.obj", "heldout:car/a_b.obj"), ranges_m=(1000.0,))


def test_a_bad_frame_or_particle_count_is_named():
    """The line read 'frames in [1, 1e5] and particles in [1, 1e7]; got 0, 1000', naming neither."""
    from torch_atr.config import ConfigError

    with pytest.raises(ConfigError, match=r"^frames must be in \[1, 100000\]; got 0$"):
        SensiacLikeConfig(frames=0)
    with pytest.raises(ConfigError, match=r"^particles must be in \[1, 10000000\]; got 20000000$"):
        SensiacLikeConfig(particles=20_000_000)


def test_a_vehicle_or_range_listed_twice_is_one_job():
    """'--vehicles t_72 t_72' ran each sequence twice (run_all's jobs are vehicles × ranges) and
    weighed it twice in the means; the repeats go, the order stays."""
    cfg = SensiacLikeConfig(vehicles=("t_72", "bmp_2", "t_72"), ranges_m=(1500.0, 1000.0, 1500.0))
    assert (cfg.vehicles, cfg.ranges_m) == (("t_72", "bmp_2"), (1500.0, 1000.0))


def test_a_folder_named_ray_is_not_taken_for_ray(tmp_path, monkeypatch):
    """Run from a folder holding a folder 'ray' (an earlier --out ray), 'import ray' found that folder
    and --ray failed with AttributeError: module 'ray' has no attribute 'is_initialized'."""
    from torch_atr.config import ConfigError
    from torch_atr.experiments.sensiac_like import _on_ray

    folder = types.ModuleType("ray")  # what 'import ray' makes of a folder: a namespace package
    folder.__path__ = [str(tmp_path / "ray")]
    monkeypatch.setitem(sys.modules, "ray", folder)  # put back as it was, Ray installed or not
    with pytest.raises(ConfigError, match=f"found the folder {re.escape(str(tmp_path / 'ray'))}, not the package"):
        next(_on_ray([], SensiacLikeConfig(), "local"))


@pytest.mark.slow
def test_a_local_ray_cluster_gives_the_processes_results(run, tmp_path):
    pytest.importorskip("ray")
    out, _ = run
    on_ray = tmp_path / "ray"
    main([*QUICK, "--ray", "local", "--out", str(on_ray)])
    for path in (out / "sequences").iterdir():
        here, there = (json.loads(p.read_text()) for p in (path, on_ray / "sequences" / path.name))
        for r in (here, there):
            r.pop("wall_s")
            for method in r["methods"].values():
                method["metrics"].pop("frames_per_second")
        assert here == there, path.name


def test_scene_overrides_reach_the_simulator_and_bad_ones_name_their_key():
    from torch_atr.config import ConfigError
    from torch_atr.data.synthetic import SceneConfig

    cfg = SensiacLikeConfig(scene=("night=false", "occluder_width_m=3"), frames=40)
    assert scene(1500.0, cfg) == SceneConfig(range_m=1500.0, frames=40, night=False, occluder_width_m=3.0)
    with pytest.raises(ConfigError, match="--scene nite=1: unknown config key"):
        SensiacLikeConfig(scene=("nite=1",))
    with pytest.raises(ConfigError, match="sets the grid itself"):
        SensiacLikeConfig(scene=("range_m=500",))
    # The tracker's overrides are checked as the config is made, not once a worker has built its scene.
    with pytest.raises(ConfigError, match="override bogus.key=1: unknown config key"):
        SensiacLikeConfig(tracker=("bogus.key=1",))


def test_each_study_changes_one_thing_and_its_rows_average_its_sequences(tmp_path):
    from torch_atr.experiments.studies import run_studies, study_configs, write_studies_report

    configs = study_configs(quick=True)
    base = dataclasses.asdict(configs["baseline"])
    changed = {name: {k for k, v in dataclasses.asdict(cfg).items() if v != base[k]} for name, cfg in configs.items()}
    assert changed == {"baseline": set(), "particles_250": {"particles"}, "particles_4000": {"particles"},
                       "particles_16000": {"particles"}, "range_4000_5000": {"ranges_m"}, "day": {"scene"},
                       "occlusion": {"scene"}, "turret": {"scene"}}
    assert not scene(1000.0, configs["day"]).night and scene(1000.0, configs["occlusion"]).occluder_width_m == 12
    two = {name: dataclasses.replace(configs[name], frames=8) for name in ("baseline", "day")}
    results = run_studies(tmp_path / "studies", two, workers=1)
    rows = write_studies_report(tmp_path / "studies", two, results, wall_s=1.0)
    for row in rows:
        (seq,) = [json.loads(p.read_text()) for p in (tmp_path / "studies" / row["setting"] / "sequences").iterdir()]
        metrics = seq["methods"]["I"]["metrics"]
        assert row["recognition_pct"] == pytest.approx(100 * (metrics["recognition_accuracy"] or 0))
        assert row["range_error_m"] == pytest.approx(metrics["range_error_m"])
    assert json.loads((tmp_path / "studies" / "results.json").read_text())["format"] == "torch_atr.studies_report"
    assert "| day scene (low contrast) | 1000 |" in (tmp_path / "studies" / "report.md").read_text()
    with pytest.raises(ValueError, match="--particles cannot be given"):
        main(["studies", "--quick", "--particles", "10", "--out", str(tmp_path / "bad")])


@pytest.mark.slow
def test_the_quick_studies_run_every_setting(tmp_path):
    rows = main(["studies", "--quick", "--workers", "1", "--out", str(tmp_path / "studies")])
    assert [(r["setting"], r["range_m"]) for r in rows] == [
        ("baseline", 1000.0), ("particles_250", 1000.0), ("particles_4000", 1000.0), ("particles_16000", 1000.0),
        ("range_4000_5000", 4000.0), ("day", 1000.0), ("occlusion", 1000.0), ("turret", 1000.0)]


def test_a_range_the_scene_refuses_fails_before_any_sequence_or_folder(tmp_path):
    """``--ranges 1000 10`` ran the 1000 m sequence and failed in the 10 m one's worker, leaving a run folder."""
    with pytest.raises(ValueError, match=r"range_m=10.0 \(expected at most 100 km, more than circle_diameter_m"):
        main([*QUICK, "--ranges", "1000", "10", "--out", str(tmp_path / "out")])
    with pytest.raises(ValueError, match="range_m=200000.0"):
        SensiacLikeConfig(ranges_m=(200_000.0,))
    assert os.listdir(tmp_path) == []


def test_a_negative_worker_count_is_named_before_a_folder_is_made(tmp_path):
    for experiment in (QUICK, ["visible", "--quick"], ["all", "--quick"]):
        with pytest.raises(ValueError, match=r"--workers must be 0 \(one per core\) or more; got -1"):
            main([*experiment, "--workers", "-1", "--out", str(tmp_path / "out")])
    assert os.listdir(tmp_path) == []


def test_tracker_overrides_after_the_options_reach_the_tracker(tmp_path):
    """``... --out DIR key=value``, as the README writes it: the override is parsed (argparse's
    plain parse_args left it to no argument and exited) and a bad key is named."""
    from torch_atr.config import ConfigError

    with pytest.raises(ConfigError, match="unknown config key.*init.nope"):
        main([*QUICK, "--out", str(tmp_path / "bad"), "init.nope=1"])


def test_the_combined_report_nests_each_report_and_points_into_its_folder(tmp_path):
    from torch_atr.experiments.combined import write_combined_report

    for name, fmt in (("a", "torch_atr.x"), ("b", "torch_atr.y")):
        (tmp_path / name).mkdir()
        (tmp_path / name / "report.md").write_text(f"# {name}\n\n## Table\n\n![fig](fig.png) [site](https://x.org) "
                                                   f"[here](#table)\n\n```\n# not a heading\n```\n")
        (tmp_path / name / "results.json").write_text(json.dumps({"format": fmt}))
    write_combined_report(tmp_path, ("a", "b"), wall_s=3.0)
    text = (tmp_path / "report.md").read_text()
    assert ("\n## a\n\n### Table\n\n![fig](a/fig.png) [site](https://x.org) [here](#table)\n\n```\n# not a heading\n```"
            in text)
    assert "![fig](b/fig.png)" in text and text.index("## a") < text.index("## b")
    assert json.loads((tmp_path / "results.json").read_text())["experiments"] == {
        "a": {"results": "a/results.json", "format": "torch_atr.x"},
        "b": {"results": "b/results.json", "format": "torch_atr.y"}}
    (tmp_path / "b" / "report.md").unlink()
    with pytest.raises(FileNotFoundError, match="b/report.md: the b experiment wrote no report"):
        write_combined_report(tmp_path, ("a", "b"), wall_s=3.0)
    with pytest.raises(ValueError, match="all: --frames cannot be given"):
        main(["all", "--frames", "10", "--out", str(tmp_path / "c")])
    with pytest.raises(ValueError, match=r"all: tracker overrides \(key=value\) cannot be given"):
        main(["all", "--out", str(tmp_path / "c"), "init.ground_row=null"])


@pytest.mark.slow
def test_all_quick_runs_every_experiment_into_one_report(tmp_path):
    main(["all", "--quick", "--workers", "1", "--out", str(tmp_path / "all")])
    text = (tmp_path / "all" / "report.md").read_text()
    for name in ("sensiac-like", "unseen", "visible", "studies"):
        assert (tmp_path / "all" / name / "results.json").is_file()
    assert "](sensiac-like/errors_by_range.png)" in text and text.count("\n## ") >= 4


def test_study_labels_name_the_particles_and_ranges_each_run_ran(tmp_path):
    """A quick run's rows said "16 000 particles" for a run of 800: the labels come from the configs."""
    from torch_atr.experiments.report import MEASURES
    from torch_atr.experiments.studies import study_configs, study_label, write_studies_report

    full, quick = study_configs(), study_configs(quick=True)
    assert study_label("particles_16000", full["particles_16000"]) == "16000 particles"
    assert study_label("range_4000_5000", full["range_4000_5000"]) == "4000-5000 m"
    assert study_label("range_4000_5000", quick["range_4000_5000"]) == "4000 m"
    for name, cfg in quick.items():
        if name == "baseline" or name.startswith("particles"):
            assert study_label(name, cfg).split(", ")[-1] == f"{cfg.particles} particles", name
    assert [cfg.particles for cfg in quick.values()][:4] == [200, 100, 400, 800]  # not the full run's counts
    # The report's rows and results.json carry the same labels (made-up results: nothing is tracked).
    metrics = {"recognition_accuracy": 0.5, "frames_per_second": 10.0, "frames": 20,
               **{k: 1.0 for k, _ in MEASURES}}
    results = {name: [{"range_m": cfg.ranges_m[0], "methods": {"I": {"metrics": metrics}}}]
               for name, cfg in quick.items()}
    rows = write_studies_report(tmp_path, quick, results, wall_s=1.0)
    assert [r["change"] for r in rows] == [  # the quick configs' counts and range, written out
        "night, 200 particles", "100 particles", "400 particles", "800 particles", "4000 m", "day scene (low contrast)",
        "12 m x 1 m berm in front", "turrets sweeping ±60°"]
    assert [r["change"] for r in json.loads((tmp_path / "results.json").read_text())["rows"]] == [
        r["change"] for r in rows]
    report = (tmp_path / "report.md").read_text()
    assert "| night, 200 particles | 1000 |" in report and "| 800 particles | 1000 |" in report
    assert "| 4000 m | 4000 |" in report and "16000" not in report and "250 particles" not in report


def test_study_rows_leave_out_vehicles_without_a_true_class(tmp_path):
    """A vehicle of a class the model does not know (recognition None, as the unseen truck) counted as
    0 % recognised: a row of a tank at 50 % and a truck read 25 %, and a truck alone 0 %."""
    from torch_atr.experiments.report import MEASURES
    from torch_atr.experiments.studies import study_configs, write_studies_report

    configs = study_configs(quick=True)
    configs = {name: configs[name] for name in ("baseline", "day")}

    def seq(range_m: float, accuracy: float | None) -> dict:
        metrics = {"recognition_accuracy": accuracy, "frames_per_second": 10.0, "frames": 20,
                   **{k: 1.0 for k, _ in MEASURES}}
        return {"range_m": range_m, "methods": {"I": {"metrics": metrics}}}

    results = {"baseline": [seq(1000.0, 0.5), seq(1000.0, None)], "day": [seq(1000.0, None)]}
    rows = write_studies_report(tmp_path, configs, results, wall_s=1.0)
    assert [(r["setting"], r["sequences"], r["recognition_pct"]) for r in rows] == [
        ("baseline", 2, pytest.approx(50.0)), ("day", 1, None)]
    report = (tmp_path / "report.md").read_text()
    assert "| night, 200 particles | 1000 | 50 |" in report and "| day scene (low contrast) | 1000 | — |" in report


def test_recognition_gives_other_classes_their_own_column_beside_table_6_1s():
    """Table 6.1 has tanks, APCs, SUVs and pick-ups only; a car run in the grid was left out of the
    recognition table without a word. It gets its own column (no thesis number); a vehicle of a
    class the model does not know stays out."""
    from torch_atr.experiments.report import _recognition_table
    from torch_atr.experiments.sensiac_like import aggregate

    cfg = SensiacLikeConfig(vehicles=("t_72", "toyota_camry"), ranges_m=(1000.0,))

    def seq(cls: str, accuracy: float | None) -> dict:
        metrics = {"recognition_accuracy": accuracy, "frames_per_second": 10.0, "frames": 20,
                   "horizontal_error_m": 1.0,
                   "range_error_m": 1.0, "aspect_error_rad": 0.1}
        return {"class": cls, "range_m": 1000.0, "methods": {m: {"metrics": metrics} for m in cfg.methods}}

    agg = aggregate([seq("car", 0.25), seq("tank", 0.5), seq("unknown", None)], cfg)
    assert list(agg["recognition"]) == ["tank", "car"]
    assert agg["recognition"]["car"]["1000"] == dict.fromkeys(cfg.methods, pytest.approx(25.0))
    assert _recognition_table(agg, cfg) == ["| range (m) | Tanks | car |", "|---|---|---|",
                                             "| 1000 (ours) | 50/50/50/50 | 25/25/25/25 |",
                                             "| 1000 (thesis, SENSIAC) | 96/94/91/90 | — |"]


def test_recognition_leaves_out_vehicles_of_a_class_the_model_does_not_know():
    """A checkpoint without the car class scores a car's frames None (recognition_accuracy); the
    table counted it as 0 % recognised, a column of cars at 0 and a tank beside it at 50 read 25."""
    from torch_atr.experiments.report import mean_recognition
    from torch_atr.experiments.sensiac_like import aggregate

    cfg = SensiacLikeConfig(vehicles=("t_72", "toyota_camry"), ranges_m=(1000.0,), methods=("I",))

    def seq(cls: str, accuracy: float | None) -> dict:
        metrics = {"recognition_accuracy": accuracy, "frames_per_second": 10.0, "frames": 20,
                   "horizontal_error_m": 1.0,
                   "range_error_m": 1.0, "aspect_error_rad": 0.1}
        return {"class": cls, "range_m": 1000.0, "methods": {"I": {"metrics": metrics}}}

    agg = aggregate([seq("tank", 0.5), seq("car", None), seq("unknown", None)], cfg)
    assert agg["recognition"] == {"tank": {"1000": {"I": pytest.approx(50.0)}}}
    assert mean_recognition(agg) == {"I": pytest.approx(50.0)}
    assert agg["errors"]["horizontal_error_m"]["1000"] == {"I": pytest.approx(1.0)}  # the errors keep every vehicle


def test_the_default_checkpoint_is_found_from_any_folder_and_a_missing_one_makes_no_folder(tmp_path, monkeypatch):
    """From another folder, "checkpoints/default.pt" failed, once OUT/sequences/ had been made."""
    from torch_atr.experiments.sensiac_like import REPO, resolve_checkpoint

    monkeypatch.chdir(tmp_path)
    assert resolve_checkpoint("checkpoints/default.pt") == REPO / "checkpoints" / "default.pt"
    SensiacLikeConfig(vehicles=("t_72",))  # the default checkpoint passes the config's check from here
    (tmp_path / "checkpoints").mkdir()
    (tmp_path / "checkpoints" / "default.pt").write_bytes(b"mine")
    mine = (tmp_path / "checkpoints" / "default.pt").resolve()
    assert resolve_checkpoint("checkpoints/default.pt").resolve() == mine  # as given wins, as track.py's
    with pytest.raises(FileNotFoundError, match=r"checkpoint not found: nope.pt \(neither from ") as missing:
        resolve_checkpoint("nope.pt")
    assert f"from {os.getcwd()} nor from {REPO})" in str(missing.value)
    for experiment in ("sensiac-like", "unseen", "studies", "visible", "all"):
        with pytest.raises(FileNotFoundError, match="checkpoint not found: nope.pt"):
            main([experiment, "--quick", "--checkpoint", "nope.pt", "--out", "out"])
    with pytest.raises(ValueError, match="vehicles: Unknown vehicle 'nope'"):
        main(["sensiac-like", "--quick", "--vehicles", "nope", "--out", "out"])
    with pytest.raises(ValueError, match="not in the held-out manifest"):
        main(["unseen", "--quick", "--vehicles", "heldout:tank/nope.obj", "--out", "out"])
    assert sorted(os.listdir(tmp_path)) == ["checkpoints"]  # no run folder


def test_report_figures_start_at_zero_key_classes_as_alpha_over_time_and_count_one_vehicle():
    """identity_1000m.png started at −0.04 s and keyed the class arcs in arc order (apc, minivan, …)
    where alpha_over_time.png keys them in class order; errors_by_range.png said "the 1 test vehicles".
    The reference: the checkpoint's class names in order, and alpha_over_time.png's own legend."""
    from torch_atr.experiments.report import errors_figure, identity_figure
    from torch_atr.model import GenerativeShapeModel
    from torch_atr.viz import alpha_figure

    model = GenerativeShapeModel.from_checkpoint(Path(__file__).resolve().parents[1] / "checkpoints" / "default.pt")
    times = [i / 30 for i in range(16)]
    results = [{"range_m": 1000.0, "vehicle": v, "class": c,
                "methods": {"I": {"time_s": times, "alpha": [a] * 16, "metrics": {"best_matches": ["t_55", "t_72"]}}}}
               for v, c, a in (("t_72", "tank", 0.3), ("btr_70", "apc", None))]
    ax = identity_figure(results, model).axes[0]
    assert ax.get_xlim()[0] == 0.0 and ax.get_xlim()[1] == pytest.approx(15.5 / 30)
    arcs = [t.get_text() for t in ax.get_legend().get_texts()][:len(model.class_names)]
    assert arcs == [f"{name} arc" for name in model.class_names]
    rows = [{"frame": i, "time_s": t, "lost": 0, "alpha": 0.3} for i, t in enumerate(times)]
    keyed = [t.get_text() for t in alpha_figure(rows, model, "t").axes[0].get_legend().get_texts()]
    assert keyed[:len(model.class_names)] == arcs
    cfg = SensiacLikeConfig(vehicles=("t_72",), ranges_m=(1000.0,), methods=("I",), frames=16)
    measures = ("horizontal_error_m", "range_error_m", "aspect_error_rad")
    fig = errors_figure({"errors": {m: {"1000": {"I": 0.5}} for m in measures}}, cfg)
    assert fig._suptitle.get_text().startswith("Mean tracking errors over the 1 test vehicle per range (")
    cfg = dataclasses.replace(cfg, vehicles=("t_72", "btr_70"))
    fig = errors_figure({"errors": {m: {"1000": {"I": 0.5}} for m in measures}}, cfg)
    assert fig._suptitle.get_text().startswith("Mean tracking errors over the 2 test vehicles per range (")


def test_the_grids_rate_is_its_frames_over_its_seconds_and_its_errors_say_whom_they_average(tmp_path):
    """Two 150-frame sequences at 100 and 10 frames/s ran at 300 / 16.5 s = 18.2 frames/s; the mean of
    their rates put it at 55. A vehicle never tracked counts as 0 % recognised but has no errors: the
    report says the errors average the others."""
    from torch_atr.experiments.report import _error_coverage
    from torch_atr.experiments.sensiac_like import aggregate

    cfg = SensiacLikeConfig(vehicles=("t_72", "btr_70"), ranges_m=(1000.0,), methods=("I",))

    def seq(fps: float, tracked: bool) -> dict:
        errors = {k: (1.0 if tracked else None) for k in ("horizontal_error_m", "range_error_m", "aspect_error_rad")}
        metrics = {"recognition_accuracy": 1.0 if tracked else 0.0, "frames_per_second": fps, "frames": 150, **errors}
        return {"class": "tank", "range_m": 1000.0, "methods": {"I": {"metrics": metrics}}}

    results = [seq(100.0, True), seq(10.0, False)]
    agg = aggregate(results, cfg)
    assert agg["frames_per_second"]["I"] == pytest.approx(300 / (150 / 100 + 150 / 10))
    assert agg["recognition"]["tank"]["1000"]["I"] == pytest.approx(50.0)
    assert agg["errors"]["horizontal_error_m"]["1000"]["I"] == pytest.approx(1.0)
    assert _error_coverage(results, cfg) == [
        "- At 1000 m, Method I's errors average 1 of the 2 vehicles: the others had no estimate (recognition "
        "counts them as 0 %).", ""]
    assert _error_coverage(results[:1], cfg) == []
