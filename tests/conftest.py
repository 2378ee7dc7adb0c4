"""Fixtures shared by every test module (defined in tests/support)."""

from tests.support.node import archives, batch_ref  # noqa: F401 (fixtures)
