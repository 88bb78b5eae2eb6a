"""Benchmark: every method on every case, interleaved, with paper metrics and plots."""
