"""Tests of probmap.pipelines (a package so that its file names may repeat those of tests/grid etc.)."""
