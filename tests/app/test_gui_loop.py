"""PlacementWindow's render loop (app/gui.py) with a stand-in controller and event loop, no window: a late
frame makes it drop the poses made meanwhile (it renders the newest, never queues them); while the mouse
button is held it does not refine; the release refines the pose at rest, and a press stops that; the frame
of a pose an edit replaced is abandoned once the pointer rests, never two in a row."""
import contextlib
import math
import threading
from types import SimpleNamespace

from app.gui import PlacementWindow, _ScriptMouse

WAIT_S = 60.0  # a guard against a hung loop, not a timing


def _pose(k: int):
    return SimpleNamespace(mesh="object.ply", k=k)


class _Controller:
    """Frames and refinement under the test's control: each render waits for `go`; refine returns at once
    (it is asked again while the pose rests) unless `hold` is set, then it waits for `pressed`."""

    def __init__(self):
        self.pose = _pose(0)
        self.rendered: list[int] = []
        self.refined: list[int] = []
        self.started = threading.Semaphore(0)
        self.go = threading.Semaphore(0)
        self.hold = False
        self.refining = threading.Event()
        self.pressed = threading.Event()
        self.stop_said: list[bool] = []
        self.render_stop_said: list[bool] = []  # what each frame's stop answered when asked (after `go`)

    def render(self, pose, stop=None):
        self.rendered.append(pose.k)
        self.started.release()
        assert self.go.acquire(timeout=WAIT_S)
        if stop is not None:  # one pause between two stages, after `go`
            self.render_stop_said.append(stop())
            if self.render_stop_said[-1]:
                return None
        return SimpleNamespace(pixels=None, stats={"cached": False, "frame_s": 0.0, "converged": False})

    def refine(self, pose, budget_s=None, intermediate=False, stop=None):
        self.refined.append(pose.k)
        if self.hold:
            self.stop_said.append(stop())  # at rest, nothing pending: False
            self.refining.set()
            assert self.pressed.wait(WAIT_S)
            self.stop_said.append(stop())  # after the press: True, the refinement ends between two steps
        return None

    def end_gesture(self):
        pass


class _Condition(threading.Condition):
    """The loop's condition, telling when the loop waits for the next request (it is idle)."""

    def __init__(self):
        super().__init__()
        self.idle = threading.Event()

    def wait(self, timeout=None):
        self.idle.set()
        return super().wait(timeout)


def _window(ctl) -> tuple[PlacementWindow, list]:
    import open3d.visualization.gui as gui

    w = PlacementWindow.__new__(PlacementWindow)  # the loop's state only: no Open3D window
    shown = []
    w.gui, w.ctl, w.choices, w.closed, w._dirty, w._script, w._dragging = gui, ctl, [], False, False, None, False
    w._render_cv, w.engine_ready = _Condition(), threading.Event()
    w.frame_times, w.error, w.refined_frames, w.window = [], None, 0, None
    w._edit_t = math.inf  # the pointer keeps moving (no frame is abandoned) unless a test says it rests
    w._tick_t = w._tick_prev = 0.0  # the event loop's last tick and the one before
    w.app = SimpleNamespace(post_to_main_thread=lambda window, fn: fn())
    w._show_frame = lambda fr, pose: shown.append(pose.k)
    w.engine_ready.set()
    return w, shown


def _move(w, ctl, k: int, rests: bool = False):  # what a mouse move does: a new pose, then _on_pose_change's
    # request_frame; rests: the pointer rests from then on (the event loop ticked STILL_S after the move)
    ctl.pose = _pose(k)
    w._edit_t = -math.inf if rests else math.inf
    w.request_frame()


def _frame(ctl):  # wait for the loop to start a frame, then let it finish
    assert ctl.started.acquire(timeout=WAIT_S)
    ctl.go.release()


@contextlib.contextmanager
def _loop_running(w, ctl):
    """The window's render loop on its own thread for the with-block; then the window closes, the stand-in lets a
    waiting frame go, and the loop must have ended."""
    loop = threading.Thread(target=w._render_loop, daemon=True)
    loop.start()
    try:
        yield
    finally:
        w.closed = True
        with w._render_cv:
            w._render_cv.notify()
        ctl.go.release()
        loop.join(WAIT_S)
    assert not loop.is_alive()


def test_a_late_frame_drops_the_poses_made_meanwhile_and_a_press_stops_the_refinement():
    ctl = _Controller()
    w, shown = _window(ctl)
    w._dragging = True  # the button is down (BUTTON_DOWN on the photo): a drag
    _move(w, ctl, 1)
    with _loop_running(w, ctl):
        assert ctl.started.acquire(timeout=WAIT_S)  # pose 1's frame is under way ...
        for k in range(2, 7):  # ... and late: five moves meanwhile
            _move(w, ctl, k)
        ctl.go.release()
        w._render_cv.idle.clear()
        _frame(ctl)  # the next frame: the newest pose's
        assert w._render_cv.idle.wait(WAIT_S)  # the pointer rests a moment: the loop waits, it does not refine
        _move(w, ctl, 7)
        _frame(ctl)
        # 2-5 were dropped, not queued; nothing refined while the button is held
        assert ctl.rendered == [1, 6, 7] and ctl.refined == []
        ctl.hold = True
        T = w.gui.MouseEvent.Type
        w._on_image_mouse(_ScriptMouse(T.BUTTON_UP, 0.0, 0.0))  # the release asks for the pose at rest
        _frame(ctl)
        assert ctl.refining.wait(WAIT_S)
        w._dragging = True  # a press while it refines (on the object's own spot: no new pose)
        ctl.pressed.set()
    assert ctl.rendered == [1, 6, 7, 7] and shown == [1, 6, 7, 7]
    assert ctl.refined == [7] and ctl.stop_said == [False, True]


def test_a_frame_of_a_replaced_pose_is_abandoned_once_the_pointer_rests_never_two_in_a_row():
    ctl = _Controller()
    w, shown = _window(ctl)
    w._dragging = True
    _move(w, ctl, 1)
    with _loop_running(w, ctl):
        assert ctl.started.acquire(timeout=WAIT_S)
        _move(w, ctl, 2)  # the pointer still moves: pose 1's frame is finished and shown
        ctl.go.release()
        assert ctl.started.acquire(timeout=WAIT_S)  # pose 2's frame
        _move(w, ctl, 3, rests=True)  # replaced, and the pointer rests: abandoned between two stages
        ctl.go.release()
        assert ctl.started.acquire(timeout=WAIT_S)  # pose 3's frame at once
        _move(w, ctl, 4, rests=True)  # replaced too, but it follows an abandoned frame: finished
        ctl.go.release()
        _frame(ctl)  # pose 4's frame: its pose is the newest, nothing to abandon
        w._render_cv.idle.clear()
        assert w._render_cv.idle.wait(WAIT_S)
    assert ctl.rendered == [1, 2, 3, 4] and shown == [1, 3, 4]
    assert ctl.render_stop_said == [False, True, False]  # frame 3 had no stop; 4's pose was the newest


def test_the_3d_views_object_is_uploaded_only_while_its_tab_is_shown():
    # each upload costs the main thread a mesh and the renderer a geometry: none while the Photo tab is shown
    import numpy as np

    added = []
    obj = SimpleNamespace(vertices=np.zeros((3, 3)), faces=np.array([[0, 1, 2]]),
                          normals=np.tile([0.0, 1.0, 0.0], (3, 1)), albedo=np.array([0.5, 0.5, 0.5]))
    w = PlacementWindow.__new__(PlacementWindow)
    from recon.io import open3d

    w.o3d = open3d()
    w.ctl = SimpleNamespace(scene_object=lambda pose=None: obj)
    w.tabs = SimpleNamespace(selected_tab_index=0)  # the Photo tab
    w.scene3d = SimpleNamespace(scene=SimpleNamespace(has_geometry=lambda name: False,
                                                      add_geometry=lambda name, g, mat: added.append(name)))
    w._mat_obj, w._object_stale = None, False
    w._show_object()
    w._show_object()
    assert added == [] and w._object_stale
    w.tabs.selected_tab_index = 1
    w._on_tab(1)  # the 3D tab selected: the pose's object now
    assert added == ["object"] and not w._object_stale
    w._on_tab(1)  # nothing stale: no second upload
    assert added == ["object"]


def test_no_preview_is_drawn_while_the_button_is_held():
    # during a drag the window is drawn once per frame (each frame carries the newest outline): the moves' previews
    # wait, and the release shows the one due (the clock is set by hand: no timing)
    drawn = []
    w = PlacementWindow.__new__(PlacementWindow)
    w.ctl = SimpleNamespace(pose=_pose(2))
    w._show_pose = lambda p: drawn.append("label")
    w._show_object = lambda: drawn.append("object")
    w.last_frame = None  # (no frame to draw the outline on in the stand-in)
    w._preview_due, w._preview_t, w._dragging = True, -math.inf, True
    assert not w._preview() and drawn == [] and w._preview_due
    w._dragging = False  # the release
    assert w._preview() and drawn == ["label", "object"] and not w._preview_due


def test_a_tick_held_up_past_still_s_is_not_a_rest_until_another_tick_ends():
    # a move at t = 0, after a tick that ended before it; the next tick's draw held its end (where Open3D runs the
    # tick callback) up to 2 STILL_S: the pointer may be moving still (its moves arrive in the next tick), so the
    # replaced pose's frame is not abandoned; once another tick ends with no edit since, the pointer has rested
    from app.gui import STILL_S

    ctl = _Controller()
    w, _ = _window(ctl)
    old = ctl.pose
    ctl.pose = _pose(2)
    w._edit_t = 0.0
    w._tick_prev, w._tick_t = -0.001, 2 * STILL_S
    assert not w._overtaken(old)
    w._tick_prev, w._tick_t = 2 * STILL_S, 2 * STILL_S + 0.01
    assert w._overtaken(old)
    assert not w._overtaken(ctl.pose)  # the newest pose's frame is never abandoned
    w._edit_t = 2 * STILL_S + 0.005  # a move delivered in that tick: moving again
    assert not w._overtaken(old)
