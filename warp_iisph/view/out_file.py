"""A view's ``--out``: the one rule for the file that preview, plot, usd and blender-script write
(its default place in the run folder, the suffixes it may end in, and what of the run it must never
replace), each refusal one line naming ``--out`` and what is allowed. The run folder's lock, taken
while the file is written into it, is :func:`~warp_iisph.run.lock.writing_into`'s."""

from __future__ import annotations

import os
from pathlib import Path

from ..run.folder import RECORD, VIEW_FILES, RunError, RunFolder


def view_file(run: RunFolder, out, default: str, suffixes: tuple[str, ...], what: str, note: str = "") -> Path:
    """Where a view of ``run`` writes: ``out`` as given (``--out``; ``None``: ``RUN_DIR/default``).
    ``RunError`` naming ``--out`` when it is empty, a folder, not ending in one of ``suffixes``
    (in any case; ``note`` says more of them), one of the run's own files or in a folder of its
    frames (``what``: the view, as the refusal names it), another run folder's own files, views
    (:data:`~warp_iisph.run.folder.VIEW_FILES`) or frame folders, under a file instead of a folder, or in
    a folder this process may not write to. Nothing is written."""
    allowed = ", ".join(suffixes) + (f" ({note})" if note else "")
    if out is not None and not str(out):
        raise RunError(f"--out '': empty; give a file name ending in {allowed}")
    path = Path(out) if out is not None else run.path / default
    if path.is_dir() or str(out or "").endswith(("/", os.sep)):  # a trailing slash asks for a folder
        raise RunError(f"--out {out or path}: is a folder; give a file name ending in {allowed}, e.g. {path / default}")
    if path.suffix.lower() not in suffixes:
        raise RunError(f"--out {path}: must end in {allowed}")
    if run.holds_as_its_own(path):
        raise RunError(f"--out {path}: one of the run's own files or in its frame folders; put the {what} elsewhere")
    other = next((f for f in (path.parent, *path.parent.parents) if (f / RECORD).is_file()), None)
    if other is not None and other.resolve() != run.path.resolve():  # into another run's folder
        if RunFolder(other).holds_as_its_own(path) or (path.parent == other and path.name in VIEW_FILES):
            raise RunError(
                f"--out {path}: one of the run in {other}'s own files or views, or in its frame folders; "
                f"put this run's {what} elsewhere"
            )
    parent = path.parent
    while not parent.exists() and parent != parent.parent:  # the folders the writer would make
        parent = parent.parent
    if parent.exists() and not parent.is_dir():
        raise RunError(f"--out {path}: {parent} is a file, not a folder")
    if parent.is_dir() and not os.access(parent, os.W_OK | os.X_OK):  # found now, not after the work
        raise RunError(f"--out {path}: {parent} is not writable; put the {what} where you may write")
    return path
