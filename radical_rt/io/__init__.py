"""Checkpoints and transports (Zenoh, in-memory)."""
