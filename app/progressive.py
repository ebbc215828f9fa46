"""Progressive refinement at rest (Engine.refine): the frames of one pose at rest, each made a batch
of shadow maps at a time, the last the all-sources frame.

Before the all-sources frame, one frame of REFINE_STEP times the drag frame's passes (one level of
the source tree finer), when that is at most REFINE_MAX_SHARE of the all-sources frame's maps (else
the exact frame comes soon enough) and, once both were timed, when it takes less time than the
all-sources frame (else it would show nothing sooner and only delay the exact frame). In rooms a sun
lights its clusters split near the object first, as the drag frame's do (finer_near_split).
"""
from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass, field
from typing import Callable, Generator

import numpy as np

from app.config import FrameConfig
from app.frame_budget import FrameBudget
from recon.scene import SceneObject

REFINE_STEP = 2
REFINE_MAX_SHARE = 1 / 8


def finer_near_split(engine, config: FrameConfig, passes: int | None, sun: bool) -> bool:
    """Whether a full-resolution frame of `config` splits its clusters near the object first (ShadowSources.select's
    near_split, the drag frame's rule): refine's finer frames (cluster frames on full-size maps) in rooms a sun
    lights, unless engine.rest_near_split is False. A sun makes the floor beside the object the brightest secondary
    source, and a cluster of it puts the light of its far members at its one eye beside the object, which blocks
    it (ShadowSources.near_factor): the plain key leaves sun_room's 100-pass frame 0.052 rmse_affected above the
    all-sources frame's (sun_101: 0.279), past CONVERGE_RMSE, and the near split brings it to 0.008 (0.014).
    Without a sun the plain key stays: the lamps' hard shadows need its splits (lamps_room 0.034 -> 0.126 with
    the near split; window_room 0.002 -> 0.083). docs/benchmarks.md, "rest48"."""
    return sun and config.full_maps and passes is not None and getattr(engine, "rest_near_split", True)


FrameSteps = Callable[[SceneObject, FrameConfig], Generator]  # Engine's frame as a generator (yields per batch)


def pose_key(obj: SceneObject) -> bytes:
    """What makes two objects the same for a frame: geometry, normals and albedo."""
    h = hashlib.sha1()
    for a in (obj.vertices, obj.normals, obj.faces, obj.albedo):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.digest()


@dataclass
class _Refinement:
    """The state of one pose at rest: the frames of refine_schedule, each composited a batch at a
    time, the last the all-sources frame."""

    key: tuple  # (pose key, mode)
    steps: object  # the generator of the frame being made
    todo: list = field(default_factory=list)  # FrameConfigs of the frames after it (the last: all sources)
    shown: int = 0  # intermediate frames returned so far
    stage_s: float = 0.0  # compute seconds of the frame being made (refine calls only)
    compute_s: float = 0.0  # seconds spent in refine calls on this pose
    calls: int = 0  # refine calls on this pose
    frames_seen: int = -1  # frames started after its last step (another frame in between: restart)
    frame: object = None  # the finished frame


class Refiner:
    """Engine.refine's schedule and state. frame_steps makes a frame as a generator; traverse(lo, hi)
    lists the sources of an object's box (ShadowSources.traverse); frames_started() counts the
    frames the engine began (render and refine: another frame in between restarts a refinement);
    budget: the engine's FrameBudget (gaps between refine calls must not enter its cost model)."""

    def __init__(self, frame_steps: FrameSteps, traverse, no_sources: bool, frames_started: Callable[[], int],
                 budget: FrameBudget):
        self.frame_steps, self.traverse, self.no_sources = frame_steps, traverse, no_sources
        self.budget = budget  # its cost model learns from drag frames only: refine puts it back
        self.frames_started = frames_started
        self.rest_s: dict[str, float] = {}  # the last measured compute seconds: "finer", "exact" frame
        self._state: _Refinement | None = None

    def forget(self) -> None:
        """Drop the pose being refined (its next call starts over)."""
        self._state = None

    def schedule(self, obj: SceneObject, config: FrameConfig) -> list[FrameConfig]:
        """The frames refine makes of `obj`'s pose at rest, in order: the last is the all-sources frame;
        before it, when the drag budget config.passes is set, a frame of REFINE_STEP x that many passes
        on maps of the all-sources size, if that is at most REFINE_MAX_SHARE of the pose's listed
        sources (a cluster frame that fine is within a few hundredths of the all-sources rmse on the
        benchmark rooms and costs a fraction of it; bench/bench_interactive.py --refine measures both),
        and unless the last such frame took at least the time of the last all-sources frame (then it
        would show no quality sooner, only delay the exact frame). Per pose: a traversal of the shafts
        with the object's box (no per-scene work)."""
        out = [FrameConfig(None, config.mode)]
        if config.passes is None or self.no_sources:
            return out
        t = self.rest_s
        if "finer" in t and "exact" in t and t["finer"] >= t["exact"]:
            return out
        n = REFINE_STEP * config.passes
        listed = int(self.traverse(obj.vertices.min(0), obj.vertices.max(0))[0].sum())
        if n <= REFINE_MAX_SHARE * listed:
            out.insert(0, FrameConfig(n, config.mode, full_maps=True))
        return out

    def refine(self, obj: SceneObject, config: FrameConfig, budget_s: float | None,
               stop: Callable[[], bool] | None = None):
        """Engine.refine (see there): (frame or None). stop() is asked before each step (a batch of shadow
        maps or a stage of the frame): True ends the call there, the state kept for the next call (a frame
        rendered in between restarts it), so a caller's next edit waits for one step at most."""
        key = (pose_key(obj), config.mode)
        st = self._state
        if st is not None and st.frame is None and st.frames_seen not in (-1, self.frames_started()):
            # another frame ran since the last step: it re-aimed the shared shadow maps and the object's
            # BVHs at its own pose, so this one starts over
            st = None
        if st is None or st.key != key:
            first, *todo = self.schedule(obj, config)
            self._state = st = _Refinement(key, self.frame_steps(obj, first), todo)
        if st.frame is not None:
            return st.frame
        if budget_s is None and st.todo:  # to the end: no intermediate frame would be shown, skip them
            st.steps, st.todo = self.frame_steps(obj, st.todo[-1]), []
        t0 = time.perf_counter()
        cost = self.budget.cost
        st.calls += 1
        out = None
        mark = t0
        try:
            while True:
                if stop is not None and stop():
                    break
                try:
                    next(st.steps)
                except StopIteration as done:
                    now = time.perf_counter()
                    self.rest_s["finer" if st.todo else "exact"] = st.stage_s + now - mark  # schedule's
                    st.stage_s, mark = 0.0, now
                    if not st.todo:
                        st.frame = out = done.value
                        break
                    st.steps = self.frame_steps(obj, st.todo.pop(0))  # the next frame of the schedule
                    if budget_s is not None:  # show the intermediate frame now
                        out = done.value
                        out.stats.update(exact=False, refine_frames=st.shown)
                        st.shown += 1
                        break
                    continue
                if budget_s is not None and time.perf_counter() - t0 >= budget_s:
                    break
        except BaseException:
            self._state = None
            raise
        finally:
            self.budget.cost = cost
            now = time.perf_counter()
            st.compute_s += now - t0
            st.stage_s += now - mark
            st.frames_seen = self.frames_started()
        if out is st.frame and out is not None:
            out.stats.update(exact=True, refine_frames=st.shown)
        if out is not None:
            out.stats.update(refine_s=st.compute_s, refine_calls=st.calls)
        return out
