"""The terminal display, `track-display`: the table and scene of the frames."""
