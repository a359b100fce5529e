"""The control loop against fakes on a virtual clock: exact timing, chunks, skips, stalls, NaN, stop."""

import dataclasses
import io
import json
import threading

import numpy as np
import pytest

from runtime.loop import EXIT_ACTION, EXIT_CAMERA, EXIT_OK, EXIT_POLICY, EXIT_ROBOT, ControlLoop, LoopConfig
from tests.runtime.fakes import DELTA, READY_Q, FakeCamera, FakePolicy, FakeRobot, VirtualClock

P = 0.1  # 10 Hz, as deployed; the clock is virtual, so long runs cost nothing
EPS = 1e-6


def _run(*, camera_period=P, camera=None, policy=None, robot=None, stop_at=None, **config):
    clock = VirtualClock()
    camera = camera(clock) if camera else FakeCamera(clock, camera_period)
    policy = policy(clock) if policy else FakePolicy(clock)
    robot = robot(clock) if robot else FakeRobot(clock)
    stop = threading.Event()
    clock.stop, clock.stop_at = stop, None if stop_at is None else clock() + stop_at
    metrics = io.StringIO()
    loop = ControlLoop(policy, camera, robot, LoopConfig(rate_hz=1 / P, **config), metrics=metrics, stop=stop,
                       clock=clock)
    code = loop.run()
    ticks = [json.loads(line) for line in metrics.getvalue().splitlines()]
    return code, ticks, robot.commands, loop, camera, policy


def _sent(ticks):
    return [t for t in ticks if t["t_send"] is not None]


@pytest.mark.parametrize("camera_period", [P, P / 3, 1 / 15])  # 10, 30 and 15 fps (hil_sim's camera)
def test_absolute_deadlines_no_drift_no_late_ticks_and_young_frames(camera_period):
    code, ticks, _, loop, camera, _ = _run(camera_period=camera_period, seconds=60.0)
    assert code == EXIT_OK and len(ticks) == 601
    deadlines = np.array([t["deadline"] for t in ticks])
    np.testing.assert_allclose(deadlines - deadlines[0], np.arange(601) * P, atol=EPS)  # t0 + k * period
    assert loop.counts["late"] == loop.counts["skipped"] == 0 and all(not t["hold"] for t in ticks)
    offsets = np.array([t["t_send"] - t["deadline"] for t in ticks])
    assert (offsets < 0).all()
    np.testing.assert_allclose(offsets[480:580], offsets[:100], atol=EPS)  # same phase 48 s later
    # every tick works on a frame the moment it arrives: age = the camera's own delay, whatever its rate
    ages = np.array([t["t_preprocess"] - t["t_capture"] for t in ticks])
    np.testing.assert_allclose(ages, camera.delay, atol=EPS)
    assert len({t["frame"] for t in ticks}) == len(ticks)  # and never the same frame twice


def test_action_chunks_execute_one_action_per_tick():
    code, ticks, commands, _, _, policy = _run(policy=lambda c: FakePolicy(c, exec_horizon=4), seconds=2.0)
    assert code == EXIT_OK and len(ticks) == 21 and policy.calls == 6
    assert [t["tick"] for t in ticks if t["t_inference"] is not None] == [0, 4, 8, 12, 16, 20]
    for tick, cmd in zip(ticks, commands, strict=False):
        index = tick["tick"] % 4
        np.testing.assert_allclose(cmd["q_target"][0] - READY_Q[0], DELTA * (index + 1), atol=1e-6)
        np.testing.assert_allclose(cmd["q_target"][1:] - READY_Q[1:], DELTA, atol=1e-6)
        assert cmd["gripper"] == 1.0 and cmd["deadline"] == pytest.approx(cmd["t_send"] + 1.5 * P)
        assert cmd["t_capture"] == tick["t_capture"]


def test_policy_sees_the_angles_it_was_trained_on_and_commands_stay_the_robots():
    """The robot reports libfranka's angles; the policy gets them plus its metadata's joint offset (hil_sim's
    joint 6 reads pi/2 less); the deltas it returns are added to the robot's own angles."""
    code, _, commands, _, _, policy = _run(seconds=0.5)
    offset = np.asarray(policy.metadata.joint_offset_rad)
    assert code == EXIT_OK and offset[5] == pytest.approx(-np.pi / 2) and not offset[[0, 1, 2, 3, 4, 6]].any()
    np.testing.assert_allclose(policy.states[0][:7], READY_Q + offset, atol=1e-6)
    np.testing.assert_allclose(commands[0]["q_target"][1:] - READY_Q[1:], DELTA, atol=1e-6)


def test_slow_inference_makes_late_ticks_skips_and_never_bursts():
    slow = lambda c: FakePolicy(c, delay=1.6 * P, exec_horizon=6)  # noqa: E731
    code, ticks, commands, loop, _, policy = _run(policy=slow, seconds=6.0)
    assert code == EXIT_OK
    late, skipped = [t for t in ticks if t["late"]], [t for t in ticks if t["skipped"]]
    assert late and skipped and loop.counts["skipped"] == len(skipped) and loop.counts["late"] == len(late)
    assert all(t["t_send"] is None and t["cmd_seq"] is None for t in skipped)
    for tick in _sent(ticks):  # never queued: no command ahead of its own frame window, none late by more
        assert tick["t_send"] >= tick["deadline"] - 0.8 * P - P  # than its own inference overran
        assert tick["t_send"] - tick["deadline"] <= policy.delay
    chunk_tick = None
    for tick in _sent(ticks):  # an action whose tick was skipped is dropped: the index follows the clock
        chunk_tick = tick["tick"] if tick["t_inference"] is not None else chunk_tick
        np.testing.assert_allclose(commands[tick["cmd_seq"]]["q_target"][0] - READY_Q[0],
                                   DELTA * (tick["tick"] - chunk_tick + 1), atol=1e-6)


def test_camera_stall_is_detected_within_one_period_then_holds_and_exits():
    code, ticks, commands, _, camera, _ = _run(camera=lambda c: FakeCamera(c, P, stop_after=30),
                                               camera_give_up_s=1.0)
    assert code == EXIT_CAMERA
    holds = [t for t in ticks if t["hold"]]
    assert holds and holds[0]["status"] == "camera_stalled"
    assert 0 < holds[0]["t_send"] - camera.arrival(30) <= P + 1e-3  # 1 period after the frame never came
    for cmd in commands[holds[0]["cmd_seq"]:]:  # every later command, the final one too, holds still
        np.testing.assert_allclose(cmd["q_target"], READY_Q)
        assert cmd["gripper"] == 1.0
    hold_sends = np.array([t["t_send"] for t in holds])
    assert np.diff(hold_sends).min() > 0.5 * P  # holding keeps the tick pace, no flood
    assert 10 <= len(holds) <= 12 and len(commands) == len(_sent(ticks)) + 1  # 1 s of holds + the final one


def test_camera_that_comes_back_resumes():
    class Gap(FakeCamera):  # frames 20..24 are lost
        def poll(self, timeout_s):
            frame = super().poll(timeout_s)
            return None if frame is not None and 20 <= frame.number < 25 else frame

    code, ticks, _, _, _, _ = _run(camera=lambda c: Gap(c, P), seconds=5.0)
    assert code == EXIT_OK
    statuses = [t["status"] for t in ticks]
    first, last = statuses.index("camera_stalled"), len(statuses) - statuses[::-1].index("camera_stalled")
    assert all(t["hold"] for t in ticks[first:last]) and 3 <= last - first <= 4
    assert not any(t["hold"] for t in ticks[last:]) and ticks[last]["t_inference"] is not None


def test_a_hold_forgets_the_frame_history_the_gap_made_stale():
    """After a camera gap the stacks start again from the first new frame, as at an episode's start."""
    class Numbered(FakeCamera):  # each frame's depth says its number; frames 20..24 are lost
        def poll(self, timeout_s):
            frame = super().poll(timeout_s)
            if frame is None or 20 <= frame.number < 25:
                return None
            return dataclasses.replace(frame, depth=np.full_like(frame.depth, 500 + 10 * frame.number))

    code, ticks, _, _, _, policy = _run(camera=lambda c: Numbered(c, P), seconds=5.0,
                                        policy=lambda c: FakePolicy(c, exec_horizon=1))
    assert code == EXIT_OK and any(t["hold"] for t in ticks)
    depths = np.array([d[:, 0, 0] for d in policy.depths])  # [call, 3 frames]
    restarts = [i for i, d in enumerate(depths) if i and (d == d[-1]).all()]  # a history of one frame
    assert len(restarts) == 1 and depths[restarts[0], -1] > depths[restarts[0] - 1, -1]  # after the gap


def test_frames_that_arrive_stale_are_not_used():
    code, ticks, _, loop, _, _ = _run(camera=lambda c: FakeCamera(c, P, age=2 * P), startup_timeout_s=1.0)
    assert code == EXIT_CAMERA and ticks == [] and loop.counts["stale_frames"] >= 9


def test_frame_age_limit_is_its_own_setting_not_the_control_period():
    # 70 ms old frames: younger than the 100 ms period, older than the 50 ms limit asked for
    code, ticks, _, loop, _, _ = _run(camera=lambda c: FakeCamera(c, P, age=0.07), startup_timeout_s=1.0,
                                      max_frame_age_s=0.05)
    assert code == EXIT_CAMERA and ticks == [] and loop.counts["stale_frames"] >= 9


def test_nan_action_holds_and_recovers():
    code, ticks, commands, _, _, _ = _run(policy=lambda c: FakePolicy(c, nan_calls={2}, exec_horizon=3),
                                          seconds=1.0)
    assert code == EXIT_OK
    nan_tick = next(t for t in ticks if t["status"] == "nan_action")
    assert nan_tick["hold"] and nan_tick["tick"] == 3
    np.testing.assert_allclose(commands[nan_tick["cmd_seq"]]["q_target"], READY_Q)
    after = ticks[4]
    assert not after["hold"] and after["t_inference"] is not None and after["status"] is None


def test_persistent_nan_gives_up():
    code, ticks, commands, _, _, _ = _run(policy=lambda c: FakePolicy(c, nan_calls=set(range(1, 100))),
                                          policy_give_up_s=0.5)
    assert code == EXIT_POLICY and all(t["hold"] for t in ticks) and 5 <= len(ticks) <= 7
    np.testing.assert_allclose(commands[-1]["q_target"], READY_Q)


def test_stale_robot_state_holds_then_exits():
    code, ticks, commands, _, _, _ = _run(robot=lambda c: FakeRobot(c, stale_after=c() + 2.0),
                                          robot_give_up_s=0.5)
    assert code == EXIT_ROBOT
    holds = [t for t in ticks if t["hold"]]
    assert holds and holds[0]["status"] == "robot_stalled" and 5 <= len(holds) <= 7
    np.testing.assert_allclose(commands[-1]["q_target"], READY_Q)


def test_stop_ends_with_a_hold_command():
    code, ticks, commands, _, _, _ = _run(stop_at=2.0)
    assert code == EXIT_OK and len(ticks) >= 10
    moving = READY_Q + DELTA * np.array([ticks[-1]["tick"] % 8 + 1, 1, 1, 1, 1, 1, 1])
    np.testing.assert_allclose(commands[-2]["q_target"], moving, atol=1e-6)  # it was moving ...
    np.testing.assert_allclose(commands[-1]["q_target"], READY_Q)  # ... and ends holding
    assert commands[-1]["gripper"] == commands[-2]["gripper"] == 1.0


@pytest.mark.parametrize("field, value", [("rate_hz", 0), ("seconds", -1.0), ("camera_give_up_s", 0),
                                          ("work_budget", 1.0)])
def test_bad_loop_config_is_named(field, value):
    with pytest.raises(ValueError, match=field):
        LoopConfig(**{field: value})


class _RecordingPolicy(FakePolicy):
    def __call__(self, depth, state):
        self.seen = depth
        return super().__call__(depth, state)


def _holey_camera(clock):
    camera = FakeCamera(clock, P)
    camera.depth[200:280, 380:470] = 0  # a hole in the middle of the deploy crop
    return camera


@pytest.mark.parametrize("restore,holes_reach_policy", [("none", True), ("inpaint", False)])
def test_restore_option_decides_whether_holes_reach_the_policy(restore, holes_reach_policy):
    code, *_, policy = _run(camera=_holey_camera, policy=_RecordingPolicy, seconds=0.5, restore=restore)
    assert code == EXIT_OK
    invalid = policy.seen == policy.metadata.preprocess.invalid_value
    assert invalid.any() == holes_reach_policy
    assert np.allclose(policy.seen[~invalid], policy.seen[~invalid].flat[0])  # filled with the 900 mm around


def test_unknown_restore_is_a_config_error():
    with pytest.raises(ValueError, match="restore must be one of"):
        LoopConfig(restore="median")


class _TurnsBad(FakeCamera):
    """A camera whose frames from ``after`` on are spoilt by ``spoil(frame)``."""

    def __init__(self, clock, period_s, *, after: int = 20, spoil=None, **kw) -> None:
        super().__init__(clock, period_s, **kw)
        self.after, self.spoil = after, spoil

    def poll(self, timeout_s):
        frame = super().poll(timeout_s)
        return self.spoil(frame) if frame is not None and frame.number >= self.after else frame


def _spoilt(spoil):
    return lambda c: _TurnsBad(c, P, spoil=spoil)


@pytest.mark.parametrize("name, spoil, code, counter", [
    ("blind", lambda f: dataclasses.replace(f, depth=np.zeros_like(f.depth)), "camera_blind", "blind_frames"),
    ("saturated", lambda f: dataclasses.replace(f, depth=np.full_like(f.depth, 65535)), "camera_blind",
     "blind_frames"),
    ("frozen counter", lambda f: dataclasses.replace(f, number=19), "camera_frozen", "frozen_frames"),
    ("capture in the future", lambda f: dataclasses.replace(f, t_capture=f.t_receive + 10.0),
     "frame_from_future", "future_frames"),
])
def test_unusable_frames_never_reach_the_policy_the_arm_holds_with_a_named_status(name, spoil, code, counter):
    """Blind or saturated depth went to the policy; a frozen counter was reused for 5 s; a capture time 10 s
    in the future was accepted (frame age -9998 ms)."""
    code_, ticks, commands, loop, _, policy = _run(camera=_spoilt(spoil), camera_give_up_s=1.0)
    assert code_ == EXIT_CAMERA and loop.counts[counter] >= 10
    holds = [t for t in ticks if t["hold"]]
    assert holds and {t["status"] for t in holds} == {code}
    assert all(t["frame"] is None or t["frame"] < 20 for t in ticks)  # no spoilt frame was used
    assert all(d[:, 0, 0].max() <= d[0, 0, 0] for d in policy.depths)  # the policy saw only good depth
    for cmd in commands[holds[0]["cmd_seq"]:]:
        np.testing.assert_allclose(cmd["q_target"], READY_Q)
    assert 10 <= len(holds) <= 13


def test_a_camera_that_turns_good_again_resumes():
    class Covered(FakeCamera):  # frames 20..24 blind: a hand over the lens for half a second
        def poll(self, timeout_s):
            frame = super().poll(timeout_s)
            if frame is not None and 20 <= frame.number < 25:
                return dataclasses.replace(frame, depth=np.zeros_like(frame.depth))
            return frame

    code, ticks, _, _, _, _ = _run(camera=lambda c: Covered(c, P), seconds=5.0)
    statuses = [t["status"] for t in ticks]
    assert code == EXIT_OK and "camera_blind" in statuses and statuses[-1] is None


def test_an_oversized_action_is_never_sent_the_arm_holds_and_the_runtime_exits_6():
    """A policy that output 1e6 rad deltas drove the arm to its limits at full speed and exited 0."""
    class Huge(FakePolicy):
        def __call__(self, depth, state):
            actions = super().__call__(depth, state)
            if self.calls >= 3:
                actions[:, 2] = 1e6
            return actions

    code, ticks, commands, _, _, _ = _run(policy=lambda c: Huge(c, exec_horizon=2), seconds=5.0)
    assert code == EXIT_ACTION and len(ticks) == 4
    assert max(np.abs(c["q_target"] - READY_Q).max() for c in commands) <= 16 * DELTA
    np.testing.assert_allclose(commands[-1]["q_target"], READY_Q)  # the final command holds


def test_a_tolerable_action_at_the_bound_is_executed():
    class AtBound(FakePolicy):
        def __call__(self, depth, state):
            actions = super().__call__(depth, state)
            actions[:, 1] = 2.0 * self.metadata.action_scale
            return actions

    code, ticks, _, _, _, _ = _run(policy=AtBound, seconds=1.0)
    assert code == EXIT_OK and not any(t["hold"] for t in ticks)


def test_another_session_holding_the_arm_holds_and_exits_4():
    """A second process moved the arm and the runtime noticed nothing and exited 0."""
    def taken(clock):
        robot = FakeRobot(clock)
        robot.controller = "0123456789abcdef"
        return robot

    code, ticks, _, _, _, _ = _run(robot=taken, controller_give_up_s=1.0)
    assert code == EXIT_ROBOT and ticks and all(t["hold"] and t["status"] == "not_controller" for t in ticks)
    assert 10 <= len(ticks) <= 12


def test_its_own_session_in_the_state_is_no_fault():
    def ours(clock):
        robot = FakeRobot(clock)
        robot.controller = robot.tag
        return robot

    code, ticks, _, _, _, _ = _run(robot=ours, seconds=1.0)
    assert code == EXIT_OK and not any(t["hold"] for t in ticks)
