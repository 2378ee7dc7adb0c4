"""The shortened clock robustness matrix (issue 17; studies/clock_matrix.py --quick): 4 seeded
cases of 300–600 s with tick tags, read offsets up to 0.9 ms, read jitter up to 100 µs 1σ,
Student-t tails, late reads, ε of both signs, a counter wrap, a reset and a gap.

The aims that apply to short runs are asserted: exact repeat/miss counts, no CLOCK_ANOMALY
outside the injected discontinuities, no false parity/gyro alarm and, where two sawtooth periods
fit in the run, lock within min(2·T/|ε|, 300 s), frequency error ≤ 0.1 ppm and time-line RMS ≤
20 µs beyond the jitter's own contribution. (Latency, the 23 parameters and convergence need the
1-hour runs of the full matrix.) These are the issue's aims, not today's performance: the
tick-tag cases fail until the clock handles them.
"""

from __future__ import annotations

import pytest

from studies.clock_matrix import QUICK_AIMS, run_case
from studies.clock_matrix_cases import QUICK


def _detail(row: dict) -> str:
    return (f"t_lock {row['t_lock_s']} s (aim {row['lock_limit_s']:.0f} s, segments "
            f"{row['lock_segments']}), freq error {row['freq_err_ppm']:+.3f} ppm, time-line RMS "
            f"{row['locked_rms_us']} µs (jitter {row['jitter_us']} µs, all {row['all_rms_us']} µs),"
            f" counts {row['counts']}, CLOCK_ANOMALY {row['anomaly_unexpected_s']:.1f} s "
            f"unexpected ({row['anomaly_s']:.1f} s total), alarms {row['alarm_s']:.1f} s, "
            f"flags {row['flag_seconds']}")


@pytest.mark.parametrize("case", QUICK, ids=[c.name for c in QUICK])
def test_quick_matrix_case(case, tmp_path):
    assert 2 * case.sawtooth_s <= case.duration_s  # the subset is chosen so that two wraps fit
    row = run_case(case, tmp_path)
    applicable = [a for a in QUICK_AIMS
                  if a not in ("lock", "freq", "timeline") or 2 * case.sawtooth_s <= case.duration_s]
    failed = [a for a in applicable if not row["aims"][a]]
    assert not failed, f"{case.name} (seed {case.seed}): aims failed {failed}: {_detail(row)}"
