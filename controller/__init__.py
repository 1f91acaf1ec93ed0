"""Attitude controllers (PID, MPC) behind one interface (issue 5)."""
