"""Shared helpers of the test suite (no tests here): seeded input streams and golden outputs."""
