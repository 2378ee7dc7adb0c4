"""Telemetry simulation, MCAP archives, replay over Zenoh and recording."""
