"""The progress bar every long command shows: frames (or a sweep's variants) done, on stderr, off with --no-progress."""

from __future__ import annotations

import sys

from tqdm import tqdm


def frame_bar(total: int, enabled: bool = True, desc: str | None = None, unit: str = "frame") -> tqdm:
    """A bar over ``total`` frames (or other ``unit``s); a disabled one accepts the same calls and draws nothing. It
    goes when closed: the command's last line (its summary or its error) stands alone."""
    return tqdm(
        total=total, unit=unit, dynamic_ncols=True, file=sys.stderr, desc=desc, disable=not enabled, leave=False
    )
