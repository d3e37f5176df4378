"""Baselines the rangeslam methods are measured against (not used by the library itself)."""

from .linear_multilateration import linear_multilaterate

__all__ = ["linear_multilaterate"]
