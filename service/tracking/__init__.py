"""Tracking: the track store (stacked arrays), the tracker loop and its components
(associator, initiator, deleter; the estimation filters are its updaters), track
status, the display state and the display clock. Imports estimation and the wire
contract, never Zenoh (tests/test_layers.py).
"""
