"""Frames -> attitude: trackers, attitude solvers, filters, the MEMS baseline (issues 3, 4, 8)."""
