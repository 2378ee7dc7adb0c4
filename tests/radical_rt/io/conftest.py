"""Fixtures of the archive tests: the synthetic stream and an archive written from it."""

from __future__ import annotations

import pytest

from tests.support.archive_stream import make_stream, write_stream


@pytest.fixture(scope="module")
def stream():
    return make_stream()


@pytest.fixture(scope="module")
def archive(tmp_path_factory, stream):
    return write_stream(tmp_path_factory.mktemp("arc") / "a.mcap", stream)
