"""Parameter tables (validation, TOML, SI conversion) and input decoding at the wire edge."""

import math

import msgpack
import numpy as np
import pytest

from radical_rt.contract.conventions import ARCSEC, DEG_PER_HR
from radical_rt.contract.params import ParamError, ParamTable, to_si
from radical_rt.stream.packets import InputError, decode_siru, decode_tracker, unpack
from radical_rt.stream.telemetry import PacketError, load_packets, parse_packets


def test_defaults_follow_the_paper():
    si = to_si(ParamTable().active)
    assert si.st_sigma == pytest.approx((3.2 * ARCSEC, 3.2 * ARCSEC, 29 * ARCSEC))
    # P0 = 3 L²: bias L = 3 deg/hr → σ = √3·3 deg/hr
    assert math.sqrt(si.p0_params[0]) == pytest.approx(math.sqrt(3) * 3 * DEG_PER_HR)
    assert si.q_params[4] == pytest.approx(1e-9**2)  # λ: 0.001 ppm/√s
    assert si.q_params[22] == pytest.approx((0.002 * ARCSEC) ** 2)  # φ2 (the last contract state)
    assert si.q_params[-1] == pytest.approx(1e-12) and si.p0_params[-1] == pytest.approx(0.03**2)  # τ
    assert si.bump_sigma["lam"][1] == pytest.approx(500e-6)
    assert si.bump_sigma["mu"][3] == pytest.approx(30e-6)
    assert si.latency_st_s == 0.115


def test_set_is_validated_and_all_or_nothing():
    t = ParamTable()
    with pytest.raises(ParamError, match="unknown parameter 'nope'"):
        t.set({"latency_st_s": 0.2, "nope": 1})
    assert t.active.latency_st_s == 0.115  # nothing applied
    with pytest.raises(ParamError, match="bump_lam_ppm"):
        t.set({"bump_lam_ppm": [1, 2]})
    with pytest.raises(ParamError, match="init_var_rule"):
        t.set({"init_var_rule": "L2"})
    with pytest.raises(ParamError, match="finite"):
        t.set({"gate_st_nis": float("nan")})
    t.set({"latency_st_s": 0.12, "init_var_rule": "L2/3"})
    assert t.active.latency_st_s == 0.12
    t.reset()
    assert t.active.latency_st_s == 0.115


def test_toml_load_errors_name_the_file_and_key(tmp_path):
    p = tmp_path / "p.toml"
    p.write_text("[params]\nst_sigma_cross_arcsec = 4.5\n")
    assert ParamTable.from_toml(p).default.st_sigma_cross_arcsec == 4.5
    p.write_text("[params]\nst_sigma_cross_arcsec = 'x'\n")
    with pytest.raises(ParamError, match=r"p\.toml: st_sigma_cross_arcsec"):
        ParamTable.from_toml(p)
    p.write_text("[params\n")
    with pytest.raises(ParamError, match="not valid TOML"):
        ParamTable.from_toml(p)


def _siru(k=3):
    return {"v": 1, "t_bus": [0.01 * i for i in range(k)], "tt": [10000 * i for i in range(k)],
            "dtheta": [[1e-6] * 4 for _ in range(k)], "status": [0] * k}


@pytest.mark.parametrize("mutate,reason", [
    (lambda m: m.pop("tt"), "missing_field"),
    (lambda m: m.update(dtheta=[[1.0] * 3] * 3), "bad_shape"),
    (lambda m: m.update(t_bus=[0.0, float("nan"), 0.02]), "nonfinite"),
    (lambda m: m.update(t_bus=[0.02, 0.01, 0.03]), "time_backwards"),
    (lambda m: m.update(tt=[1, 2]), "bad_shape"),
    (lambda m: m.update(tt=[-1, 0, 1]), "bad_value"),
    (lambda m: m.update(v=2), "bad_version"),
])
def test_bad_siru_messages_are_rejected_with_a_reason(mutate, reason):
    m = _siru()
    mutate(m)
    with pytest.raises(InputError) as e:
        decode_siru(unpack(msgpack.packb(m)))
    assert e.value.reason == reason


def test_tracker_decoding():
    good = {"v": 1, "t_bus": 1.0, "q": [0, 0, 0, 1], "n_stars": 9, "valid": True}
    t, q, n, valid = decode_tracker(good)
    assert t == 1.0 and n == 9 and valid and np.allclose(q, [0, 0, 0, 1])
    for bad, reason in [({"q": [0, 0, 0, 2]}, "non_unit_quaternion"), ({"q": [0, 0, 1]}, "bad_shape"),
                        ({"n_stars": 1.5}, "bad_type"), ({"valid": 1}, "bad_type"),
                        ({"t_bus": float("inf")}, "nonfinite")]:
        with pytest.raises(InputError) as e:
            decode_tracker({**good, **bad})
        assert e.value.reason == reason
    with pytest.raises(InputError) as e:
        unpack(b"\xc1\xff garbage")
    assert e.value.reason == "malformed"
    with pytest.raises(InputError) as e:
        unpack(msgpack.packb([1, 2]))
    assert e.value.reason == "not_a_map"


def test_siru_tag_beyond_int64_is_a_clear_rejection():
    msg = {"v": 1, "t_bus": [0.0, 0.01], "tt": [2**64, 1], "dtheta": [[0.0] * 4] * 2,
           "status": [0, 0]}
    with pytest.raises(InputError) as e:  # numpy raises OverflowError: rejected, not a crash
        decode_siru(msg)
    assert e.value.reason == "bad_value"


def test_tracker_short_path_equals_checked_path():
    """Well-formed float messages take decode_tracker's short path; its result is the checked
    path's, bit for bit (same normalization sum and divisions)."""
    from radical_rt.stream.packets import _decode_tracker_checked
    rng = np.random.default_rng(7)
    for _ in range(200):
        q = rng.normal(size=4)
        q = (q / np.linalg.norm(q) * (1.0 + rng.normal() * 1e-7)).tolist()
        msg = {"v": 1, "t_bus": float(rng.uniform(0, 1e4)), "q": q, "n_stars": 7, "valid": True}
        a, b = decode_tracker(msg), _decode_tracker_checked(msg)
        assert a[0] == b[0] and a[2:] == b[2:] and np.array_equal(a[1], b[1])


def test_packet_configuration(tmp_path):
    specs = parse_packets({"small": {"fields": ["seq", "t", "flags"], "period_s": 0.5}})
    assert specs["small"].fields == ["seq", "t", "flags"] and specs["small"].period_s == 0.5
    assert specs["large"].period_s == 1.0
    with pytest.raises(PacketError, match="unknown field"):
        parse_packets({"small": {"fields": ["seq", "warp_speed"]}})
    with pytest.raises(PacketError, match="not both"):
        parse_packets({"medium": {"period_s": 1, "decimation": 2}})
    with pytest.raises(PacketError, match="unknown packet"):
        parse_packets({"huge": {}})
    p = tmp_path / "pk.toml"
    p.write_text("[packets.large]\ndecimation = 10\nfields = ['seq', 'est']\n")
    assert load_packets(p)["large"].decimation == 10
