"""Time: latency models, the timed closed loop, exact-delay frequency-domain margins."""
