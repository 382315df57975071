"""Images out: a ``WIDTHxHEIGHT`` option, and image sequences written as an MP4 or a GIF."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..run.atomic import FILE_MODE, temporary_beside
from ..run.folder import RunError


def parse_resolution(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise RunError(f"--resolution {text!r}: must be WIDTHxHEIGHT, e.g. 640x360") from None
    if not (16 <= w <= 8192 and 16 <= h <= 8192) or w % 2 or h % 2:
        raise RunError(f"--resolution {text}: width and height must be even numbers in [16, 8192]")
    return w, h


# The slowest a video plays (frames per second): a run with fewer frames a second plays at this.
MIN_FPS = 0.1


def write_video(images, path, fps: float, gif: bool = False) -> None:
    """Write RGB uint8 frames (an iterable of (H, W, 3) arrays) as an MP4 (H.264) or a GIF."""
    import imageio.v2 as imageio

    path = Path(path)
    fps = max(float(fps), MIN_FPS)  # ffmpeg reads a rate to two decimals; a GIF's frame time is whole ms
    if path.is_dir():
        raise RunError(f"--out {path}: is a folder; give a video file name (.{'gif' if gif else 'mp4'})")
    path.parent.mkdir(parents=True, exist_ok=True)
    # a name of its own beside the video (two previews at once never share one), ending in the
    # video's suffix, which says the format
    tmp = Path(temporary_beside(path, f".{path.stem}.", f".part{path.suffix}"))
    try:
        if gif:
            writer = imageio.get_writer(tmp, mode="I", duration=1000.0 / fps, loop=0)
        else:
            writer = imageio.get_writer(
                tmp, fps=fps, codec="libx264", quality=7, macro_block_size=2, pixelformat="yuv420p"
            )
        try:
            for im in images:
                writer.append_data(np.asarray(im))
        finally:
            writer.close()
        if tmp.stat().st_size == 0:  # the encoder gave up without a word: keep the video that was there
            raise RuntimeError("the encoder wrote nothing")
        os.chmod(tmp, FILE_MODE)  # readable as any file the user makes (mkstemp's are private)
        tmp.replace(path)  # a video that is there is complete
    except (OSError, RuntimeError) as e:  # a full disk reaches us as a broken pipe to ffmpeg
        tmp.unlink(missing_ok=True)
        if isinstance(e, OSError) and e.errno is not None and not isinstance(e, BrokenPipeError):
            raise OSError(e.errno, e.strerror, str(path)) from None
        raise OSError(
            None, f"could not write the video ({type(e).__name__}: {' '.join(str(e).split())[:200]})", str(path)
        ) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
