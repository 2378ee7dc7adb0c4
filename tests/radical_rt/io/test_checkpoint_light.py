"""A checkpoint without the FDI history (``checkpoint.capture(..., history=False)``, a fleet's
periodic replica) restored as a new stream continues exactly as the full checkpoint restored
as a new stream: the same output messages, byte for byte, and the same final state. Checked at
a nominal point and in the middle of an FDI alarm (hypothesis bank running), where the full
checkpoint carries hundreds of seconds of samples. The light one is far smaller."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from radical_rt.apps.batch import make_processor
from radical_rt.io import checkpoint as ckpt
from tests.support.streams import bias_step_messages


@pytest.fixture(scope="module")
def fault_stream(tmp_path_factory):
    """300 s from bus time 1000 s, gyro B bias step of 5 deg/hr at 120 s."""
    return bias_step_messages(tmp_path_factory.mktemp("ckpt_light"))


def _cut_points(msgs) -> dict[str, int]:
    """A nominal point (90 s) and the first point with the alarm's bank running."""
    sp, out = make_processor(), {}
    for i, (topic, ns, data) in enumerate(msgs):
        sp.feed(topic, data)
        if "nominal" not in out and ns * 1e-9 - 1000.0 > 90.0:
            out["nominal"] = i + 1
        f = sp.engine.fdi
        if f.state == "alarm" and f.bank is not None and f.bank.k >= 3:
            out["alarm"] = i + 1
            return out
    raise AssertionError("no alarm with a running bank in the scenario")


def _continue(state, msgs) -> tuple[list[bytes], object]:
    sp = make_processor()
    ckpt.restore(sp, ckpt.loads(ckpt.dumps({"v": state}))["vehicles"]["v"], new_stream=True)
    outs = [msgpack.packb([k, m], default=str) for topic, _, data in msgs
            for k, m in sp.feed(topic, data)]
    outs += [msgpack.packb([k, m], default=str) for k, m in sp.end_stream(None)]
    return outs, sp


@pytest.mark.parametrize("where", ["nominal", "alarm"])
def test_light_checkpoint_continues_a_new_stream_exactly(fault_stream, where):
    cut = _cut_points(fault_stream)[where]
    sp = make_processor()
    for topic, _, data in fault_stream[:cut]:
        sp.feed(topic, data)
    full, light = ckpt.capture(sp, "v"), ckpt.capture(sp, "v", history=False)
    n_full, n_light = len(ckpt.dumps({"v": full})), len(ckpt.dumps({"v": light}))
    assert n_light < n_full / 3, (n_light, n_full)  # the history dominates the full one
    mon = light["running"]["fdi"]["monitor"]
    assert mon["snaps"] == [] and mon["trk"]["seq"]["shape"] == [0] and mon["bank"] is None
    rest = fault_stream[cut:]
    out_full, sp_full = _continue(full, rest)
    out_light, sp_light = _continue(light, rest)
    assert len(out_full) > 100 and out_light == out_full
    for k in ("xp", "d", "U", "q"):
        assert np.array_equal(getattr(sp_light.engine, k), getattr(sp_full.engine, k)), k
    assert sp_light.engine.fdi.isolations == sp_full.engine.fdi.isolations
