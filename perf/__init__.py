"""Benchmarks and latency runs."""
