"""Yardsticks: Cramer-Rao bounds of the estimators' problems."""

from __future__ import annotations

from rangeslam.evaluation.crlb import MDUBound, mdu_crlb, multilateration_crlb, wall_crlb

__all__ = ["MDUBound", "mdu_crlb", "multilateration_crlb", "wall_crlb"]
