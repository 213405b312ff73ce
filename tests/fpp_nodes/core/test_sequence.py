import numpy as np
import pytest

from fpp_nodes.core.patterns import PatternSet, pattern_images
from fpp_nodes.core.sequence import SequenceAssembler, ShownPatterns


def frame(i):
    return np.full((4, 5), i, np.uint8)


def feed(assembler, indices, start_ns=0):
    done, reasons = [], []
    for k, i in enumerate(indices):
        seq, why = assembler.add(i, start_ns + k * 1000, frame(i))
        done += [seq] if seq else []
        reasons += [why] if why else []
    return done, reasons


def test_complete_sequences_in_order():
    a = SequenceAssembler(4)
    done, reasons = feed(a, [0, 1, 2, 3, 0, 1, 2, 3])
    assert len(done) == 2 and not reasons
    np.testing.assert_array_equal(done[0].images[:, 0, 0], [0, 1, 2, 3])
    assert done[0].images is not done[1].images  # a finished stack is never overwritten
    assert a.stats.completed == 2 and a.stats.dropped == 0


@pytest.mark.parametrize(
    "indices, reason",
    [
        ([0, 1, 3, 0, 1, 2, 3], "missing frame"),
        ([0, 1, 1, 2, 3, 0, 1, 2, 3], "duplicated frame"),
        ([0, 2, 1, 3, 0, 1, 2, 3], "missing frame"),
        ([0, 1, 2, 1, 0, 1, 2, 3], "out of order frame"),
        ([0, 1, 0, 1, 2, 3], "incomplete"),  # the projector restarted its sequence
    ],
)
def test_broken_sequences_are_dropped_never_mixed(indices, reason):
    a = SequenceAssembler(4)
    done, reasons = feed(a, indices)
    assert len(done) == 1 and reasons and reasons[0].startswith(reason)
    np.testing.assert_array_equal(done[0].images[:, 0, 0], [0, 1, 2, 3])
    assert a.stats.dropped == 1


def test_time_running_backwards_drops_the_sequence():
    a = SequenceAssembler(4)
    a.add(0, 5000, frame(0))
    a.add(1, 6000, frame(1))
    seq, why = a.add(2, 1000, frame(2))  # the camera restarted its clock
    assert seq is None and "time went backwards" in why
    done, _ = feed(a, [0, 1, 2, 3], start_ns=10_000)
    assert len(done) == 1


def test_a_frame_of_another_size_ends_the_sequence():
    a = SequenceAssembler(3)
    a.add(0, 0, frame(0))
    seq, why = a.add(1, 10, np.zeros((8, 8), np.uint8))
    assert seq is None and why.startswith("frame changed")
    assert a.stats.frames_discarded >= 1


def test_joining_mid_sequence_waits_for_the_start():
    a = SequenceAssembler(4)
    done, reasons = feed(a, [2, 3, 0, 1, 2, 3])
    assert len(done) == 1 and not reasons and a.stats.frames_discarded == 2


def test_a_partial_sequence_is_not_completed_a_whole_cycle_later():
    """A camera away for a whole number of cycles comes back at the very index the sequence in
    progress expects: the index alone cannot tell, the projector's showings can. Dropped, never mixed."""
    a = SequenceAssembler(4)
    for i in range(2):
        assert a.add(i, 10 * i, frame(i), showing=i) == (None, None)
    seq, why = a.add(2, 100, frame(2), showing=2 + 4 * 3)
    assert seq is None and why.startswith("missing frames: 12 patterns")
    done, reasons = feed(a, [3, 0, 1, 2, 3], start_ns=200)
    assert len(done) == 1 and not reasons and a.stats.dropped == 1


def test_frames_are_matched_to_the_pattern_shown_nearest_their_stamp():
    """ShownPatterns, as capture_sequence and the bag data set use it: a pattern image is known by its
    bytes, a frame takes the pattern shown nearest its stamp within the offset, and a frame waits until
    a later pattern shows none can match it."""
    patterns = PatternSet(width=256, height=8)
    images = pattern_images(patterns)
    shown = ShownPatterns(patterns, max_offset_ns=5)
    assert shown.add(100, images[3]) == 3 and shown.add(200, images[4]) == 4
    assert shown.add(300, np.zeros_like(images[0])) is None and len(shown.events) == 2  # not in the set
    assert shown.match(103) == (3, 0) and shown.match(196) == (4, 1) and shown.match(150) is None
    assert not shown.none_will_match(210)  # its pattern may still arrive
    assert shown.none_will_match(150)  # the pattern at 200 came after 150's window closed
