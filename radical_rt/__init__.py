"""RADICAL-RT: real-time RIMU calibration and attitude determination (UD-factorized EKF)."""

__version__ = "0.1.0"
