"""Synthetic MESSENGER-like truth and sensor simulation (independent of the filter models)."""
