"""Benchmarks (``make bench``): timings printed, never asserted as tests."""
import pytest

pytestmark = pytest.mark.benchmark


def test_bench_adc_synthesis():
    import bench_adc

    rows = bench_adc.run((1000, 10000))
    print("\n" + bench_adc.to_markdown(rows))
    print("\n" + bench_adc.to_markdown_vs_sionna(bench_adc.run_vs_sionna((1000, 10000))))
