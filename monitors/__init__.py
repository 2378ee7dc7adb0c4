"""Dashboards and reports; they read only the contract's messages."""
