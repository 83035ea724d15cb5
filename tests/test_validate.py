"""The validation layer: each helper against hand-written good and bad values."""

import math
import os
import re
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from PIL import Image

from torch_atr.validate import (InputError, image_size, integer, parse_real, read_image, read_json_object, read_text,
                                real, rotation, show, vector)


def test_real_accepts_finite_real_numbers_only():
    assert real("k", 3) == 3.0 and isinstance(real("k", 3), float)
    assert real("k", np.float32(1.5)) == 1.5 and real("k", np.int64(2)) == 2.0
    for bad in (True, "1.0", None, [1.0], math.nan, math.inf, -math.inf, 10 ** 400):
        with pytest.raises(InputError, match="^camera.json, key 'fx': expected a finite number; got "):
            real("camera.json, key 'fx'", bad)
    assert real("k", 0.0, lo=0) == 0.0
    with pytest.raises(InputError, match=r"expected a finite number > 0; got 0.0"):
        real("k", 0.0, lo=0, lo_open=True)
    with pytest.raises(InputError, match=re.escape("expected a finite number in [1, 2]; got 3")):
        real("k", 3, lo=1, hi=2)
    with pytest.raises(InputError, match=re.escape("expected a finite number <= 2; got 3")):
        real("k", 3, hi=2)


def test_integer_refuses_bools_floats_and_strings():
    assert integer("k", np.int32(7), 1, 10) == 7
    for bad in (True, 7.0, "7", None):
        with pytest.raises(InputError, match=r"^k: expected an integer in \[1, 10\]; got "):
            integer("k", bad, 1, 10)
    with pytest.raises(InputError, match="expected an integer >= 1; got 0"):
        integer("k", 0, lo=1)


def test_parse_real_refuses_non_finite_text():
    assert parse_real("f, line 3", " -2.5e1 ") == -25.0
    for bad, what in (("inf", "a finite number"), ("-inf", "a finite number"), ("1e400", "a finite number"),
                      ("nan", "a finite number"), ("abc", "a number"), ("", "a number")):
        with pytest.raises(InputError, match=f"^f, line 3: expected {what}; got '{bad}'"):
            parse_real("f, line 3", bad)


def test_show_shortens_long_values():
    assert show("ab") == "'ab'"
    assert show("x" * 238) == repr("x" * 238)  # 240 characters with its quotes: whole
    assert show("x" * 10_000) == "'" + "x" * 39 + "… (10002 characters)"
    assert show(10 ** 5000) == "an integer of about 5001 digits"  # repr refuses over 4300 digits
    assert show(-(10 ** 4500)) == "an integer of about 4501 digits"


def test_image_size_bounds():
    assert image_size("f", 640, 512) == (640, 512)
    with pytest.raises(InputError, match=r"^f: width: expected an integer in \[1, 16384\]; got 100000"):
        image_size("f", 100_000, 512)
    with pytest.raises(InputError, match=r"^f: height: expected an integer in \[1, 16384\]; got 512.0"):
        image_size("f", 640, 512.0)
    with pytest.raises(InputError, match=r"^f: 16384 x 16384 = 268435456 pixels; expected at most 67108864"):
        image_size("f", 16384, 16384)


def test_read_image_gives_the_pixels_as_stored_and_names_a_bad_file(tmp_path):
    rng = np.random.default_rng(0)
    grey16 = rng.integers(0, 2 ** 16, (5, 7), dtype=np.uint16)
    rgb = rng.integers(0, 256, (4, 6, 3), dtype=np.uint8)
    Image.fromarray(grey16).save(tmp_path / "grey16.png")  # written by Pillow, read by OpenCV
    Image.fromarray(rgb).save(tmp_path / "rgb.png")
    got = read_image(tmp_path / "grey16.png")
    assert got.dtype == np.uint16 and np.array_equal(got, grey16)
    assert np.array_equal(read_image(tmp_path / "rgb.png"), rgb[..., ::-1])  # OpenCV's BGR order
    assert np.array_equal(read_image(tmp_path / "grey16.png", (7, 5), "meta.json"), grey16)
    with pytest.raises(InputError, match=r"grey16.png: image is 7 x 5 px; meta.json says 5 x 7$"):
        read_image(tmp_path / "grey16.png", (5, 7), "meta.json")
    (tmp_path / "text.png").write_text("not an image")
    with pytest.raises(InputError, match=f"^{re.escape(str(tmp_path / 'text.png'))}: cannot be read as an image"):
        read_image(tmp_path / "text.png")
    whole = (tmp_path / "rgb.png").read_bytes()
    (tmp_path / "cut.png").write_bytes(whole[:len(whole) // 2])  # the header intact, the pixels cut short
    with pytest.raises(InputError, match=f"^{re.escape(str(tmp_path / 'cut.png'))}: cannot be"):
        read_image(tmp_path / "cut.png")


def test_a_jpeg_cut_short_is_refused_and_one_with_a_trailer_is_read(tmp_path):
    """OpenCV decoded a JPEG cut short with its missing rows grey (libjpeg's "Premature end of JPEG
    file" went to stderr only); bytes after the end marker (a camera's trailer) are not a cut."""
    rng = np.random.default_rng(1)
    img = cv2.GaussianBlur(rng.integers(0, 256, (96, 128), dtype=np.uint8), (5, 5), 0)
    Image.fromarray(img).save(tmp_path / "whole.jpg", quality=90, progressive=False)
    Image.fromarray(img).save(tmp_path / "steps.jpg", quality=90, progressive=True)
    for name in ("whole.jpg", "steps.jpg"):
        whole = (tmp_path / name).read_bytes()
        reference = np.asarray(Image.open(tmp_path / name))  # independent: Pillow's decoder
        assert np.abs(read_image(tmp_path / name).astype(int) - reference).max() <= 2
        for seed in range(6):  # a binary trailer (a motion photo's video) holds FF DA and FF D9 anywhere
            trailer = np.random.default_rng(seed).integers(0, 256, 20_000, dtype=np.uint8).tobytes()
            (tmp_path / f"trailer_{name}").write_bytes(whole + b"\xff\xd9\xff\xda" + trailer + b"\xff\xda")
            assert np.array_equal(read_image(tmp_path / f"trailer_{name}"), read_image(tmp_path / name))
        (tmp_path / f"cut_{name}").write_bytes(whole[:len(whole) * 2 // 3])
        cut = re.escape(str(tmp_path / f"cut_{name}"))
        with pytest.raises(InputError, match=f"^{cut}: the JPEG's data ends before its end-of-image marker"):
            read_image(tmp_path / f"cut_{name}")


def test_read_image_takes_a_path_that_is_not_utf8(tmp_path):
    """A Latin-1 name reaches OpenCV with surrogates: cv2.imread crashed the process (SIGSEGV), so the
    read runs in a child process; its pixels are Pillow's."""
    rgb = np.random.default_rng(2).integers(0, 256, (4, 6, 3), dtype=np.uint8)
    try:
        path = os.fsdecode(os.path.join(os.fsencode(tmp_path), b"cl\xe9.png"))
        Image.fromarray(rgb).save(path)
    except (OSError, UnicodeEncodeError):
        pytest.skip("this file system refuses names that are not UTF-8")
    code = ("import os, sys\nfrom torch_atr.validate import read_image\n"
            "sys.stdout.write(read_image(os.fsdecode(bytes.fromhex(sys.argv[1]))).tobytes().hex())\n")
    child = subprocess.run([sys.executable, "-c", code, os.fsencode(path).hex()], capture_output=True, text=True,
                           cwd=Path(__file__).resolve().parents[1])
    assert child.returncode == 0, child.stderr
    assert bytes.fromhex(child.stdout) == rgb[..., ::-1].tobytes()  # OpenCV's BGR order


def test_rotation_accepts_rotations_and_reflections_of_them():
    R = Rotation.from_euler("xyz", [0.3, -1.2, 2.0]).as_matrix()  # independent: scipy
    assert np.allclose(rotation("R", R.tolist()), R)
    flipped = (R @ np.diag([1.0, -1.0, 1.0])).tolist()  # det -1: a left-handed world frame (camera.py)
    assert np.allclose(rotation("R", flipped), flipped)
    with pytest.raises(InputError, match=r"^cam.json, key 'R': expected a rotation .* differs from I by 3"):
        rotation("cam.json, key 'R'", (2 * R).tolist())
    with pytest.raises(InputError, match=r"expected a 3 x 3 matrix"):
        rotation("R", [[1, 0], [0, 1]])
    with pytest.raises(InputError, match=r"^R\[1\]\[1\]: expected a finite number; got nan"):
        rotation("R", [[1, 0, 0], [0, math.nan, 0], [0, 0, 1]])
    with pytest.raises(InputError, match=r"^t\[2\]: expected a finite number; got '0'"):
        vector("t", [0, 0, "0"], 3)


def test_read_text_names_file_line_and_byte(tmp_path):
    path = tmp_path / "a.csv"
    path.write_bytes("\ufeffx,y\n1,2\n".encode("utf-8"))
    assert read_text(path) == "x,y\n1,2\n"  # a byte-order mark is dropped
    path.write_bytes(b"x,y\n1,\xff\n")
    with pytest.raises(InputError, match=rf"^{path}, line 2: not UTF-8 text \(byte 0xff at byte offset 6\)"):
        read_text(path)
    with pytest.raises(InputError, match=rf"^{path}: larger than 4 bytes"):
        read_text(path, max_bytes=4)
    with pytest.raises(FileNotFoundError, match="nope.csv"):
        read_text(tmp_path / "nope.csv")
    with pytest.raises(InputError, match="expected a file"):
        read_text(tmp_path)


@pytest.mark.parametrize("text, message", [
    ('{"fx": NaN}', "NaN is not a finite number"),
    ('{"fx": -Infinity}', "-Infinity is not a finite number"),
    ('{"fx": 1e400}', "1e400 is not a finite number"),
    ('{"n": ' + "9" * 5000 + "}", "Exceeds the limit"),
    ("[" * 100_000, "nested too deeply"),
    ('{"a": 1,}', r"line 1, column [89]: not valid JSON"),  # Python's place for the error: 3.13 names the comma
    ("[1, 2]", "expected a JSON object; got list"),
    ('{"fx": 800, "fy": 800, "fx": 80}', r"not valid JSON \(key 'fx' appears twice in one object"),
    ('{"cam": {"R": 1, "t": 2, "R": 3}}', r"not valid JSON \(key 'R' appears twice in one object"),
])
def test_read_json_object_refuses_non_finite_numbers_and_bad_json(tmp_path, text, message):
    path = tmp_path / "meta.json"
    path.write_text(text)
    with pytest.raises(InputError, match=rf"^{path}.*{message}"):
        read_json_object(path, "missing")


def test_read_text_of_a_small_file_sets_no_limit_sized_buffer_aside(tmp_path):
    """read(max_bytes + 1) allocated the whole 64 MiB limit for every config, JSON or AGT file read;
    a file over the limit is still refused."""
    import tracemalloc

    (tmp_path / "small.yaml").write_text("a: 1\n")
    tracemalloc.start()
    try:
        assert read_text(tmp_path / "small.yaml") == "a: 1\n"
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 2 ** 20
    (tmp_path / "big.txt").write_text("x" * 101)
    with pytest.raises(InputError, match="larger than 100 bytes"):
        read_text(tmp_path / "big.txt", max_bytes=100)
    assert read_text(tmp_path / "big.txt", max_bytes=101) == "x" * 101


def test_read_text_of_a_named_pipe(tmp_path):
    """A shell's --config <(...) is a named pipe: refused as 'a folder or a device'. Its size is unknown until
    read (fstat says 0), so it is read in chunks up to the limit: whole beyond one chunk, refused over it."""
    import threading

    def served(text: str, max_bytes: int) -> str:
        pipe = tmp_path / "pipe"
        pipe.unlink(missing_ok=True)
        os.mkfifo(pipe)
        writer = threading.Thread(target=lambda: pipe.write_text(text))
        writer.start()
        try:
            return read_text(pipe, max_bytes=max_bytes)
        finally:
            writer.join(timeout=5)
            if writer.is_alive():  # the pipe was never opened (or not to the end): drain it, so the writer ends
                pipe.read_bytes()
                writer.join()

    text = "".join(f"key_{i}: {i}\n" for i in range(20000))  # 267 kB: five chunks
    assert served(text, 10 ** 6) == text
    with pytest.raises(InputError, match="larger than 100 bytes"):
        served("x" * 101, 100)
