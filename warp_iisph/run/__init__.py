"""Runs on disk: the run folder, file formats, the runner, background frame output, meshing a run."""
