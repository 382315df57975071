"""Looking at runs: a fast preview video, path-traced renders (Mitsuba 3), a Blender script."""
