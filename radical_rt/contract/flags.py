"""Fault flag bits (CONTRACT §3.1) and engine modes."""

from __future__ import annotations

from enum import IntFlag


class Flag(IntFlag):
    """Bits of the ``flags`` field of telemetry and fault messages."""

    PARITY_ALARM = 1 << 0
    GYRO_A_FAILED = 1 << 1
    GYRO_B_FAILED = 1 << 2
    GYRO_C_FAILED = 1 << 3
    GYRO_D_FAILED = 1 << 4
    ST1_EDITED = 1 << 5
    ST2_EDITED = 1 << 6
    ST1_STALE = 1 << 7
    ST2_STALE = 1 << 8
    GYRO_GAP = 1 << 9
    CLOCK_ANOMALY = 1 << 10
    NUMERIC = 1 << 11
    INPUT_REJECTED = 1 << 12
    NOT_CONVERGED = 1 << 13
    # extensions (docs/contract_extensions.md)
    ST1_CONFLICT = 1 << 16  # a second source on the st1 topic: ST1 samples not used
    ST2_CONFLICT = 1 << 17  # a second source on the st2 topic: ST2 samples not used
    INPUT_GAP = 1 << 18  # input lost: a gap in the siru bus times, a jump, a loss at end of stream
    LINK_LOSS = 1 << 19  # no input for --stale-after s of wall time while a stream was active
    EXCITATION_LOW = 1 << 20  # a maneuver is under way but some unconverged group learns nothing


GYRO_FAILED = (Flag.GYRO_A_FAILED, Flag.GYRO_B_FAILED, Flag.GYRO_C_FAILED, Flag.GYRO_D_FAILED)
MODES = ("init", "converging", "converged", "degraded")


def flag_names(bits: int) -> list[str]:
    """Names of the flags set in ``bits``, in bit order."""
    return [f.name for f in Flag if bits & f and f.name]
