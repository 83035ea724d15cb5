"""What a tracking run logs to TensorBoard, read back with TensorBoard's own reader and checked
against hand-made rows."""

from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from torch_atr import viz
from torch_atr.tracking.filter import TrackResult

CLASSES = ("tank", "apc", "pickup", "suv", "car", "minivan")  # the shipped model's, as the rows' p_<class>


def _row(frame: int, estimated: str, true_class: str) -> dict:
    return {"frame": frame, "time_s": frame / 30, "lost": 0, "alpha": 0.3, "class": estimated,
            **{f"p_{name}": float(name == estimated) for name in CLASSES}, "true_class": true_class}


def _scalars(folder) -> dict[str, list[tuple[int, float]]]:
    events = EventAccumulator(str(folder)).Reload()
    return {tag: [(e.step, e.value) for e in events.Scalars(tag)] for tag in events.Tags()["scalars"]}


def test_recognition_is_logged_only_for_true_classes_the_model_knows(tmp_path):
    """metrics.json's recognition leaves out frames whose true class is not one of the model's (a
    'truck', a 'Tank'); TensorBoard logged them as wrong (0), a chart of misses the metrics do not have."""
    rows = [_row(0, "tank", "truck"), _row(1, "tank", "Tank"), _row(2, "tank", "tank"), _row(3, "apc", "tank"),
            _row(4, "car", "")]
    viz.log_track_tensorboard(tmp_path, TrackResult(rows, [], 1.0), {})
    assert _scalars(tmp_path)["recognition/correct"] == [(2, 1.0), (3, 0.0)]
