"""Frames -> attitude: trackers, attitude solvers, filters, the MEMS baseline."""
