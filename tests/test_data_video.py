"""Video files and image folders: what cv2 wrote comes back (MJPG is lossy, PNG exact)."""

import json
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from torch_atr.camera import Camera
from torch_atr.data import VideoSequence, open_sequence, save_sequence
from torch_atr.validate import InputError

H, W, N = 48, 64, 12


def _scene(i):
    """BGR frame i: grey level 20 i on the left half, a red block whose column moves with i."""
    img = np.zeros((H, W, 3), np.uint8)
    img[:, : W // 2] = 20 * i
    img[8:24, 34 + 2 * i: 42 + 2 * i] = (0, 0, 255)
    return img


@pytest.fixture(scope="module")
def avi(tmp_path_factory):
    path = tmp_path_factory.mktemp("vid") / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 15.0, (W, H), True)
    assert writer.isOpened()
    for i in range(N):
        writer.write(_scene(i))
    writer.release()
    return path


def test_video_grey_frames(avi):
    seq = open_sequence(f"video:{avi}")
    assert isinstance(seq, VideoSequence) and len(seq) == N and seq.fps == 15.0 and seq.camera is None
    assert seq.meta["kind"] == "video" and seq.meta["fourcc"] == "MJPG" and seq.name == "clip"
    for i, f in enumerate(seq):
        assert f.shape == (H, W) and f.dtype == np.uint8
        want = cv2.cvtColor(_scene(i), cv2.COLOR_BGR2GRAY).astype(float)
        assert np.abs(f.astype(float) - want).mean() < 3.0


def test_video_random_access_matches_sequential(avi):
    seq = VideoSequence(avi)
    sequential = [f.copy() for f in seq]
    for i in (7, 2, 3, 11, 0, 0, 5):
        np.testing.assert_array_equal(seq.frame(i), sequential[i])
    with pytest.raises(IndexError, match=f"frame index {N} out of range for a sequence of {N} frames"):
        seq.frame(N)
    seq.close()
    with pytest.raises(ValueError, match="closed"):
        seq.frame(0)


def test_inter_frame_codec_random_access(tmp_path):
    """MPEG-4 part 2 (mp4v) stores P-frames: a seek must still land on the frame asked for.

    Sequential decoding is the reference, itself checked frame by frame: the grey level of the
    top rows rises by 6 a frame, so a repeated or skipped frame shows."""
    n = 40  # beyond the encoder's keyframe interval, so most frames are predicted
    path = tmp_path / "clip.mp4"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 25.0, (W, H), True)
    assert writer.isOpened()
    for i in range(n):
        img = np.zeros((H, W, 3), np.uint8)
        img[:, : W // 2] = 6 * i
        img[8:24, 16 + i // 2: 24 + i // 2] = 255
        img[28:44, 8 + i: 16 + i] = (0, 0, 255)
        writer.write(img)
    writer.release()
    seq = open_sequence(f"video:{path}")
    assert len(seq) == n and seq.meta["fourcc"].lower() in ("mp4v", "fmp4") and seq.fps == 25.0
    sequential = [f.copy() for f in seq]
    steps = np.diff([float(f[:8, : W // 2].mean()) for f in sequential])
    assert np.all((steps > 3) & (steps < 9)), steps  # no frame repeated or skipped
    for i in (37, 3, 20, 21, 13, 0, 39, 12, 25, 26, 5):
        np.testing.assert_array_equal(seq.frame(i), sequential[i])
    seq.close()


def test_video_color_is_rgb(avi):
    seq = open_sequence(f"video:{avi},color=yes,fps=30")
    assert seq.fps == 30.0
    f = seq.frame(4)
    assert f.shape == (H, W, 3) and f.dtype == np.uint8
    block = f[10:22, 36 + 8: 40 + 8].reshape(-1, 3).mean(0)
    assert block[0] > 200 and block[1] < 40 and block[2] < 40  # red lands in channel 0
    want = cv2.cvtColor(_scene(4), cv2.COLOR_BGR2RGB).astype(float)
    assert np.abs(f.astype(float) - want).mean() < 4.0


def _write_images(folder, n=N, name="frame{}.png"):
    folder.mkdir()
    for i in range(n):  # unpadded numbers: natural order differs from string order
        cv2.imwrite(str(folder / name.format(i + 1)), _scene(i))
    (folder / "notes.txt").write_text("ignored")


def test_image_folder_natural_order_exact(tmp_path):
    _write_images(tmp_path / "imgs")
    seq = open_sequence(f"video:{tmp_path / 'imgs'}")
    assert len(seq) == N and math.isnan(seq.fps) and seq.name == "imgs"
    for i in range(N):
        np.testing.assert_array_equal(seq.frame(i), cv2.cvtColor(_scene(i), cv2.COLOR_BGR2GRAY))
    rgb = VideoSequence(tmp_path / "imgs", color=True, fps=10.0)
    np.testing.assert_array_equal(rgb.frame(10), cv2.cvtColor(_scene(10), cv2.COLOR_BGR2RGB))
    out = save_sequence(rgb, tmp_path / "folder", progress=False)
    back = open_sequence(str(out))
    assert back.fps == 10.0
    for i in range(N):
        np.testing.assert_array_equal(back.frame(i), rgb.frame(i))


def test_glob_and_16_bit(tmp_path):
    (tmp_path / "ir").mkdir()
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 65536, (H, W), dtype=np.uint16) for _ in range(3)]
    for i, f in enumerate(frames):
        cv2.imwrite(str(tmp_path / "ir" / f"ir_{i}.png"), f)
    cv2.imwrite(str(tmp_path / "ir" / "other_0.png"), frames[0])
    seq = open_sequence(f"video:{tmp_path / 'ir' / 'ir_*.png'}")
    assert len(seq) == 3 and seq.meta["kind"] == "images"
    for i in range(3):
        got = seq.frame(i)
        assert got.dtype == np.uint16
        np.testing.assert_array_equal(got, frames[i])


def test_a_16_bit_grey_video_stays_16_bit(tmp_path):
    """Lossless IR video (FFV1, GRAY16LE) frame i holding 1000 + 300 i: OpenCV's default conversion to
    8-bit BGR read frame 3's 1900 as 7; random reads after seeks, and colour, as for 8-bit video."""
    path = str(tmp_path / "ir16.mkv")
    writer = cv2.VideoWriter(path, cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*"FFV1"), 30.0, (48, 32),
                             [cv2.VIDEOWRITER_PROP_DEPTH, cv2.CV_16U, cv2.VIDEOWRITER_PROP_IS_COLOR, 0])
    if not writer.isOpened():
        pytest.skip("this OpenCV build writes no 16-bit FFV1")
    for i in range(8):
        writer.write(np.full((32, 48), 1000 + 300 * i, np.uint16))
    writer.release()
    seq = VideoSequence(path)
    for i in (3, 0, 7, 4, 5):
        frame = seq.frame(i)
        assert frame.dtype == np.uint16 and frame.shape == (32, 48) and (frame == 1000 + 300 * i).all()
    colour = VideoSequence(path, color=True).frame(3)
    assert colour.dtype == np.uint8 and colour.shape == (32, 48, 3) and (colour == 1900 >> 8).all()


def test_image_order_across_folders_ties_and_hidden_files(tmp_path):
    """A glob over several folders keeps each folder's frames together, in natural order; names
    that sort alike (img1, img01) come in a fixed order; a folder's hidden files (macOS's ._img
    beside img) are not frames."""
    for day, values in (("day2", (20, 21, 22)), ("day1", (10, 11, 12)), ("day10", (30,))):
        (tmp_path / day).mkdir()
        for k, value in enumerate(values):
            cv2.imwrite(str(tmp_path / day / f"{k:03d}.png"), np.full((H, W), value, np.uint8))
    seq = open_sequence(f"video:{tmp_path / 'day*' / '*.png'}")
    assert [int(seq.frame(i)[0, 0]) for i in range(len(seq))] == [10, 11, 12, 20, 21, 22, 30]
    tie = tmp_path / "tie"
    tie.mkdir()
    for name, value in (("img1.png", 1), ("img01.png", 2), ("._img1.png", 3)):
        (tie / name).write_bytes(b"not an image" if name.startswith(".") else cv2.imencode(".png",
                                 np.full((H, W), value, np.uint8))[1].tobytes())
    seq = open_sequence(f"video:{tie}")
    assert len(seq) == 2 and [int(seq.frame(i)[0, 0]) for i in range(2)] == [2, 1]  # img01, then img1


def test_digit_runs_compare_as_whole_numbers_as_ls_v_does():
    """A counter after a dot sorts by value (cam1.2 before cam1.10), as do time stamps with a fixed
    number of decimals; one of varying width (t_1.5, t_1.25) compares its decimals as a whole
    number too, like ls -v (README: write them with a fixed number of decimals)."""
    from torch_atr.data.video import natural_key

    counters = [f"cam1.{k}.png" for k in (1, 2, 9, 10, 11, 20)]
    assert sorted(reversed(counters), key=natural_key) == counters
    assert sorted(["shot_2024.10.png", "shot_2024.2.png"], key=natural_key) == ["shot_2024.2.png", "shot_2024.10.png"]
    stamps = ["t_0.750.png", "t_1.250.png", "t_1.500.png", "t_10.000.png"]
    assert sorted(reversed(stamps), key=natural_key) == stamps
    # ² and ① are digits to str.isdigit, not to int(): a name or folder ending in one raised ValueError.
    assert sorted(["area2².png", "area10².png", "scan1²", "①", "scan1"], key=natural_key) == [
        "area2².png", "area10².png", "scan1", "scan1²", "①"]



def test_images_in_a_folder_named_with_a_superscript_open(tmp_path):
    folder = tmp_path / "field1²"  # its path's parts are sort keys too
    folder.mkdir()
    for k in (10, 2):
        cv2.imwrite(str(folder / f"img{k}.png"), np.full((H, W), k, np.uint8))
    seq = open_sequence(f"video:{folder}")
    assert [int(seq.frame(i)[0, 0]) for i in range(len(seq))] == [2, 10]


def test_mixed_image_sizes(tmp_path):
    (tmp_path / "m").mkdir()
    cv2.imwrite(str(tmp_path / "m" / "a1.png"), np.zeros((4, 5), np.uint8))
    cv2.imwrite(str(tmp_path / "m" / "a2.png"), np.zeros((4, 6), np.uint8))
    seq = VideoSequence(tmp_path / "m")
    with pytest.raises(ValueError, match=r"a2.png: image is \(4, 6\) uint8; a1.png was \(4, 5\) uint8"):
        seq.frame(1)


def test_home_in_a_spec_is_expanded(avi, tmp_path, monkeypatch):
    """The shell does not expand a ~ after "video:" or "calib=": the reader does."""
    monkeypatch.setenv("HOME", str(avi.parent))
    (avi.parent / "cam.json").write_text(json.dumps(Camera(fx=100.0, fy=100.0, cx=32.0, cy=24.0, width=W,
                                                           height=H).to_dict()))
    seq = open_sequence(f"video:~/{avi.name},calib=~/cam.json")
    assert len(seq) == N and seq.camera.fx == 100.0
    save_sequence(seq, avi.parent / "saved", progress=False)
    for spec in ("~/saved", "folder:~/saved"):  # a folder, with its scheme or without
        assert len(open_sequence(spec)) == N, spec


def test_calibration_option(avi, tmp_path):
    cam = Camera(600.0, 610.0, 31.5, 23.5, W, H, dist=[0.1, 0, 0, 0, 0])
    calib = tmp_path / "cam.json"
    calib.write_text(json.dumps(cam.to_dict()))
    seq = open_sequence(f"video:{avi},calib={calib}")
    assert seq.camera.to_dict() == cam.to_dict()
    d = cam.to_dict()
    del d["cx"]
    calib.write_text(json.dumps(d))
    with pytest.raises(ValueError, match=re.escape(f"{calib}: missing key(s) cx")):
        open_sequence(f"video:{avi},calib={calib}")
    calib.write_text(json.dumps(Camera(600.0, 610.0, 31.5, 23.5, 2 * W, H).to_dict()))
    with pytest.raises(ValueError, match=f"the camera is {2 * W} x {H} px but the frames are {W} x {H}"):
        open_sequence(f"video:{avi},calib={calib}")
    with pytest.raises(FileNotFoundError, match="absent.json"):
        open_sequence(f"video:{avi},calib={tmp_path / 'absent.json'}")


def test_video_errors(tmp_path):
    want = f"Video file or image folder not found: {tmp_path / 'x.avi'}"
    with pytest.raises(FileNotFoundError, match=re.escape(want)):
        open_sequence(f"video:{tmp_path / 'x.avi'}")
    with pytest.raises(FileNotFoundError, match="No files match the pattern"):
        open_sequence(f"video:{tmp_path / '*.png'}")
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match="empty: no image files"):
        open_sequence(f"video:{tmp_path / 'empty'}")
    cv2.imwrite(str(tmp_path / "one.png"), np.zeros((H, W), np.uint8))
    one = f"one.png: one image is not a sequence; give its folder (video:{tmp_path})"
    with pytest.raises(ValueError, match=re.escape(one)):
        open_sequence(f"video:{tmp_path / 'one.png'}")
    (tmp_path / "junk.avi").write_bytes(b"not a video at all")
    with pytest.raises(ValueError, match=re.escape(f"{tmp_path / 'junk.avi'}: OpenCV cannot open it as a video")):
        open_sequence(f"video:{tmp_path / 'junk.avi'}")
    with pytest.raises(ValueError, match="color must be one of"):
        open_sequence(f"video:{tmp_path / 'junk.avi'},color=maybe")
    for bad in (0.0, -1.0, math.inf, math.nan, True, "15"):
        with pytest.raises(ValueError, match=re.escape(f"junk.avi: fps must be a positive number; got {bad!r}")):
            VideoSequence(tmp_path / "junk.avi", fps=bad)


def test_a_video_cut_short_gives_the_frames_it_holds(avi, tmp_path, caplog):
    """A truncated file's header still claims every frame: the sequence is as long as what reads."""
    cut = tmp_path / "cut.avi"
    data = avi.read_bytes()
    cut.write_bytes(data[: len(data) * 6 // 10])
    cap = cv2.VideoCapture(str(cut))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == N  # the claim
    held = 0
    while cap.read()[0]:  # the reference: read from the start until a frame fails
        held += 1
    cap.release()
    assert 0 < held < N
    seq = VideoSequence(cut)
    assert len(seq) == held and "claims 12 frames but only the first" in caplog.text
    whole = VideoSequence(avi)
    for i in (held - 1, 0, held - 1):
        np.testing.assert_array_equal(seq.frame(i), whole.frame(i))


def test_a_video_holding_more_frames_than_it_claims_is_refused_not_cut(tmp_path):
    """An MPEG-1 program stream's count is an estimate from its duration, short of its frames:
    the sequence was as long as the claim, and the frames after it were lost without a word."""
    path = tmp_path / "clip.mpg"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"PIM1"), 25.0, (W, H), True)
    assert writer.isOpened()
    for i in range(40):
        writer.write(np.full((H, W, 3), 6 * i, np.uint8))
    writer.release()
    cap = cv2.VideoCapture(str(path))
    claim = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    held = 0
    while cap.grab():  # the reference: read from the start until a frame fails
        held += 1
    cap.release()
    assert held == 40 and 0 < claim < held
    want = f"{path}: the video claims {claim} frames but holds more (frame {claim} reads too)"
    with pytest.raises(InputError, match=re.escape(want)):
        open_sequence(f"video:{path}")


def test_a_video_path_that_is_not_utf8_is_refused_not_a_crash(avi, tmp_path):
    """A name of Latin-1 bytes (an old archive's) reaches OpenCV with surrogates: cv2.VideoCapture
    crashed the process (SIGSEGV), so the call runs in a child process."""
    try:
        path = os.fsdecode(os.path.join(os.fsencode(tmp_path), b"cl\xe9.avi"))
        shutil.copyfile(avi, path)
    except OSError:
        pytest.skip("this file system refuses names that are not UTF-8")
    code = ("import sys\nfrom torch_atr.data import VideoSequence\ntry:\n    VideoSequence(sys.argv[1])\n"
            "except ValueError as exc:\n    print(exc)\n")
    child = subprocess.run([sys.executable, "-c", code, path], capture_output=True, text=True,
                           cwd=Path(__file__).resolve().parents[1])
    assert child.returncode == 0, child.stderr
    assert child.stdout == f"{path!r}: the path is not UTF-8 text, and OpenCV's video reader crashes the process " \
                           f"(a segmentation fault) on such a path; rename the file\n"


def test_a_video_refused_after_opening_releases_its_capture(avi, monkeypatch):
    """Every refusal once the capture is open (no frames, a bad size, no readable frame) releases it."""
    from torch_atr.data import video as video_module

    opened, real = [], cv2.VideoCapture

    class Capture:  # OpenCV's capture, with its release counted
        def __init__(self, path):
            self.cap, self.released = real(path), False
            opened.append(self)

        def __getattr__(self, name):
            return getattr(self.cap, name)

        def release(self):
            self.released = True
            self.cap.release()

    def refuse(*args):
        raise video_module.InputError("refused")

    monkeypatch.setattr(video_module.cv2, "VideoCapture", Capture)
    for name in ("image_size", "_readable_frames"):
        with monkeypatch.context() as m:
            m.setattr(video_module, name, refuse)
            with pytest.raises(ValueError, match="refused"):
                VideoSequence(avi)
    assert len(opened) == 2 and all(c.released for c in opened)


def test_image_headers_are_checked_before_decoding(tmp_path):
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    folder = tmp_path / "frames"
    folder.mkdir()
    cv2.imwrite(str(folder / "a0.png"), np.zeros((4, 5), np.uint8))
    header = struct.pack(">IIBBBBB", 10000, 9000, 8, 0, 0, 0, 0)  # 9e7 pixels: within Pillow's bound, not ours
    (folder / "a1.png").write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IEND", b""))
    seq = open_sequence(f"video:{folder}")
    with pytest.raises(InputError, match=re.escape(f"{folder / 'a1.png'}: 10000 x 9000 = 90000000 pixels; "
                                                   f"expected at most 67108864")):
        seq.frame(1)
    (folder / "a1.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    with pytest.raises(InputError, match=re.escape(f"{folder / 'a1.png'}: cannot be read as an image")):
        seq.frame(1)


def test_frames_of_an_h264_transport_stream_are_its_own_after_any_seek():
    """OpenCV's seek to frames 0-12 of this H.264 MPEG-TS (B-frames, a keyframe every 12) lands on
    frame 12 without a word, so frame(0) and every frame read after it were 12 frames late. Each
    frame is compared with OpenCV's own reading from the start, which is exact, and with the frame
    as drawn (a square at column 2i, brightness 40 + 4i).

    tests/data/h264_bframes.ts (10 KB) was made with ffmpeg 9.0 (imageio-ffmpeg 0.8.1): 30 frames of 64 x 48,
    frame i grey 40 + 4i with a white 8 x 16 square at columns 2i..2i+7 of rows 8..23, piped as raw
    RGB to ``ffmpeg -r 30 -c:v libx264 -bf 3 -g 12 -crf 20 -pix_fmt yuv420p -f mpegts``."""
    path = Path(__file__).parent / "data" / "h264_bframes.ts"
    capture = cv2.VideoCapture(str(path))
    reference = []
    while (frame := capture.read())[0]:
        reference.append(cv2.cvtColor(frame[1], cv2.COLOR_BGR2GRAY))
    assert [int(np.argmax(f[16])) // 2 for f in reference] == list(range(30))  # the square's column: 2i
    seq = open_sequence(f"video:{path}")
    assert len(seq) == 30
    for i in [*range(30), 5, 0, 29, 13, 3]:  # in order, then back and forth
        assert np.array_equal(seq.frame(i), reference[i]), i


def test_a_read_that_fails_after_a_seek_is_read_again_from_the_start(avi):
    """A seek whose read then fails (a container whose index points past a damaged packet) raised at
    once, where reading from the start gets the frame; the read after a seek that landed elsewhere
    already went that way. Here the capture's first read after each seek is made to fail."""
    seq = VideoSequence(avi)
    sequential = [f.copy() for f in seq]
    real = seq._cap

    class FailsAfterSeek:
        def __init__(self, cap):
            self.cap, self.sought = cap, False

        def set(self, prop, value):
            self.sought = prop == cv2.CAP_PROP_POS_FRAMES
            return self.cap.set(prop, value)

        def read(self):
            if self.sought:
                self.sought = False
                return False, None
            return self.cap.read()

        def __getattr__(self, name):
            return getattr(self.cap, name)

    seq._cap = FailsAfterSeek(real)
    np.testing.assert_array_equal(seq.frame(7), sequential[7])
    np.testing.assert_array_equal(seq.frame(8), sequential[8])  # then on from there, no seek
    seq.close()
