"""The pass budget of a frame (--passes, --fps): how many shadow maps fit the target frame time, from
the measured fixed and per-pass cost of the frames made so far."""
from __future__ import annotations

from app.config import FrameConfig


class FrameBudget:
    """The measured frame cost (`cost`: {"fixed_s", "per_pass_s"}, None until a frame with sources
    ran) and the pass count it allows. `override` (an int) fixes the pass count (the calibration
    frame's)."""

    def __init__(self):
        self.cost: dict | None = None
        self.override: int | None = None

    def passes(self, config: FrameConfig, sun: bool) -> int | None:
        """The shadow-source passes of a frame: --passes, or those that fit 1/--fps from the measured
        costs; a sun takes one pass of the budget, never dropped. None: one per source."""
        if self.override is not None:
            return self.override
        if config.fps is None or self.cost is None:
            return None if config.passes is None else max(1, config.passes - int(sun))
        budget = 1.0 / config.fps - self.cost["fixed_s"]
        n = int(budget / max(self.cost["per_pass_s"], 1e-6))
        return max(1, min(n, config.passes or n) - int(sun))

    def measured(self, frame_s: float, masks_s: float, n_passes: int) -> None:
        """Update the cost model from a frame of n_passes source passes (none: nothing learnt)."""
        if n_passes:
            self.cost = {"per_pass_s": masks_s / n_passes, "fixed_s": frame_s - masks_s}
