"""Lightweight clients of the track service; they depend on service.wire only."""
