"""Looking at runs: a fast preview video, path-traced renders (Mitsuba 3), the run as one USD stage,
a Blender script, and the camera they share."""
