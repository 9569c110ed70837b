"""The loop shell and the service around the pure law: clock, bus, real-time scheduling, summary."""
