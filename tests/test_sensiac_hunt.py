"""AGT readings checked against the format's definition: the ARF Ground Truth specification's
grammar (keywords are tokens; line breaks are white space), its ``Tgt`` semantics (``TgtType``
only on targets scored for ATR; a ``Tgt`` without one is a target-like object or false alarm),
and the ``Keyword "Frame# N"`` line that numbers a ``TgtUpd``'s frame (1-based) in the ATR
database's files."""

import math
import re

import numpy as np
import pytest

from torch_atr.data import SensiacSequence, agt_frame_truths, write_arf
from torch_atr.data.sensiac import parse_agt
from torch_atr.validate import InputError


def _truths(text):
    return agt_frame_truths(parse_agt(text, "x.agt"), "x.agt")


def test_several_keywords_on_one_line_are_read_as_such():
    """``Tgt { TgtType "T72" PixLoc 10 20 Aspect 90 }`` is three attributes, not a type
    'T72 PixLoc 10 20 Aspect 90'."""
    (t,) = _truths('Agt { TgtSect { TgtUpd { Time 2004 1 0 0 1 0 Tgt { TgtType "T72" PixLoc 10 20 Aspect 90 } } } }')
    assert (t.vehicle, t.vehicle_class, t.u, t.v, t.aspect) == ("T72", "tank", 10.0, 20.0, math.pi / 2)
    (t,) = _truths('Agt { TgtSect { TgtUpd {\n Tgt {\n  Comment "near the berm" Range 1500\n  TgtType ZSU23\n }\n} } }')
    assert (t.vehicle, t.range_m) == ("ZSU23", 1500.0)


def test_the_tracked_target_is_the_first_scored_one():
    """A ``Tgt`` without ``TgtType`` (a false alarm) listed first is not the truth."""
    (t,) = _truths('Agt { TgtSect { TgtUpd {\n'
                   ' Tgt {\n  Comment "hot rock"\n  PixLoc 1 2\n }\n'
                   ' Tgt {\n  TgtType "BMP2"\n  PixLoc 300 200\n  Range 2000\n }\n'
                   '} } }')
    assert (t.vehicle, t.vehicle_class, t.u, t.v, t.range_m) == ("BMP2", "apc", 300.0, 200.0, 2000.0)
    (t,) = _truths('Agt { TgtSect { TgtUpd {\n Tgt {\n  PixLoc 1 2\n }\n} } }')  # none scored: the first
    assert (t.vehicle, t.u) == ("", 1.0)


AGT_NUMBERED = '''Agt {
 TgtSect {
  TgtUpd {
   Keyword "Frame# 2"
   Tgt {
    TgtType "T72"
    PixLoc 10 20
   }
  }
  TgtUpd {
   Keyword "Frame# 4"
   Tgt {
    TgtType "T72"
    PixLoc 11 21
   }
  }
 }
}
'''


def test_numbered_frames_place_the_truth(tmp_path, caplog):
    """Frames 1 and 3 have no TgtUpd: frame 2's truth is at index 1, frame 4's at index 3."""
    truths = _truths(AGT_NUMBERED)
    assert [t and t.u for t in truths] == [None, 10.0, None, 11.0]
    write_arf(tmp_path / "s.arf", np.zeros((5, 4, 6), np.uint16))
    (tmp_path / "s.agt").write_text(AGT_NUMBERED)
    seq = SensiacSequence(tmp_path / "s.arf")
    assert [seq.truth(i) and (seq.truth(i).u, seq.truth(i).v) for i in range(5)] == [
        None, (10.0, 20.0), None, (11.0, 21.0), None]
    assert "matching by index" not in caplog.text


def test_a_far_frame_number_costs_no_list_of_that_length(tmp_path, caplog):
    """A 150-byte AGT naming Frame# 16777216 against a 3-frame ARF built a list of 16.8 million
    entries (134 MB); the truths are kept by frame, the far one warned of and dropped."""
    import tracemalloc

    write_arf(tmp_path / "s.arf", np.zeros((3, 4, 6), np.uint16))
    (tmp_path / "s.agt").write_text(AGT_NUMBERED.replace('Keyword "Frame# 4"', 'Keyword "Frame# 16777216"'))
    tracemalloc.start()
    try:
        seq = SensiacSequence(tmp_path / "s.arf")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 2 ** 22
    assert [seq.truth(i) and seq.truth(i).u for i in range(3)] == [None, 10.0, None]
    assert "the AGT numbers frames up to 16777216, the ARF has 3" in caplog.text


def test_a_comment_that_mentions_a_frame_does_not_number_one():
    """Only a Keyword whose whole value is "Frame# N" numbers a TgtUpd: an operator's comment naming a
    frame made an unnumbered file a half-numbered one, refused."""
    text = AGT_NUMBERED.replace('Keyword "Frame# 2"', 'Comment "as frame# 1, smoke"').replace(
        'Keyword "Frame# 4"', 'Keyword "Frame# 4 of a re-run"')
    assert [t.u for t in _truths(text)] == [10.0, 11.0]  # matched by index


def test_frame_numbers_beyond_the_arf_are_warned_of(tmp_path, caplog):
    write_arf(tmp_path / "s.arf", np.zeros((3, 4, 6), np.uint16))
    (tmp_path / "s.agt").write_text(AGT_NUMBERED)
    seq = SensiacSequence(tmp_path / "s.arf")
    assert f"{tmp_path / 's.arf'}: the AGT numbers frames up to 4, the ARF has 3" in caplog.text
    assert [seq.truth(i) and seq.truth(i).u for i in range(3)] == [None, 10.0, None]


@pytest.mark.parametrize("second,message", [
    ('Keyword "Frame# 2"', "x.agt, line 10: TgtUpd numbers frame 2, as the TgtUpd at line 3 does"),
    ('Comment "second pass"', "x.agt, line 10: this TgtUpd has no Frame# line, but the TgtUpd at line 3 has one"),
    ('Keyword "Frame# 0"', "x.agt, line 11: Frame# 0: frames count from 1 to at most 16777216"),
    ('Keyword "Frame# 99999999999999999999999"', "x.agt, line 11: Frame# 99999999999999999999999: frames count "
                                                  "from 1 to at most 16777216"),
])
def test_ambiguous_frame_numbers_are_refused(second, message):
    text = AGT_NUMBERED.replace('Keyword "Frame# 4"', second)
    with pytest.raises(InputError, match=re.escape(message)):
        _truths(text)
