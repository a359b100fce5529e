"""Domain randomisation: every draw inside its declared range, reproducible under a seed, undone on reset."""

from __future__ import annotations

import numpy as np
import pytest

from hil_sim.world import CAMERA_POS, HOME_Q, Randomisation, World


def _model_params(world: World) -> dict[str, np.ndarray]:
    m = world.model
    return {n: getattr(m, n).copy() for n in ("body_mass", "dof_damping", "dof_frictionloss", "jnt_stiffness",
                                             "cam_pos", "cam_quat")}


@pytest.mark.parametrize("seed", range(8))
def test_draws_stay_inside_their_ranges(world: World, seed: int) -> None:
    r, spec = Randomisation(), world.spec
    ep = world.reset("apple", seed=seed)
    for name in ("link_mass_scale", "joint_friction", "joint_damping_scale", "joint_stiffness"):
        lo, hi = getattr(r, name)
        values = np.asarray(getattr(ep, name))
        assert len(values) == 7 and np.all((lo <= values) & (values <= hi)), name
    assert np.all(np.abs(np.asarray(ep.q0) - HOME_Q) <= r.init_joint_noise + 1e-6)
    assert np.all(np.abs(np.asarray(ep.camera_pos) - CAMERA_POS) <= r.camera_pos_noise + 1e-6)
    top, left = ep.crop_window
    ctop, cleft = spec.centred_window()
    assert abs(top - ctop) <= r.crop_shift[0] and abs(left - cleft) <= r.crop_shift[1]
    assert 0 <= top <= spec.stream_height - spec.crop_height
    assert 0 <= left <= spec.stream_width - spec.crop_width
    np.testing.assert_allclose(world.q, ep.q0, atol=0.01)  # the arm starts (and holds) at the drawn pose
    np.testing.assert_allclose(world.model.cam_pos[world.model.camera("d455").id], ep.camera_pos)


def test_same_seed_same_episode_and_frame(world: World) -> None:
    ep1 = world.reset("banana", seed=42)
    frame1, q1 = world.render_depth(), world.q
    world.reset("cube", seed=7)
    ep2 = world.reset("banana", seed=42)
    assert ep1 == ep2
    np.testing.assert_array_equal(world.render_depth(), frame1)
    np.testing.assert_array_equal(world.q, q1)


def test_different_seeds_differ(world: World) -> None:
    eps = [world.reset("banana", seed=s) for s in range(5)]
    assert len({e.object_xy for e in eps}) == 5
    assert len({e.crop_window for e in eps}) > 1
    assert len({e.camera_pos for e in eps}) == 5


def test_randomisation_is_undone_by_a_nominal_reset(world: World) -> None:
    world.reset("cube", seed=0, randomise=False)
    nominal = _model_params(world)
    world.reset("cube", seed=1, randomise=True)
    changed = _model_params(world)
    assert any(not np.array_equal(nominal[k], changed[k]) for k in nominal)
    ep = world.reset("cube", seed=2, randomise=False)
    for name, value in _model_params(world).items():
        np.testing.assert_array_equal(value, nominal[name], err_msg=name)
    assert ep.crop_window == world.spec.centred_window() and not ep.randomised


def test_wrist_noise_widens_the_wrist_start_alone(world: World) -> None:
    """A wider ``wrist_noise`` (collect --wrist-noise) rescales the wrist's share of the same draw: every
    other draw of the episode is unchanged, and the default leaves episodes as they were."""
    wide = World(("banana",), randomisation=Randomisation(wrist_noise=1.5))
    try:
        wrists = []
        for seed in range(6):
            narrow, widened = world.reset("banana", seed=seed), wide.reset("banana", seed=seed)
            assert widened.q0[:6] == narrow.q0[:6] and widened.object_xy == narrow.object_xy
            assert widened.camera_pos == narrow.camera_pos and widened.joint_friction == narrow.joint_friction
            assert widened.q0[6] - HOME_Q[6] == pytest.approx(30 * (narrow.q0[6] - HOME_Q[6]), abs=1e-4)
            np.testing.assert_allclose(wide.q, widened.q0, atol=0.03)  # its spring pulls the wrist a little
            wrists.append(widened.q0[6] - HOME_Q[6])
        assert max(np.abs(wrists)) <= 1.5 and np.ptp(wrists) > 0.5
    finally:
        wide.close()


def test_wrist_noise_alone_when_the_other_joints_start_exactly_home() -> None:
    """``init_joint_noise=0`` keeps joints 1-6 at home and still draws the wrist (it once divided by zero)."""
    world = World(("banana",), randomisation=Randomisation(init_joint_noise=0.0, wrist_noise=1.0))
    try:
        wrists = [world.reset("banana", seed=s).q0 for s in range(4)]
        assert all(q[:6] == HOME_Q[:6] for q in wrists)
        assert all(abs(q[6] - HOME_Q[6]) <= 1.0 for q in wrists) and np.ptp([q[6] for q in wrists]) > 0.2
    finally:
        world.close()
