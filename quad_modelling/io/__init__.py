"""Readers and writers: thesis .mat logs, NanoBench CSV, MCAP bags, reports."""

from quad_modelling.io.loader import detect_format, load_flight

__all__ = ["detect_format", "load_flight"]
