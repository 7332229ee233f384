"""Progress for long work: a tqdm bar for Python loops, a stderr line for compiled loops."""

from __future__ import annotations

import sys
import time


def progress(items, enabled: bool, desc: str, unit: str = "frame"):
    """`items`, wrapped in a tqdm bar on stderr when `enabled`."""
    if not enabled:
        return items
    from tqdm.auto import tqdm

    return tqdm(items, desc=desc, unit=unit, leave=False)


_STARTED: dict[str, tuple[float, int]] = {}


def report(label: str, done, total, detail: str = "", final: bool = False) -> None:
    """One overwritten stderr line: `label done/total`, `detail`, time per unit and ETA.

    Called from inside jitted loops through `jax.debug.callback` (arguments arrive as
    arrays). The clock starts at the first report of `label` whose `done` is not
    larger than the last one seen (a new run), so the rate excludes compilation.
    """
    done, total = int(done), int(total)
    now = time.perf_counter()
    start = _STARTED.get(label)
    if start is None or done <= start[1]:
        _STARTED[label] = start = (now, done)
    t0, first = start
    rate = ""
    if done > first:
        per = (now - t0) / (done - first)
        rate = f", {per:.3g} s per {label.split()[-1]}, ETA {per * (total - done):.0f} s at most"
    print(f"\r{label} {done}/{total}{': ' + detail if detail else ''}{rate}" + ("\n" if final else "   "),
          end="", file=sys.stderr, flush=True)  # fmt: skip


class StageClock:
    """Stage timings and one progress line per stage."""

    def __init__(self, log):
        self.say = log if log is not None else (lambda *_: None)
        self.timings: dict[str, float] = {}
        self.last = time.perf_counter()

    def done(self, stage: str, line: str) -> None:
        now = time.perf_counter()
        self.timings[stage] = now - self.last
        self.last = now
        self.say(f"{stage:<8s} {line} ({self.timings[stage]:.1f} s)")
