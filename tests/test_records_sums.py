"""``probmap._sums.field_sums`` and the count records that add with it, against sums written
out field by field."""

from __future__ import annotations

import dataclasses

import pytest

from probmap._sums import field_sums
from probmap.datasets.validate import ReadingReport
from probmap.grid.occupancy import ScanStats


def test_scan_stats_add_every_field():
    a = ScanStats(scans=1, beams=181, hits=170, max_range=9, dropped=2, cell_updates=4000)
    b = ScanStats(scans=3, beams=540, hits=500, max_range=30, dropped=10, cell_updates=12000)
    s = a + b
    assert type(s) is ScanStats
    assert s == ScanStats(4, 721, 670, 39, 12, 16000)
    # no field left out: each one is the sum of the two
    for f in dataclasses.fields(ScanStats):
        assert getattr(s, f.name) == getattr(a, f.name) + getattr(b, f.name)


def test_reading_report_adds_counts_and_merges_beam_histograms():
    a = ReadingReport(1, 3, 1, 1, 1, 0, ((3, 1),), 2)
    b = ReadingReport(2, 10, 8, 0, 0, 2, ((3, 1), (4, 1)), 1)
    s = a + b
    assert s == ReadingReport(3, 13, 9, 1, 1, 2, ((3, 2), (4, 1)), 3)
    for f in dataclasses.fields(ReadingReport):
        if f.name != "beam_counts":
            assert getattr(s, f.name) == getattr(a, f.name) + getattr(b, f.name)
    # the empty report is the identity
    assert ReadingReport() + a == a


def test_field_sums_refuses_a_field_the_record_lacks():
    a = ScanStats(1, 1, 1, 0, 0, 1)
    with pytest.raises(TypeError, match="ScanStats has no field 'beam_counts'"):
        field_sums(a, a, beam_counts=())
