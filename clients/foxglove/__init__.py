"""The live picture in Foxglove and Lichtblick, `track-foxglove`: a Foxglove WebSocket
server (foxglove-sdk) serving the scene drawn by clients/lib/scene.py."""
