"""Recording: `track-record` (the key space to an MCAP file) and reading recordings."""
