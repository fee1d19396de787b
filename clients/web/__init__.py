"""The browser map, `track-web`: an aiohttp server on loopback relaying the frames to
the page in `web_static/`."""
