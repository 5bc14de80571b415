"""SFA: the track-constrained positioning filter."""
