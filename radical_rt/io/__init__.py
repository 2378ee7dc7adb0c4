"""Checkpoints, transports (Zenoh, in-memory), output paths and the MCAP archive layer."""
