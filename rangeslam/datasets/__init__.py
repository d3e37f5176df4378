"""Loaders for real data sets. Each takes a path; nothing is downloaded or copied."""

from .dechorate import DEchorate, load_dechorate

__all__ = ["DEchorate", "load_dechorate"]
