"""``simbench bench pipeline``'s table: the start search is printed apart from the per-frame
stages, and spread over the frames it gives the amortised total (known values)."""

from __future__ import annotations

from simbench.benchmarks.pipeline import PipelineBenchmark


def test_start_search_is_apart_from_the_per_frame_total():
    stages = {"detection": 9.0, "correspondence": 2.0, "labelling": 11.0, "tracking": 0.0, "reconstruction": 1.0,
              "skeleton": 5.0}
    b = PipelineBenchmark(30, 4, (640, 480), 39, stages, reference_ms=6.0, start_search_ms=1500.0)
    assert b.total_ms == 28.0
    text = b.table()
    assert "total                28.00   target 33 ms (30 Hz): met" in text
    assert "the total is 78.00 ms/frame" in text          # 28 + 1500 / 30
    assert "start search       1500.00" in text
    assert "detection / reference: 1.50x" in text
