"""Revisits no loop closure joined (:func:`probmap.metrics.revisits.unjoined_revisits`).

Oracle: an out-and-back drive along a straight corridor, 0.1 m per node, whose answer follows
from the geometry by hand: the way back at x revisits the way out at x once the travel between
them (120.5 - x - x' to the way out at x' within the 2 m radius of x) reaches the 30 m gap:
from x = 46.2 m back to 0. In pieces of 5 m of travel (travel 120.5 - x on the way back), the
piece of 70-75 m revisits in 14 % of its nodes, so the ten from 75 m (x = 45.5 m) on count."""

from __future__ import annotations

import numpy as np
import pytest

from probmap.metrics.revisits import unjoined_revisits


def out_and_back(offset: float = 0.5):
    """Nodes 0.1 m apart from x = 0 to 60 m along y = 0, then back along y = ``offset``
    (the other lane), one node per second."""
    out = np.arange(0.0, 60.0 + 1e-9, 0.1)
    back = out[::-1]
    xy = np.concatenate([np.column_stack([out, np.zeros_like(out)]),
                         np.column_stack([back, np.full_like(back, offset)])])  # fmt: skip
    heading = np.r_[np.zeros(len(out)), np.full(len(back), np.pi)]
    poses = np.column_stack([xy, heading])
    return np.arange(len(poses), dtype=np.float64), poses, len(out)


def test_an_unjoined_way_back_is_one_span():
    t, p, _ = out_and_back()
    r = unjoined_revisits(t, p, np.zeros((0, 2), int))
    (s,) = r.spans
    assert r.pieces == r.unjoined == 10
    # (45.5 or the node after it: the piece's edge, in sums of 0.1 m steps)
    assert p[s.first, 0] == pytest.approx(45.5, abs=0.11) and s.last == len(p) - 1
    assert s.length == pytest.approx(p[s.first, 0], abs=1e-6)
    assert (s.start, s.end) == (t[s.first], t[-1])
    # the way out seen from it: x' = 0 to the largest x' with x' <= x + 1.936 and
    # x' <= 90.5 - x, which is 46.2 m (node 462, one per second)
    assert s.earlier_start == 0.0 and s.earlier_end == pytest.approx(462.0, abs=1.0)
    assert s.box == pytest.approx((0.0, 0.5, p[s.first, 0], 0.5))


def test_a_closure_joins_the_pieces_around_it():
    t, p, _ = out_and_back()
    back_20 = len(p) - 1 - 200  # the way back at x = 20 m
    links = np.array([[back_20, 200]])  # tied to the way out at x = 20 m
    r = unjoined_revisits(t, p, links)
    # the closure (travel 100.5 m) joins the pieces within 5 m of travel of it, those of
    # 95-110 m (x = 25.5-10.6 m); left: 75-95 m (x = 45.5-25.6) and 110-120.5 m (x = 10.5-0)
    assert (r.pieces, r.unjoined) == (10, 7)
    ranges = sorted((p[s.last, 0], p[s.first, 0]) for s in r.spans)
    assert ranges == [pytest.approx((0.0, 10.5), abs=0.11), pytest.approx((25.6, 45.5), abs=0.11)]
    # closures every 10 m join it all
    links = np.array([[len(p) - 1 - k, k] for k in range(0, 460, 100)])
    assert unjoined_revisits(t, p, links).spans == ()


def test_what_does_not_count():
    t, p, _ = out_and_back()
    # a closure within one pass (less than the gap apart) joins nothing
    near = np.array([[len(p) - 1, len(p) - 50]])
    assert len(unjoined_revisits(t, p, near).spans) == 1
    # a way back in a lane beyond the radius is no revisit
    t, p, _ = out_and_back(offset=2.5)
    r = unjoined_revisits(t, p, np.zeros((0, 2), int))
    assert r.pieces == 0 and r.spans == ()
    # spans shorter than min_length are counted, not reported
    t, p, _ = out_and_back()
    r = unjoined_revisits(t, p, np.zeros((0, 2), int), min_length=50.0)
    assert r.unjoined == 10 and r.spans == ()


def test_bad_input_is_named():
    t, p, _ = out_and_back()
    with pytest.raises(ValueError, match="poses"):
        unjoined_revisits(t[:-1], p, np.zeros((0, 2), int))
    with pytest.raises(ValueError, match="links"):
        unjoined_revisits(t, p, np.array([[0, len(p)]]))
    with pytest.raises(ValueError, match="radius"):
        unjoined_revisits(t, p, np.zeros((0, 2), int), radius=0.0)
    assert unjoined_revisits([], np.zeros((0, 3)), []).pieces == 0
