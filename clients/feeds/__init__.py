"""Feeds: `track-feed` (the reference scenarios, swarms, labelled, batched and unlabelled
scans), the scenarios and their plots, and `track-replay` (a recording played back)."""
