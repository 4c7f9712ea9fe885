"""The real-time twin's schedule (twin.realtime.Pacer) on a scripted wall clock."""

from __future__ import annotations

import json

import pytest

from twin.realtime import REALTIME_FILE, Pacer
from vigil.report.records import read_realtime

T = 0.02


def run(pacer: Pacer, walls: list[float]) -> list[int]:
    """Call the pacer at each wall time, step what it owes there; the owed counts."""
    owed = []
    for w in walls:
        n = pacer.due(w)
        for _ in range(n):
            pacer.stepped(w)
        owed.append(n)
    return owed


def test_on_time_one_period_per_period_and_never_ahead_of_the_wall_clock():
    p = Pacer(T)
    walls = [10.0 + k * T / 2 for k in range(201)]  # polled twice a period for 2 s
    owed = run(p, walls)
    assert owed[0] == 0  # the first call starts the schedule
    assert sum(owed) == 100  # 2 s of wall time: 100 periods, not one more
    assert max(owed) == 1
    s = p.stats
    assert s.sim_s == pytest.approx(2.0)
    assert s.wall_s == pytest.approx(2.0)
    assert s.factor == pytest.approx(1.0)
    assert s.late_ticks == 0 and s.slips == 0
    assert s.max_lag_s < T / 2 + 1e-9


def test_a_stall_is_caught_up_and_counted_late():
    p = Pacer(T)
    walls = [0.0] + [k * T for k in range(1, 11)] + [0.2 + 0.5]  # 0.5 s without a call
    owed = run(p, walls)
    assert owed[-1] == 25  # the half second's periods, stepped at once
    s = p.stats
    assert s.factor == pytest.approx(1.0)  # caught up: no simulated time lost
    assert s.max_lag_s == pytest.approx(0.5 - T)  # the first owed period waited longest
    # periods due more than 0.1 s before the catch-up are late: those due at 0.22-0.58 s
    assert s.late_ticks == 19
    assert s.slips == 0


def test_falling_further_behind_than_the_catch_up_bound_slips():
    p = Pacer(T, max_catchup_s=1.0)
    owed = run(p, [0.0, T, 3.0 + T, 3.0 + 2 * T])
    assert owed == [0, 1, 1, 1]  # the 3 s gap is not stepped through
    s = p.stats
    assert s.slips == 1 and s.slipped_s == pytest.approx(3.0 - T)
    assert s.sim_s == pytest.approx(3 * T)
    assert s.factor < 0.05  # the lost time counts against real time


def test_a_process_that_cannot_keep_up_reports_a_factor_below_one():
    p = Pacer(T, max_catchup_s=0.2)
    # each call costs 3 periods of wall time but is owed 3: it keeps up ...
    owed = run(p, [k * 3 * T for k in range(50)])
    assert p.stats.factor == pytest.approx(1.0, abs=0.03)
    assert max(owed) == 3
    # ... whereas one whose every stepped period costs 1.5 periods of wall time slips
    slow = Pacer(T, max_catchup_s=0.2)
    w = 0.0
    slow.due(w)
    for _ in range(200):
        for _ in range(slow.due(w)):
            w += 1.5 * T
            slow.stepped(w)
        w += 0.001
    assert slow.stats.slips > 0
    assert slow.stats.factor == pytest.approx(1 / 1.5, abs=0.08)


def test_frames_delivered_and_dropped():
    p = Pacer(T)
    p.frame(sent=True)
    p.frame(sent=True, due=3)  # two periods' frames skipped while catching up
    s = p.stats.to_json()
    assert (s["frames"], s["frames_due"], s["dropped_frames"]) == (2, 4, 2)


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_bad_periods_are_refused_by_name(bad):
    with pytest.raises(ValueError, match="period_s"):
        Pacer(bad)


def test_the_report_reads_the_stats_and_warns_on_a_bad_file(tmp_path):
    warnings: list[str] = []
    assert read_realtime(tmp_path, warnings) is None and not warnings  # lock-step run
    p = Pacer(T)
    run(p, [0.0, T, 2 * T])
    (tmp_path / REALTIME_FILE).write_text(json.dumps(p.stats.to_json()))
    got = read_realtime(tmp_path, warnings)
    assert got is not None and got["ticks"] == 2 and got["factor"] == pytest.approx(1.0)
    (tmp_path / REALTIME_FILE).write_text("[1, 2]")
    assert read_realtime(tmp_path, warnings) is None
    assert warnings and REALTIME_FILE in warnings[0]


class FakeRenderer:
    """Records on which thread it was made, updated, rendered and closed."""

    def __init__(self, log: list, fail: bool = False):
        import threading

        self.log, self.fail, self.scene = log, fail, None
        self.log.append(("made", threading.current_thread().name))

    def update_scene(self, data, camera=None):
        self.scene = (data, camera)

    def render(self):
        import threading

        import numpy as np

        self.log.append(("render", threading.current_thread().name))
        if self.fail:
            raise RuntimeError("GL lost")
        return np.full((2, 3, 3), self.scene[0], np.uint8)

    def close(self):
        import threading

        self.log.append(("closed", threading.current_thread().name))


def test_the_async_camera_renders_on_its_thread_one_frame_at_a_time():
    from twin.camera_thread import AsyncCamera

    log: list = []
    cam = AsyncCamera(lambda: FakeRenderer(log), camera="ceiling")
    assert cam.collect() is None  # nothing in flight
    assert cam.render_ms() is None  # no frame yet
    assert cam.capture(7, 1.25)
    assert not cam.capture(8, 1.35)  # one in flight: the next frame is dropped
    t_s, img = cam.collect(wait=True)
    assert t_s == 1.25 and int(img[0, 0, 0]) == 7  # the scene taken at capture
    assert cam.capture(9, 1.45)
    assert cam.collect(wait=True)[0] == 1.45
    median_ms, max_ms = cam.render_ms()
    assert 0.0 <= median_ms <= max_ms + 0.05
    cam.close()
    threads = {what: name for what, name in log}
    assert threads["made"] == threads["render"] == threads["closed"] == "camera-render"


def test_a_failed_render_reaches_the_collector():
    from twin.camera_thread import AsyncCamera

    cam = AsyncCamera(lambda: FakeRenderer([], fail=True), camera=0)
    cam.capture(1, 0.0)
    with pytest.raises(RuntimeError, match="GL lost"):
        cam.collect(wait=True)
    assert not cam.busy
    cam.close()


def test_the_twin_s_async_camera_renders_what_render_camera_renders():
    import numpy as np

    from twin.config import TwinConfig

    t_s, img, direct = _threaded_and_direct(TwinConfig())
    assert t_s == pytest.approx(0.5)
    assert np.array_equal(img, direct)


def _threaded_and_direct(cfg):
    """After 0.5 s of the twin: the render thread's frame (its capture time, the image)
    and ``render_camera()``'s image of the same instant."""
    from twin.twin import Twin

    with Twin(cfg, seed=0) as tw:
        for _ in range(25):
            tw.step(None)
        direct = tw.render_camera()
        cam = tw.async_camera()
        try:
            assert cam.capture(tw.data, tw.time_s)
            t_s, img = cam.collect(wait=True)
        finally:
            cam.close()
    return t_s, img, direct


def test_the_lens_blur_renders_the_sharp_image_blurred_on_both_camera_paths():
    """camera.blur_sigma_px: the rendered image through a Gaussian of that sigma, the
    same from render_camera() and from the real-time twin's render thread."""
    import dataclasses

    import cv2
    import numpy as np

    from twin.config import TwinConfig

    sharp_cfg = TwinConfig()
    sharp_cfg = dataclasses.replace(
        sharp_cfg, camera=dataclasses.replace(sharp_cfg.camera, antialias_samples=0)
    )
    blur_cfg = dataclasses.replace(
        sharp_cfg, camera=dataclasses.replace(sharp_cfg.camera, blur_sigma_px=0.7)
    )
    images = []
    for cfg in (sharp_cfg, blur_cfg):
        _, threaded, direct = _threaded_and_direct(cfg)
        assert np.array_equal(threaded, direct)
        images.append(direct)
    sharp, blurred = images
    assert not np.array_equal(sharp, blurred)
    assert np.array_equal(blurred, cv2.GaussianBlur(sharp, (0, 0), 0.7))
    with pytest.raises(ValueError, match="blur_sigma_px"):
        TwinConfig.from_dict({"camera": {"blur_sigma_px": -1.0}})
