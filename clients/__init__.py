"""Lightweight clients of the track service; they depend on zenoh_track.wire only."""
