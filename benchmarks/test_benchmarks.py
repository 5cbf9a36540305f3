"""Benchmarks (``make bench``): timings printed, never asserted as tests."""
import pytest

pytestmark = pytest.mark.benchmark


def test_bench_adc_synthesis():
    import bench_adc

    rows = bench_adc.run((1000, 10000))
    print("\n" + bench_adc.to_markdown(rows))
