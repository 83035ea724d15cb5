import math
from pathlib import Path

import numpy as np
import pytest
import torch

from torch_atr import viz
from torch_atr.model import GenerativeShapeModel

CKPT = Path(__file__).resolve().parents[1] / "checkpoints" / "default.pt"


def test_image_grid_figure_labels_every_row_and_column():
    images = torch.rand(2, 3, 8, 8).numpy()
    fig = viz.image_grid_figure(images, ["first", "second"], ["a", "b", "c"], "A title",
                                [("white", (1.0, 1.0, 1.0))], "views")
    axes = fig.axes
    assert len(axes) == 6 and "A title" in fig._suptitle.get_text() and "views" in fig._suptitle.get_text()
    assert [axes[0].get_ylabel(), axes[3].get_ylabel()] == ["first", "second"]
    assert [ax.get_title() for ax in axes[:3]] == ["a", "b", "c"]
    assert [t.get_text() for t in fig.legends[0].get_texts()] == ["white"]
    with pytest.raises(ValueError, match="2 row and 3 column labels"):
        viz.image_grid_figure(images, ["one"], ["a", "b", "c"], "t")


def test_sweeps_start_and_end_at_their_anchors():
    model = GenerativeShapeModel.from_checkpoint(CKPT)
    a = model.alphas[4].item()
    sweep = viz.view_sweep(model, a, 0.5, 0.1, 0.2, 0.15, between=2)
    assert sweep.shape[0] == 2 * 2 + 3
    ends = model.silhouette(torch.full((2,), a), torch.tensor([0.5, 0.7]), torch.tensor([0.1, 0.25]))
    assert torch.equal(sweep[0], ends[0]) and torch.equal(sweep[-1], ends[1])
    anchors = [model.alphas[k].item() for k in (5, 0, 2)]  # wraps past 2π
    sweep = viz.identity_sweep(model, anchors, math.radians(60), math.radians(10), between=3)
    assert sweep.shape[0] == 2 * 4 + 1
    for i, k in ((0, 5), (4, 0), (8, 2)):
        expected = model.silhouette(model.alphas[k:k + 1], torch.tensor([math.radians(60)]),
                                    torch.tensor([math.radians(10)]))[0]
        assert torch.equal(sweep[i], expected)


def test_overlay_colours_and_identity_figure():
    truth = torch.tensor([[[True, True, False, False]]])
    recon = torch.tensor([[[True, False, True, False]]])
    rgb = viz.overlay_pairs(truth, recon)[0, :, 0]  # (3, 4)
    assert rgb.T.tolist() == [[1, 1, 1], [1, 0, 0], [0, 1, 1], [0, 0, 0]]  # both, missed, extra, neither
    fig = viz.identity_circle_figure([0.0, 2.0], ["a", "b"], [0, 1], ["x", "y"], [(0, 5.0, 7.28), (1, 1.0, 5.0)])
    assert len(fig.axes) == 1


def test_track_figures_of_a_run_without_an_estimate_span_it_and_say_so():
    """A run in which no frame had a target: α over the run's 2 s, not an axis shrunk round nothing."""
    model = GenerativeShapeModel.from_checkpoint(CKPT)
    rows = [{"frame": i, "time_s": i / 30, "lost": 1, "mask_area_px": 0} for i in range(61)]
    alpha = viz.alpha_figure(rows, model, "empty")
    view = viz.view_figure(rows, "empty")
    assert alpha.axes[0].get_xlim() == pytest.approx((0.0, 2.0 + 1 / 60))
    for fig in (alpha, view):
        assert "no estimate" in " ".join(text.get_text() for text in fig.axes[0].texts)
    blank = np.zeros((40, 50), dtype=bool)
    shots = [{"frame": i, "image": np.zeros((40, 50), np.uint8), "mask": blank, "silhouette": blank} for i in (0, 5)]
    rows[5].update({"alpha": 0.3, "theta": 1.0, "phi": 0.1, "class": "tank"})
    strip = viz.frame_strip_figure(shots, rows, "strip")
    assert [ax.get_title() for ax in strip.axes] == ["frame 0: no estimate", "frame 5: tank\nα = 0.30"]
    assert not viz.alpha_figure(rows, model, "one").axes[0].texts


def test_frame_strip_gives_the_true_class_where_the_sequence_has_one():
    """An uncalibrated APC tracked as a car: every panel said 'car', and nothing on the figure showed it wrong."""
    blank = np.zeros((40, 50), dtype=bool)
    shots = [{"frame": i, "image": np.zeros((40, 50), np.uint8), "mask": blank, "silhouette": blank} for i in (0, 1)]
    rows = [{"frame": 0, "time_s": 0.0, "lost": 1, "true_class": "apc"},
            {"frame": 1, "time_s": 1 / 30, "lost": 0, "alpha": 4.2, "class": "car", "true_class": "apc"}]
    titles = [ax.get_title() for ax in viz.frame_strip_figure(shots, rows, "strip").axes]
    assert titles == ["frame 0: no estimate (true: apc)", "frame 1: car (true: apc)\nα = 4.20"]


def _sensiac_like_rows(n: int = 12) -> list[dict]:
    """Rows of a run whose truth (as SENSIAC's AGT files) has the aspect and class but no position
    or elevation: true_x, true_z and true_phi NaN."""
    return [{"frame": i, "time_s": i / 30, "lost": 0, "x": 1.0, "z": 900.0, "theta": 0.1 * i, "phi": 0.05,
             "alpha": 0.05, "class": "tank", "true_x": math.nan, "true_z": math.nan, "true_theta": 0.1 * i,
             "true_phi": math.nan, "true_class": "tank"} for i in range(n)]


def test_view_figure_shows_what_truth_there_is_and_keeps_it_in_view():
    """A truth without elevation is drawn as azimuth ticks, named so (it was a 'truth' key with
    nothing drawn); a truth elevation above the estimate's stays inside the axes."""
    legend = [t.get_text() for t in viz.view_figure(_sensiac_like_rows(), "sensiac").axes[0].get_legend().get_texts()]
    assert legend == ["estimate", "true azimuth (elevation unknown)"]
    rows = [{**row, "true_phi": math.radians(65.0)} for row in _sensiac_like_rows()]
    fig = viz.view_figure(rows, "high")
    assert [t.get_text() for t in fig.axes[0].get_legend().get_texts()] == ["estimate", "truth"]
    assert fig.axes[0].get_ylim()[1] > 65.0


def test_tensorboard_logs_errors_only_where_truth_and_estimate_are_known(tmp_path):
    """SENSIAC-like rows: the aspect error every frame, no horizontal or range error (they were NaN)."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from torch_atr.tracking.filter import TrackResult

    viz.log_track_tensorboard(tmp_path, TrackResult(_sensiac_like_rows(), [], 1.0), {})
    tags = EventAccumulator(str(tmp_path)).Reload().Tags()["scalars"]
    assert "error/aspect_rad" in tags and "error/horizontal_m" not in tags and "error/range_m" not in tags


def test_the_figures_a_run_writes_are_the_named_ones(tmp_path):
    """track.py and train.py replace only the figures named in viz (a user's own PNGs in the folder
    stay), so every figure a run draws must be among those names."""
    from torch_atr.tracking.filter import TrackResult

    model = GenerativeShapeModel.from_checkpoint(CKPT)
    rows = [{**row, "true_x": 0.5, "true_z": 900.0} for row in _sensiac_like_rows()]
    blank = np.zeros((40, 50), dtype=bool)
    shots = [{"frame": 0, "image": np.zeros((40, 50), np.uint8), "mask": blank, "silhouette": blank}]
    assert set(viz.track_figures(TrackResult(rows, shots, 1.0), model, "t")) == set(viz.TRACK_FIGURES)
    V = model.rbf.num_centres
    masks = torch.zeros(model.core.num_vehicles, V, model.template.size_px, model.template.size_px, dtype=torch.bool)
    theta, phi = model.rbf.centres_theta.double(), model.rbf.centres_phi.double()
    names = list(viz.model_figures(model, masks, theta, phi, math.radians(12), math.radians(10)))
    assert set(names) == set(viz.MODEL_FIGURES)


def _model_figures(model, step_deg: tuple[float, float], grid: tuple[torch.Tensor, torch.Tensor] | None = None):
    """viz.model_figures of the checkpoint, blank templates at its training views (or at ``grid``)."""
    theta, phi = grid or (model.rbf.centres_theta.double(), model.rbf.centres_phi.double())
    masks = torch.zeros(model.core.num_vehicles, len(theta), model.template.size_px, model.template.size_px,
                        dtype=torch.bool)
    return viz.model_figures(model, masks, theta, phi, *map(math.radians, step_deg))


def test_model_figures_refuse_views_that_are_not_the_masks_views():
    """θ, φ of one more view than the masks hold labelled the reconstructions with the wrong views."""
    model = GenerativeShapeModel.from_checkpoint(CKPT)
    V = model.rbf.num_centres
    masks = torch.zeros(model.core.num_vehicles, V, model.template.size_px, model.template.size_px, dtype=torch.bool)
    theta, phi = model.rbf.centres_theta.double(), model.rbf.centres_phi.double()
    longer = torch.cat([theta[:1], theta])
    with pytest.raises(ValueError, match=rf"Expected theta to have shape \({V}\); got \({V + 1},\)"):
        viz.model_figures(model, masks, longer, torch.cat([phi[:1], phi]), math.radians(12), math.radians(10))
    with pytest.raises(ValueError, match=rf"Expected phi to have shape \({V}\); got \({V}, 1\)"):
        viz.model_figures(model, masks, theta, phi[:, None], math.radians(12), math.radians(10))


def _grid_texts(fig) -> tuple[list[str], list[str]]:
    """An image grid's column titles and row labels."""
    axes = np.array(fig.axes).reshape(len([ax for ax in fig.axes if ax.get_ylabel()]), -1)
    return [ax.get_title() for ax in axes[0]], [ax.get_ylabel() for ax in axes[:, 0]]


def test_identity_sweeps_name_the_classes_at_each_border_and_mark_the_named_vehicles_columns():
    """Between classes the rows named only the vehicles ("chevrolet_silverado → fv101_scorpion"), not which
    classes meet; the columns ran 0/8 … 8/8 without saying which are the named training vehicles. The
    reference: the checkpoint's class of each vehicle named, and the named vehicle's own silhouette in
    its column."""
    model = GenerativeShapeModel.from_checkpoint(CKPT)
    figures = _model_figures(model, (12, 10))
    cls = {name: model.class_names[c] for name, c in zip(model.vehicle_names, model.vehicle_classes)}
    columns, rows = _grid_texts(figures["identity_sweeps_between_classes"])
    assert rows[0] == "pickup → tank: chevrolet_silverado → fv101_scorpion"
    for row in rows:
        classes, vehicles = row.split(": ")
        (a, b), (u, v) = classes.split(" → "), vehicles.split(" → ")
        assert (cls[u], cls[v]) == (a, b) and a != b
    assert columns == ["0/6\nvehicle 1", "1/6", "2/6", "3/6", "4/6", "5/6", "6/6\nvehicle 2"]
    fig = figures["identity_sweeps_within_class"]
    columns, rows = _grid_texts(fig)
    assert columns == ["0/8\nvehicle 1", "1/8", "2/8", "3/8", "4/8\nvehicle 2", "5/8", "6/8", "7/8",
                       "8/8\nvehicle 3"]
    assert "vehicle k: the row's k-th named vehicle" in fig._suptitle.get_text()
    names = rows[0].split(": ")[1].split(" → ")
    for column, name in zip((0, 4, 8), names):
        expected = model.silhouette(model.alphas[model.vehicle_names.index(name)][None],
                                    torch.tensor([math.radians(60)]), torch.tensor([math.radians(10)]))[0]
        np.testing.assert_array_equal(fig.axes[column].images[0].get_array(), expected.float().numpy())


def test_view_sweeps_give_each_columns_view_in_degrees_and_mark_the_training_views():
    """The columns said only θ₀ + 2/4·Δθ and the caption called every column interpolated. On the shipped
    grid (12° by 10°, by hand from (36°, 10°)) columns 1, 5 and 9 are training views; on a 60° by 20°
    grid none is."""
    model = GenerativeShapeModel.from_checkpoint(CKPT)
    fig = _model_figures(model, (12, 10))["view_sweeps"]
    assert _grid_texts(fig)[0] == ["36°, 10°\n(training)", "39°, 10°", "42°, 10°", "45°, 10°", "48°, 10°\n(training)",
                                   "48°, 12.5°", "48°, 15°", "48°, 17.5°", "48°, 20°\n(training)"]
    assert "(training): a training view, the others interpolated" in fig._suptitle.get_text()
    theta, phi = torch.meshgrid(torch.arange(0.0, 360.0, 60.0), torch.tensor([0.0, 20.0, 40.0]), indexing="ij")
    coarse = _model_figures(model, (60, 20), (torch.deg2rad(theta.flatten()), torch.deg2rad(phi.flatten())))
    assert _grid_texts(coarse["view_sweeps"])[0] == ["36°, 10°", "51°, 10°", "66°, 10°", "81°, 10°", "96°, 10°",
                                                    "96°, 15°", "96°, 20°", "96°, 25°", "96°, 30°"]


def _drawn_pixels(fig, colour: str) -> list[int]:
    """Per axes, the pixels of ``colour`` inside it, legends left out."""
    from matplotlib.colors import to_rgb

    for ax in fig.axes:
        ax.get_legend().remove()
    fig.canvas.draw()
    image = np.asarray(fig.canvas.buffer_rgba())[..., :3].astype(int)
    hit = (np.abs(image - np.array(to_rgb(colour)) * 255).max(axis=2) < 40)[::-1]  # rows from the bottom
    counts = []
    for ax in fig.axes:
        (x0, y0), (x1, y1) = ax.get_window_extent().get_points().astype(int)
        counts.append(int(hit[y0:y1, x0:x1].sum()))
    return counts


def test_error_figure_draws_frames_without_a_neighbour():
    """A one-frame run, or frames with a lost frame (no estimate) either side: a line alone drew no
    pixel of them, three empty panels."""
    truth = {"true_x": 0.5, "true_z": 900.0, "true_theta": 1.0}
    estimate = {"x": 0.8, "z": 905.0, "theta": 1.2}
    one = [{"frame": 0, "time_s": 0.0, "lost": 0, **estimate, **truth}]
    gaps = [{"frame": i, "time_s": i / 30, "lost": i % 2, **truth, **(estimate if i % 2 == 0 else {})}
            for i in range(5)]
    for rows in (one, gaps):
        assert all(count > 0 for count in _drawn_pixels(viz.error_figure(rows, "t"), "C0"))


def test_error_figure_shows_the_aspect_up_to_the_mirror():
    """The aspect panel also draws the error against the nearer of θ and π − θ, with its mean in the
    legend: θ̂ = 2.0 against θ = 1.0 is 1.00 rad off, 0.14 (2.1416 − 2.0) up to the mirror; by hand."""
    rows = [{"frame": i, "time_s": i / 30, "lost": 0, "x": 0.8, "z": 905.0, "theta": 2.0, "true_x": 0.5,
             "true_z": 900.0, "true_theta": 1.0} for i in range(3)]
    aspect = viz.error_figure(rows, "mirror").axes[2]
    labels = [t.get_text() for t in aspect.get_legend().get_texts()]
    assert labels == ["aspect |θ̂ − θ|: mean 1.00 rad",
                      "up to the mirror θ ↔ π − θ (same silhouette at φ = 0): mean 0.14 rad"]
    np.testing.assert_allclose(aspect.get_lines()[1].get_ydata(), math.pi - 3.0)


def test_error_figure_titles_a_run_by_what_it_holds_and_keeps_the_silhouettes_mirror():
    """A run without a camera (the blob tracker's rows: θ, φ, α, no x, z) has no 3D estimate: its one
    panel is the view error, and the title said '3D tracking errors'. Its dashed line is the mirror
    θ ↔ π − θ, the same silhouette at φ = 0; θ ↔ 2π − θ is the image flipped left to right, which the
    blob tracker tells apart. θ̂ = 5.0 against θ = 1.0 (by hand): 2.28 rad off (2π − 4.0), 2.28 up to
    π − θ (5.0 − 2.14 = 2.86 is further), where 2π − θ = 5.28 would have given 0.28."""
    truth = {"true_x": 0.5, "true_z": 900.0, "true_theta": 1.0, "true_phi": 0.01, "true_class": "apc"}
    blob = [{"frame": i, "time_s": i / 30, "lost": 0, "theta": 5.0, "phi": 0.05, "alpha": 0.3, **truth}
            for i in range(3)]
    fig = viz.error_figure(blob, "nocam")
    assert len(fig.axes) == 1 and fig.axes[0].get_title() == "nocam: view error over time (no camera: no 3D)"
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert labels == ["aspect |θ̂ − θ|: mean 2.28 rad",
                      "up to the mirror θ ↔ π − θ (same silhouette at φ = 0): mean 2.28 rad"]
    np.testing.assert_allclose(fig.axes[0].get_lines()[1].get_ydata(), 2 * math.pi - 4.0)
    calibrated = [{**row, "x": 0.8, "z": 905.0} for row in blob]
    assert viz.error_figure(calibrated, "3d").axes[0].get_title() == "3d: 3D tracking errors over time"
    sensiac = viz.error_figure(_sensiac_like_rows(), "sensiac")
    assert [ax.get_title() for ax in sensiac.axes] == ["sensiac: aspect error over time (truth: no position)"]


def test_view_figure_legend_shows_the_estimate_of_a_late_start():
    """A run whose first frames have no estimate (a blind start on a vehicle driving in): the
    legend's 'estimate' took the colour of frame 0, transparent, and showed nothing."""
    rows = [{"frame": i, "time_s": i / 30, "lost": 1, "mask_area_px": 0} for i in range(3)]
    rows += [{"frame": i, "time_s": i / 30, "lost": 0, "theta": 1.0 + 0.01 * i, "phi": 0.05} for i in range(3, 6)]
    fig = viz.view_figure(rows, "late")
    fig.canvas.draw()  # the handle takes the points' colours when drawn
    legend = fig.axes[0].get_legend()
    handles = dict(zip((t.get_text() for t in legend.get_texts()), legend.legend_handles))
    assert (handles["estimate"].get_facecolor()[:, 3] > 0).all()


def test_error_figure_spans_the_run_as_the_alpha_figure_does():
    """A blind start at 1 s of a 2 s run: the errors' time axis began at 1 s, where the identity
    figure's begins at 0, and hid the second without an estimate."""
    model = GenerativeShapeModel.from_checkpoint(CKPT)
    rows = [{"frame": i, "time_s": i / 30, "lost": int(i < 30), "true_x": 0.5, "true_z": 900.0, "true_theta": 1.0,
             **({"x": 0.8, "z": 905.0, "theta": 1.2, "alpha": 0.3} if i >= 30 else {})} for i in range(61)]
    for ax in viz.error_figure(rows, "late").axes:
        assert ax.get_xlim() == pytest.approx((0.0, 2.0 + 1 / 60))
    assert viz.alpha_figure(rows, model, "late").axes[0].get_xlim() == pytest.approx((0.0, 2.0 + 1 / 60))


def test_a_one_frame_run_has_no_negative_time():
    """One frame at 0 s: the time axes ran from −0.05 s (matplotlib's margin around one point)."""
    model = GenerativeShapeModel.from_checkpoint(CKPT)
    rows = [{"frame": 0, "time_s": 0.0, "lost": 0, "true_x": 0.5, "true_z": 900.0, "true_theta": 1.0,
             "x": 0.8, "z": 905.0, "theta": 1.2, "alpha": 0.3}]
    for ax in [*viz.error_figure(rows, "one").axes, *viz.alpha_figure(rows, model, "one").axes]:
        assert ax.get_xlim() == pytest.approx((0.0, 0.5))
    later = [{**rows[0], "time_s": 3.0}]
    assert viz.error_figure(later, "one").axes[0].get_xlim() == pytest.approx((2.5, 3.5))


def test_view_figure_plots_the_azimuth_against_time_below():
    """The second panel: the estimated azimuth (degrees, 0-360) at each estimated frame's time, and the
    truth's at every frame; a grazing camera's views, all at φ ≈ 0, are told apart there."""
    rows = [{"frame": i, "time_s": i / 30, "lost": int(i < 2), "true_theta": 0.1 * i - 0.5, "true_phi": 0.01,
             **({"theta": 0.1 * i - 0.4, "phi": 0.01} if i >= 2 else {})} for i in range(10)]
    fig = viz.view_figure(rows, "grazing")
    above, below = fig.axes[:2]
    assert below.get_ylim() == (0.0, 360.0) and below.get_xlabel() == "time (s)"
    assert below.get_ylabel() == "azimuth θ (degrees)"
    estimate = below.collections[0].get_offsets()
    np.testing.assert_allclose(estimate[:, 0], [i / 30 for i in range(2, 10)])
    np.testing.assert_allclose(estimate[:, 1], [math.degrees(0.1 * i - 0.4) % 360 for i in range(2, 10)])
    truth = below.lines[0]
    np.testing.assert_allclose(truth.get_ydata(), [math.degrees(0.1 * i - 0.5) % 360 for i in range(10)])
    assert [t.get_text() for t in below.get_legend().get_texts()] == ["estimate", "truth"]
    assert fig.axes[2].get_ylabel() == "time (s)"  # the colour key


def test_view_figure_draws_the_estimate_over_the_truth_and_fits_the_elevation():
    """A grazing camera: truth and estimate both at φ ≈ 0.2°. The truth was drawn over the estimate
    and hid it, and the elevation axis was forced to −5°..50° (the run a 1-px line). The estimate is
    above the truth (hollow rings), the axis spans the run's elevations (0.2°-3°, by hand) with a
    little room, and the training elevations are shaded and keyed (the checkpoint's 0°-40°)."""
    rows = [{"frame": i, "time_s": i / 30, "lost": 0, "theta": 1.0 + 0.01 * i, "phi": math.radians(0.2 + 0.3 * i),
             "true_theta": 1.0 + 0.01 * i, "true_phi": math.radians(0.2)} for i in range(11)]
    model = GenerativeShapeModel.from_checkpoint(CKPT)
    lowest, highest = np.degrees(model.rbf.centres_phi.min().item()), np.degrees(model.rbf.centres_phi.max().item())
    assert (round(lowest), round(highest)) == (0, 40)
    fig = viz.view_figure(rows, "grazing", (math.radians(lowest), math.radians(highest)))
    above, below = fig.axes[:2]
    for ax in (above, below):
        truth, estimate = ax.lines[0], ax.collections[0]
        assert truth.get_zorder() < estimate.get_zorder() and truth.get_markerfacecolor() == "none"
    low, high = above.get_ylim()
    assert -2.0 < low < 0.2 and 3.2 < high < 5.0
    assert [t.get_text() for t in above.get_legend().get_texts()] == ["estimate", "truth",
                                                                     "training elevations (0°–40°)"]
    shade = above.patches[0]  # the span, from the lowest to the highest training elevation, under the points
    assert shade.get_zorder() < above.lines[0].get_zorder()
    np.testing.assert_allclose([shade.get_y(), shade.get_y() + shade.get_height()], [lowest, highest])


def test_alpha_figure_draws_the_matches_over_the_dots_keys_the_bands_as_drawn_and_keeps_the_first_dot_whole():
    """α̂ sitting on the best match (the quick start's t_55): the dashed line was drawn under the dots and
    hidden; the legend's class swatches were darker (alpha 0.35) than the bands (0.18); the first
    frame's dot, at t = 0 on the axis's edge, was cut in half. The reference: the checkpoint's classes
    in order, their tab10 colours, and the dot's pixels left of the axes' edge."""
    from matplotlib.colors import to_rgb

    model = GenerativeShapeModel.from_checkpoint(CKPT)
    a = model.alphas[model.vehicle_names.index("t_55")].item()
    rows = [{"frame": i, "time_s": i / 30, "lost": 0, "alpha": a, "class": "tank"} for i in range(30)]
    fig = viz.alpha_figure(rows, model, "on the match")
    ax = fig.axes[0]
    dots = next(line for line in ax.lines if line.get_label() == "estimated α")
    matches = [line for line in ax.lines if line.get_label().startswith("best match")]
    assert matches[0].get_label() == "best match 1: t_55"
    assert all(match.get_zorder() > dots.get_zorder() for match in matches)
    legend = ax.get_legend()
    texts = [t.get_text() for t in legend.get_texts()]
    assert texts[:len(model.class_names)] == [f"{name} arc" for name in model.class_names]
    for c, handle in enumerate(legend.legend_handles[:len(model.class_names)]):
        bands = [p for p in ax.patches if np.allclose(p.get_facecolor()[:3], to_rgb(f"C{c}"))]
        assert bands and np.allclose(to_rgb(handle.get_color()), to_rgb(f"C{c}"))
        assert {band.get_alpha() for band in bands} == {handle.get_alpha()}
    assert ax.get_xlim()[0] == 0.0  # no negative time: the dot is drawn whole across the edge
    legend.remove()
    fig.set_dpi(300)  # the dot 12 px across
    fig.canvas.draw()
    image = np.asarray(fig.canvas.buffer_rgba())[..., :3].astype(int)
    x, y = np.round(ax.transData.transform((0.0, a))).astype(int)
    row = image.shape[0] - y
    left_of_edge = image[:, x - 5:x - 2].max(axis=(1, 2))  # the lightest of three columns just outside the axes
    assert left_of_edge[row] < 80 and left_of_edge[row + 20] > 240  # the dot's left half, black, only there


def test_heldout_failure_rows_say_what_their_number_is_and_long_names_do_not_touch(monkeypatch):
    """benchmarks/bench_heldout.py's figure: the row label 'views on class 0.10' did not say what 0.10 is,
    and a long mesh name, rotated, ran into the next row's label (chrono_vw_microbus_chassis). The
    reference: the labels as written by hand, and their drawn extents, one above the other."""
    import importlib

    from torch_atr.vehicles import load_catalog_vehicle
    from torch_atr.vehicles.catalog import CATALOG_DIR

    monkeypatch.syspath_prepend(str(CKPT.parents[1] / "benchmarks"))
    bench = importlib.import_module("bench_heldout")
    model = GenerativeShapeModel.from_checkpoint(CKPT)
    rows = [{"path": f"{folder}/{stem}.obj", "class": cls, "classified": "car", "views_correct": share,
             "duplicate_of": None, "nearest": ["ford_focus"], "nearest_in_class": "vw_multivan"}
            for folder, stem, cls, share in (("van", "chrono_vw_microbus_chassis", "minivan", 0.1),
                                             ("van", "chrono_nissan_patrol_chassis", "minivan", 0.25))]
    mesh = load_catalog_vehicle("vw_multivan")
    fig = bench.failure_figure(rows, [mesh, mesh], CATALOG_DIR / "train", model, "failures")
    labels = [fig.axes[i * 6].yaxis.label for i in range(2)]
    assert [label.get_text() for label in labels] == [
        "chrono_nissan_\npatrol_chassis\nminivan → car\nshare of single views\nin true class: 0.25",
        "chrono_vw_microbus_\nchassis\nminivan → car\nshare of single views\nin true class: 0.10"]
    fig.canvas.draw()
    top_low = labels[0].get_window_extent().get_points()[0, 1]
    high = labels[1].get_window_extent().get_points()[1, 1]
    assert top_low - high > 0.25 * fig.dpi  # the second row's label a quarter inch below the first's (was 0.12)


class _RecordingWriter:
    """Stands in for cv2.VideoWriter: keeps every frame written, in order."""

    frames: list = []

    def __init__(self, *args):
        _RecordingWriter.frames = []

    def write(self, image):
        _RecordingWriter.frames.append(image.copy())

    def release(self):
        pass


def test_the_overlay_video_draws_each_frame_with_the_kernel_widths_of_that_frame(tmp_path, monkeypatch):
    """With adapt on the widths change over a run. The video was drawn after the run, every frame
    with the end-of-run widths; it is drawn as the run steps. Reference: each frame's contour drawn
    from the silhouette placed at the widths recorded when the tracker was at that frame."""
    import cv2

    from torch_atr.config import load_config
    from torch_atr.data.synthetic import SceneConfig, SyntheticSequence
    from torch_atr.tracking.filter import Tracker, TrackerConfig

    seq = SyntheticSequence("t_72", SceneConfig(frames=6))
    cfg = load_config(TrackerConfig, None, ["filter.particles=100", "init.mode=truth", "adapt.every=1",
                                            "adapt.steps=20", "adapt.lr=0.1"])
    tracker = Tracker(GenerativeShapeModel.from_checkpoint(CKPT), seq.camera, cfg, seed=0)
    widths = []
    monkeypatch.setattr(cv2, "VideoWriter", _RecordingWriter)
    with viz.OverlayVideo(tmp_path / "overlay.mp4", tracker) as video:
        def on_frame(i, frame, row):
            widths.append(tracker.model.rbf.log_width.detach().clone())
            video(i, frame, row)

        result = tracker.run(seq, progress=False, on_frame=on_frame)
    assert (tmp_path / "overlay.mp4").exists() and len(_RecordingWriter.frames) == len(result.rows) == 6
    log_width = tracker.model.rbf.log_width
    for i, (row, image) in enumerate(zip(result.rows, _RecordingWriter.frames)):
        with torch.no_grad():
            log_width.copy_(widths[i])
        placed = tracker.silhouette_at(row, image.shape[:2]).numpy().astype(np.uint8)
        contours, _ = cv2.findContours(placed, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        expected = cv2.drawContours(np.zeros(image.shape[:2], np.uint8), contours, -1, 1, 1).astype(bool)
        assert not expected[:60].any()  # the key's rows, top left, hold a swatch of the contour's colour
        assert np.array_equal((image[60:] == (40, 40, 255)).all(-1), expected[60:]), i
    with torch.no_grad():
        log_width.copy_(widths[-1])
    end = tracker.silhouette_at(result.rows[0], image.shape[:2])
    with torch.no_grad():
        log_width.copy_(widths[0])
    assert not torch.equal(end, tracker.silhouette_at(result.rows[0], image.shape[:2]))  # the widths did move it


def test_the_overlay_video_keys_its_contour_and_writes_alpha_and_the_true_class(tmp_path, monkeypatch):
    """The video had no key for its red contour, wrote α as 'a=' and never the true class. OpenCV's
    fonts cannot draw α: 'alpha='. The reference: the texts handed to cv2.putText, and a swatch of
    the contour's colour in the key on every frame, estimate or not."""
    import types

    import cv2

    said = []
    put_text = cv2.putText

    def recording(image, text, *args):
        said.append(text)
        return put_text(image, text, *args)

    monkeypatch.setattr(cv2, "VideoWriter", _RecordingWriter)
    monkeypatch.setattr(cv2, "putText", recording)
    box = torch.zeros(120, 160, dtype=torch.bool)
    box[60:80, 70:110] = True
    tracker = types.SimpleNamespace(dt=1 / 30, segmenter=types.SimpleNamespace(display=lambda frame: frame),
                                    silhouette_at=lambda row, shape: box)
    rows = [{"frame": 0, "lost": 1, "true_class": "apc"},
            {"frame": 1, "lost": 0, "alpha": 4.2, "class": "car", "true_class": "apc"},
            {"frame": 2, "lost": 0, "alpha": 0.3, "class": "tank"}]
    with viz.OverlayVideo(tmp_path / "overlay.mp4", tracker) as video:
        for i, row in enumerate(rows):
            video(i, np.zeros((120, 160), np.uint8), row)
    keys = ["estimate's silhouette", "segmented target"]
    assert said == ["frame 0: no estimate (true: apc)", *keys, "frame 1: car alpha=4.20 (true: apc)", *keys,
                    "frame 2: tank alpha=0.30", *keys]
    for image in _RecordingWriter.frames:
        assert (image[:45, :40] == (40, 40, 255)).all(-1).sum() >= 20  # the key's swatches
        assert (image[40:56, :40] == (255, 255, 0)).all(-1).sum() >= 20


def test_the_overlay_video_draws_the_segmented_target_under_the_estimate(tmp_path, monkeypatch):
    """frames.png draws the segmented target's contour beside the estimate's; the video drew the
    estimate's alone. The reference: OpenCV's contour of the tracker's last mask in cyan, the
    estimate's in red over it where the two meet."""
    import types

    import cv2

    monkeypatch.setattr(cv2, "VideoWriter", _RecordingWriter)
    mask = np.zeros((120, 160), bool)
    mask[70:90, 60:100] = True
    placed = torch.zeros(120, 160, dtype=torch.bool)
    placed[72:88, 80:120] = True
    tracker = types.SimpleNamespace(dt=1 / 30, segmenter=types.SimpleNamespace(display=lambda frame: frame),
                                    silhouette_at=lambda row, shape: placed, last_mask=mask)
    with viz.OverlayVideo(tmp_path / "overlay.mp4", tracker) as video:
        video(0, np.zeros((120, 160), np.uint8), {"frame": 0, "lost": 0, "alpha": 0.3, "class": "tank"})
    image = _RecordingWriter.frames[0]

    def outline(m: np.ndarray) -> np.ndarray:
        contours, _ = cv2.findContours(m.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        return cv2.drawContours(np.zeros(m.shape, np.uint8), contours, -1, 1, 1).astype(bool)

    red, cyan = outline(placed.numpy()), outline(mask)
    assert np.array_equal((image[60:] == (40, 40, 255)).all(-1), red[60:])
    assert np.array_equal((image[60:] == (255, 255, 0)).all(-1), (cyan & ~red)[60:])


def test_an_overlay_video_of_a_run_that_fails_leaves_no_file(tmp_path):
    """The video replaces its path only when the run ends: a run that raises leaves the old file."""
    from torch_atr.tracking.filter import Tracker

    old = tmp_path / "overlay.mp4"
    old.write_bytes(b"the user's video")
    tracker = Tracker.__new__(Tracker)
    with pytest.raises(RuntimeError, match="the run failed"):
        with viz.OverlayVideo(old, tracker):
            raise RuntimeError("the run failed")
    assert old.read_bytes() == b"the user's video" and [p.name for p in tmp_path.iterdir()] == ["overlay.mp4"]
