"""Fault detection and isolation: parity detector, history, hypothesis bank."""
