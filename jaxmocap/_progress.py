"""One progress bar for every long loop (tqdm, only imported when a bar is shown)."""

from __future__ import annotations


def progress(items, enabled: bool, desc: str, unit: str = "frame"):
    """`items`, wrapped in a tqdm bar on stderr when `enabled`."""
    if not enabled:
        return items
    from tqdm.auto import tqdm

    return tqdm(items, desc=desc, unit=unit, leave=False)
