"""Fixtures of the replay and record tests."""

from __future__ import annotations

from pathlib import Path

import pytest

from replayer.synth.api import synthesize


@pytest.fixture(scope="module")
def archives(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """a: 60 s from bus time 1000 s; b: 20 s from 5000 s (a disjoint second stream)."""
    d = tmp_path_factory.mktemp("replay_archives")
    out = {}
    for name, t0, dur, seed in (("a", 1000.0, 60, 1), ("b", 5000.0, 20, 2)):
        toml = d / f"{name}.toml"
        toml.write_text(f'base = "2006216"\nt_start_s = {t0}\n')
        out[name] = synthesize(toml, d / f"{name}.mcap", seed=seed, duration=dur).path
    return out

