"""The Gymnasium adapters against Gymnasium's own CartPole-v1 and its checkers.

``gymnasium.make("CartPole-v1")`` is the reference: the same start state (from the seed or
injected), the same actions, then observations within 1e-5 and rewards and flags identical on
every step. The vector env is checked step by step, in each autoreset mode, against
Gymnasium's ``CartPoleVectorEnv`` (next-step) and ``SyncVectorEnv`` of ``CartPole-v1`` with the
same mode: the same injected start states and actions, then observations, rewards, flags and
info dicts compared, with jaxcart's fresh start states injected into Gymnasium's envs after
each reset (their random draws differ).
"""

from __future__ import annotations

import os
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.envs.classic_control.cartpole import CartPoleVectorEnv
from gymnasium.utils.env_checker import check_env
from gymnasium.utils.env_match import check_environments_match
from gymnasium.vector import AutoresetMode, SyncVectorEnv
from gymnasium.vector.utils import batch_space
from helpers import fresh_python

from jaxcart.gym.adapter import ENV_ID, JaxCartPoleEnv, JaxCartPoleVectorEnv

try:
    import pygame  # noqa: F401  (rendering draws with Gymnasium's pygame renderer)

    HAVE_PYGAME = True
except ImportError:
    HAVE_PYGAME = False

OBS_TOL = 1e-5


def balancing_action(obs: np.ndarray) -> int:
    """A controller that keeps the pole up for all 500 steps."""
    return int(obs[2] + 0.5 * obs[3] > 0)


def gym_messages(caught: list[warnings.WarningMessage]) -> list[str]:
    """The messages of warnings raised through Gymnasium's logger (its checkers' findings)."""
    return [str(w.message) for w in caught if "WARN" in str(w.message)]


def check_env_warnings(env: gym.Env) -> list[str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        # The render check builds the env with each declared render mode and draws a frame.
        check_env(env, skip_render_check=not HAVE_PYGAME)
    return gym_messages(caught)


def test_passes_gymnasium_check_env_with_no_more_warnings_than_gymnasiums_cartpole():
    env = gym.make(ENV_ID).unwrapped
    assert isinstance(env, JaxCartPoleEnv)
    found = check_env_warnings(env)
    # The unbounded velocities of CartPole's observation Box draw the same two warnings for
    # Gymnasium's own CartPole; nothing else may appear.
    assert found == check_env_warnings(gym.make("CartPole-v1").unwrapped)
    assert len(found) == 2 and all("infinity" in m for m in found)


def test_make_and_make_vec():
    env = gym.make(ENV_ID)
    reference = gym.make("CartPole-v1")
    assert isinstance(env, gym.wrappers.TimeLimit)
    assert env.spec.max_episode_steps == 500
    assert env.spec.reward_threshold == reference.spec.reward_threshold
    assert env.observation_space == reference.observation_space
    assert env.action_space == reference.action_space

    envs = gym.make_vec(ENV_ID, num_envs=8, vectorization_mode="vector_entry_point")
    assert isinstance(envs, JaxCartPoleVectorEnv)
    assert envs.num_envs == 8
    # The default autoreset mode is that of Gymnasium's own vector CartPole.
    gymnasium_vector = gym.make_vec(
        "CartPole-v1", num_envs=8, vectorization_mode="vector_entry_point"
    )
    assert envs.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
    assert envs.metadata["autoreset_mode"] is gymnasium_vector.metadata["autoreset_mode"]
    assert envs.params.max_episode_steps == 500
    assert envs.single_observation_space == reference.observation_space
    assert envs.observation_space == batch_space(reference.observation_space, 8)
    assert envs.action_space == batch_space(reference.action_space, 8)
    obs, info = envs.reset(seed=0)
    assert obs.shape == (8, 4) and obs.dtype == np.float32 and info == {}
    assert obs in envs.observation_space

    # The default vectorisation of an env with a vector entry point is that entry point, and
    # Gymnasium's own SyncVectorEnv over the single env works too.
    assert isinstance(gym.make_vec(ENV_ID, num_envs=2), JaxCartPoleVectorEnv)
    sync = gym.make_vec(ENV_ID, num_envs=2, vectorization_mode="sync")
    sync.reset(seed=0)
    assert sync.step(np.array([0, 1]))[0].shape == (2, 4)


def test_make_by_module_id_in_a_fresh_interpreter():
    """``gym.make("jaxcart.gym.adapter:jaxcart/CartPole-v1")`` imports and registers the env
    itself; importing the adapter does not import JAX (it loads when an env is built)."""
    code = (
        "import sys, gymnasium as gym\n"
        "import jaxcart.gym.adapter\n"
        "assert 'jax' not in sys.modules, 'the adapter imported JAX'\n"
        "env = gym.make('jaxcart.gym.adapter:jaxcart/CartPole-v1')\n"
        "obs, _ = env.reset(seed=0)\n"
        "assert obs.tolist() == gym.make('CartPole-v1').reset(seed=0)[0].tolist()\n"
        "print(type(env.unwrapped).__name__)\n"
    )
    assert run_fresh(code) == "JaxCartPoleEnv"


def run_fresh(code: str) -> str:
    """Runs ``code`` in a fresh interpreter (CPU JAX) and returns its stdout."""
    return fresh_python(code, {**os.environ, "JAX_PLATFORMS": "cpu"})


@pytest.mark.parametrize("first", ["jaxcart", "gymnasium"])
def test_import_jaxcart_registers_the_env_in_a_fresh_interpreter(first):
    """``import jaxcart``, before or after ``import gymnasium``, is all ``gym.make`` and
    ``gym.make_vec`` need: it calls ``gymnasium.register`` with string entry points, so
    registering loads neither JAX nor the adapter, and adds no import hook."""
    imports = ["import jaxcart", "import gymnasium as gym"]
    code = "\n".join(
        [
            "import sys",
            "hooks = list(sys.meta_path)",
            *(imports if first == "jaxcart" else imports[::-1]),
            "assert 'jax' not in sys.modules and 'jaxcart.gym.adapter' not in sys.modules",
            "assert sys.meta_path == hooks",
            "spec = gym.spec('jaxcart/CartPole-v1')",
            "assert spec.entry_point == 'jaxcart.gym.adapter:JaxCartPoleEnv', spec.entry_point",
            "assert (spec.max_episode_steps, spec.reward_threshold) == (500, 475.0)",
            "env = gym.make('jaxcart/CartPole-v1')",
            "obs, _ = env.reset(seed=0)",
            "assert obs.tolist() == gym.make('CartPole-v1').reset(seed=0)[0].tolist()",
            "envs = gym.make_vec('jaxcart/CartPole-v1', num_envs=3)",
            "print(type(env.unwrapped).__name__, type(envs).__name__, envs.reset(seed=0)[0].shape)",
        ]
    )
    assert run_fresh(code) == "JaxCartPoleEnv JaxCartPoleVectorEnv (3, 4)"


def test_make_with_the_package_before_the_colon_in_a_fresh_interpreter():
    """``gym.make("jaxcart:jaxcart/CartPole-v1")``: Gymnasium imports ``jaxcart``, whose import
    registers the env; a second registration (the package reloaded) is silent."""
    code = (
        "import importlib, sys, warnings\n"
        "import gymnasium as gym\n"
        "env = gym.make('jaxcart:jaxcart/CartPole-v1')\n"
        "envs = gym.make_vec('jaxcart:jaxcart/CartPole-v1', num_envs=2)\n"
        "with warnings.catch_warnings():\n"
        "    warnings.simplefilter('error')\n"
        "    importlib.reload(sys.modules['jaxcart'])\n"
        "print(type(env.unwrapped).__name__, type(envs).__name__, env.spec.max_episode_steps)\n"
    )
    assert run_fresh(code) == "JaxCartPoleEnv JaxCartPoleVectorEnv 500"


def test_import_jaxcart_imports_neither_jax_nor_the_front_ends():
    code = (
        "import sys, jaxcart\n"
        "print([m for m in ('jax', 'jaxcart.gym.adapter') if m in sys.modules])"
    )
    assert run_fresh(code) == "[]"


@pytest.mark.parametrize("options", [None, {"low": -0.2, "high": 0.3}])
def test_seeded_resets_equal_gymnasiums(options):
    env, reference = gym.make(ENV_ID), gym.make("CartPole-v1")
    for seed in (0, 1, 12345):
        obs, info = env.reset(seed=seed, options=options)
        ref_obs, ref_info = reference.reset(seed=seed, options=options)
        np.testing.assert_array_equal(obs, ref_obs)
        assert obs.dtype == np.float32 and info == ref_info == {}
        np.testing.assert_array_equal(env.unwrapped.state, reference.unwrapped.state)
        # Unseeded resets continue the seeded generator, as in Gymnasium.
        np.testing.assert_array_equal(env.reset()[0], reference.reset()[0])


@pytest.mark.parametrize("float64", [True, False])
@pytest.mark.parametrize("sutton_barto", [False, True])
def test_episodes_from_injected_states_match_gymnasium(float64, sutton_barto):
    rng = np.random.default_rng(0)
    env = gym.make(ENV_ID, float64=float64, sutton_barto_reward=sutton_barto)
    reference = gym.make("CartPole-v1", sutton_barto_reward=sutton_barto)
    env.reset(seed=0)
    reference.reset(seed=0)
    lengths = []
    for _ in range(12):
        start = rng.uniform(-1, 1, 4) * [1.0, 0.5, 0.1, 0.5]
        env.unwrapped.state = start.copy()
        reference.unwrapped.state = start.copy()
        for t in range(1, 501):
            action = int(rng.integers(0, 2))
            obs, reward, terminated, truncated, info = env.step(action)
            ref_obs, ref_reward, ref_terminated, ref_truncated, ref_info = reference.step(action)
            np.testing.assert_allclose(obs, ref_obs, rtol=0, atol=OBS_TOL)
            assert obs.dtype == ref_obs.dtype == np.float32
            assert (reward, terminated, truncated, info) == (
                ref_reward,
                ref_terminated,
                ref_truncated,
                ref_info,
            )
            assert type(reward) is type(ref_reward) and type(terminated) is type(ref_terminated)
            if terminated or truncated:
                break
        assert terminated
        lengths.append(t)
        env.reset()
        reference.reset()
    assert min(lengths) < max(lengths)  # a mix of episodes, not one repeated


def test_balanced_episode_is_truncated_at_500_like_gymnasium():
    """Float64 physics tracks Gymnasium for hundreds of steps of a balanced episode (the
    unstable pendulum amplifies ~1e-16 differences from fused multiply-adds after that), and
    ``TimeLimit`` truncates both on step 500."""
    env, reference = gym.make(ENV_ID), gym.make("CartPole-v1")
    obs, _ = env.reset(seed=3)
    ref_obs, _ = reference.reset(seed=3)
    for t in range(1, 501):
        obs, reward, terminated, truncated, _ = env.step(balancing_action(obs))
        ref_obs, ref_reward, ref_terminated, ref_truncated, _ = reference.step(
            balancing_action(ref_obs)
        )
        if t <= 300:
            np.testing.assert_allclose(obs, ref_obs, rtol=0, atol=OBS_TOL)
        assert (reward, terminated, truncated) == (ref_reward, ref_terminated, ref_truncated)
        assert truncated == (t == 500) and not terminated


def test_gymnasium_check_environments_match():
    """Gymnasium's own env-matching check: seeded resets, 150 sampled actions over several
    episodes, observations, rewards, flags, infos and rendered frames compared."""
    render_mode = "rgb_array" if HAVE_PYGAME else None
    env = gym.make(ENV_ID, render_mode=render_mode)
    reference = gym.make("CartPole-v1", render_mode=render_mode)
    check_environments_match(env, reference, num_steps=150, seed=7)


@pytest.mark.parametrize("sutton_barto", [False, True])
def test_steps_past_termination_pay_and_warn_as_in_gymnasium(sutton_barto):
    envs = [
        gym.make(ENV_ID, sutton_barto_reward=sutton_barto).unwrapped,
        gym.make("CartPole-v1", sutton_barto_reward=sutton_barto).unwrapped,
    ]
    rewards, warned = [], []
    for env in envs:
        env.reset(seed=0)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            results = [env.step(1)[1:3] for _ in range(40)]
        rewards.append(results)
        warned.append([m for m in gym_messages(caught) if "already returned terminated" in m])
    assert rewards[0] == rewards[1]
    assert sum(terminated for _, terminated in rewards[0]) > 2  # stepped on past the end
    assert len(warned[0]) == len(warned[1]) == 1


INVALID_ACTIONS = [2, -1, 0.5, "a", None, 1.0, np.float32(0.0), np.array([1]), [0], (1,)]


@pytest.mark.parametrize("action", INVALID_ACTIONS, ids=repr)
def test_invalid_actions_raise_as_in_gymnasium(action):
    for wrapped in (False, True):
        envs = [gym.make(ENV_ID), gym.make("CartPole-v1")]
        if not wrapped:
            envs = [e.unwrapped for e in envs]
        messages = []
        for env in envs:
            env.reset(seed=0)
            with pytest.raises(AssertionError, match="invalid") as raised:
                env.step(action)
            messages.append(str(raised.value))
        assert messages[0] == messages[1]


def test_valid_action_types_are_accepted_as_in_gymnasium():
    env, reference = gym.make(ENV_ID), gym.make("CartPole-v1")
    env.reset(seed=0)
    reference.reset(seed=0)
    for action in (1, 0, np.int64(1), np.int32(0), np.array(1), True, False):
        obs, *_ = env.step(action)
        ref_obs, *_ = reference.step(action)
        np.testing.assert_allclose(obs, ref_obs, rtol=0, atol=OBS_TOL)


def test_step_before_reset_raises():
    with pytest.raises(AssertionError, match="Call reset before using step method"):
        JaxCartPoleEnv().step(0)


def test_vector_env_matches_gymnasium_with_same_step_autoreset():
    num_envs = 8
    envs = gym.make_vec(
        ENV_ID,
        num_envs=num_envs,
        vectorization_mode="vector_entry_point",
        autoreset_mode="SameStep",
    )
    assert envs.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP
    envs = gym.wrappers.vector.RecordEpisodeStatistics(envs)
    obs, _ = envs.reset(seed=42)
    np.testing.assert_array_equal(obs, envs.reset(seed=42)[0])  # seeded resets repeat
    assert not np.array_equal(obs, envs.reset(seed=43)[0])
    obs, _ = envs.reset(seed=42)

    # One Gymnasium CartPole per sub-environment, started from the same state.
    references = [gym.make("CartPole-v1").unwrapped for _ in range(num_envs)]
    for ref, o in zip(references, obs):
        ref.reset(seed=0)
        ref.state = o.astype(np.float64)
    lengths = np.zeros(num_envs, dtype=int)
    rng = np.random.default_rng(1)
    episodes = 0
    for _ in range(120):
        actions = rng.integers(0, 2, num_envs)
        obs, rewards, terminated, truncated, info = envs.step(actions)
        assert obs.dtype == np.float32 and rewards.dtype == np.float32
        lengths += 1
        done = terminated | truncated
        assert not truncated.any()  # random actions drop the pole long before 500 steps
        if done.any():
            np.testing.assert_array_equal(info["_final_obs"], done)
            np.testing.assert_array_equal(info["_final_info"], done)
            np.testing.assert_array_equal(info["_episode"], done)
            np.testing.assert_array_equal(info["episode"]["l"][done], lengths[done])
            np.testing.assert_array_equal(info["episode"]["r"][done], lengths[done])
        else:
            assert "final_obs" not in info
        for i, ref in enumerate(references):
            ref_obs, ref_reward, ref_terminated, _, _ = ref.step(int(actions[i]))
            assert (rewards[i], terminated[i]) == (ref_reward, ref_terminated)
            if done[i]:
                episodes += 1
                np.testing.assert_allclose(info["final_obs"][i], ref_obs, rtol=0, atol=OBS_TOL)
                # Same-step autoreset: obs already starts the next episode.
                assert np.all(np.abs(obs[i]) <= 0.05)
                ref.reset()
                ref.state = obs[i].astype(np.float64)
                lengths[i] = 0
            else:
                if done.any():
                    assert info["final_obs"][i] is None
                np.testing.assert_allclose(obs[i], ref_obs, rtol=0, atol=OBS_TOL)
    assert episodes >= num_envs


def test_vector_env_same_step_truncates_and_reports_final_obs():
    envs = gym.make_vec(
        ENV_ID,
        num_envs=4,
        vectorization_mode="vector_entry_point",
        max_episode_steps=5,
        autoreset_mode=AutoresetMode.SAME_STEP,
    )
    first, _ = envs.reset(seed=0)
    actions = np.array([0, 1, 0, 1])
    for t in range(1, 6):
        obs, rewards, terminated, truncated, info = envs.step(actions)
        actions = 1 - actions  # alternate pushes: the pole stays up
        assert not terminated.any()
        np.testing.assert_array_equal(rewards, np.ones(4, np.float32))
        assert truncated.all() == (t == 5)
    final = np.stack(info["final_obs"])
    assert final.shape == (4, 4) and not np.allclose(final, first)
    assert not np.allclose(obs, final) and np.all(np.abs(obs) <= 0.05)  # already reset
    # The step after a truncation counts from one again.
    assert not envs.step(actions)[3].any()


def random_states(rng: np.random.Generator, num_envs: int) -> np.ndarray:
    """Start states ``[4, num_envs]`` (Gymnasium's vector layout) away from the reset box."""
    return (rng.uniform(-1, 1, (num_envs, 4)) * [1.0, 0.5, 0.1, 0.5]).T.copy()


def sync_cartpoles(num_envs: int, mode: AutoresetMode, **make_kwargs) -> SyncVectorEnv:
    """Gymnasium's ``SyncVectorEnv`` of ``gym.make("CartPole-v1")`` with ``mode``."""
    return SyncVectorEnv(
        [lambda: gym.make("CartPole-v1", **make_kwargs)] * num_envs, autoreset_mode=mode
    )


def inject(reference: SyncVectorEnv, states: np.ndarray, which: np.ndarray) -> None:
    """Sets the state of ``reference``'s sub-envs ``which`` from ``states`` ``[4, num_envs]``."""
    for i in np.flatnonzero(which):
        reference.envs[i].unwrapped.state = states[:, i].copy()


def assert_step_matches(step: tuple, ref_step: tuple, compare_obs: np.ndarray) -> None:
    """Rewards, flags and info equal; observations within OBS_TOL where ``compare_obs``."""
    obs, reward, terminated, truncated, info = step
    ref_obs, ref_reward, ref_terminated, ref_truncated, ref_info = ref_step
    assert obs.dtype == np.float32 and obs.shape == ref_obs.shape
    assert reward.dtype == np.float32 and terminated.dtype == truncated.dtype == np.bool_
    np.testing.assert_allclose(obs[compare_obs], ref_obs[compare_obs], rtol=0, atol=OBS_TOL)
    np.testing.assert_array_equal(reward, ref_reward)
    np.testing.assert_array_equal(terminated, ref_terminated)
    np.testing.assert_array_equal(truncated, ref_truncated)
    assert info.keys() == ref_info.keys()


def test_vector_env_next_step_matches_gymnasiums_vector_cartpole_step_by_step():
    """Default (next-step) autoreset against Gymnasium's ``CartPoleVectorEnv``: the step that
    ends an episode reports it with the last observation; the next step is a reset step."""
    num_envs = 8
    envs = gym.make_vec(ENV_ID, num_envs=num_envs, vectorization_mode="vector_entry_point")
    reference = CartPoleVectorEnv(num_envs)
    envs.reset(seed=0)
    reference.reset(seed=0)
    rng = np.random.default_rng(2)
    start = random_states(rng, num_envs)
    envs.state = start
    reference.state = start.copy()
    np.testing.assert_array_equal(envs.state, start)
    reset_steps = episodes = 0
    for _ in range(200):
        actions = rng.integers(0, 2, num_envs)
        resetting = reference.prev_done.copy()  # its episode ended on the previous step
        step = envs.step(actions)
        ref_step = reference.step(actions)
        assert_step_matches(step, ref_step, compare_obs=~resetting)
        obs, reward, terminated, truncated, info = step
        assert info == ref_step[4] == {}
        # A reset step: the first observation of a new episode, reward 0, no flag.
        assert np.all(np.abs(obs[resetting]) <= 0.05)
        assert not (reward[resetting].any() or terminated[resetting].any())
        assert not truncated[resetting].any()
        reset_steps += resetting.sum()
        episodes += (terminated | truncated).sum()
        # Gymnasium drew its own fresh states: continue both from jaxcart's.
        ref_state = reference.state.copy()
        ref_state[:, resetting] = envs.state[:, resetting]
        reference.state = ref_state
    assert reset_steps >= num_envs and episodes - reset_steps <= num_envs


@pytest.mark.parametrize("mode", ["NextStep", "SameStep"])
def test_vector_env_truncation_matches_sync_vector_env(mode):
    """Truncation, the reset that follows it (on the next step or the same one) and the step
    counting after it, against ``SyncVectorEnv`` of ``CartPole-v1`` with a 5-step limit."""
    mode = AutoresetMode(mode)
    envs = JaxCartPoleVectorEnv(num_envs=4, max_episode_steps=5, autoreset_mode=mode)
    reference = sync_cartpoles(4, mode, max_episode_steps=5)
    envs.reset(seed=0)
    reference.reset(seed=0)
    inject(reference, envs.state, np.ones(4, bool))
    actions = np.array([0, 1, 0, 1])
    truncations, truncated = [], np.zeros(4, bool)
    for t in range(1, 14):
        ended_before = truncated
        step, ref_step = envs.step(actions), reference.step(actions)
        actions = 1 - actions  # alternate pushes: the pole stays up
        obs, reward, terminated, truncated, info = step
        # The envs that start a new episode on this step, each with its own random draw.
        reset = truncated if mode is AutoresetMode.SAME_STEP else ended_before
        assert_step_matches(step, ref_step, compare_obs=~reset)
        assert not terminated.any()
        assert truncated.all() or not truncated.any()  # the four envs run in step
        if truncated.any():
            truncations.append(t)
        if mode is AutoresetMode.SAME_STEP and truncated.any():
            for i in range(4):
                np.testing.assert_allclose(
                    info["final_obs"][i], ref_step[4]["final_obs"][i], rtol=0, atol=OBS_TOL
                )
        else:
            assert info == ref_step[4] == {}
        inject(reference, envs.state, reset)
    # NEXT_STEP spends a step on the reset: 5 steps, a reset step, 5 steps, ...
    assert truncations == ([5, 10] if mode is AutoresetMode.SAME_STEP else [5, 11])


def test_vector_env_same_step_info_matches_sync_vector_env():
    """Same-step autoreset against ``SyncVectorEnv(autoreset_mode=SAME_STEP)``: the info dict
    has the same keys, masks, ``final_obs`` (object array, None where no episode ended) and
    ``final_info``."""
    num_envs = 6
    envs = JaxCartPoleVectorEnv(num_envs, autoreset_mode=AutoresetMode.SAME_STEP)
    reference = sync_cartpoles(num_envs, AutoresetMode.SAME_STEP)
    envs.reset(seed=1)
    reference.reset(seed=1)
    rng = np.random.default_rng(3)
    envs.state = random_states(rng, num_envs)
    inject(reference, envs.state, np.ones(num_envs, bool))
    ended = 0
    for _ in range(150):
        actions = rng.integers(0, 2, num_envs)
        step, ref_step = envs.step(actions), reference.step(actions)
        done = step[2] | step[3]
        assert_step_matches(step, ref_step, compare_obs=~done)
        info, ref_info = step[4], ref_step[4]
        if done.any():
            assert list(info) == ["final_obs", "_final_obs", "final_info", "_final_info"]
            assert set(ref_info) == set(info)
            for key in ("_final_obs", "_final_info"):
                assert info[key].dtype == np.bool_
                np.testing.assert_array_equal(info[key], ref_info[key])
            assert info["final_info"] == ref_info["final_info"] == {}
            assert info["final_obs"].dtype == ref_info["final_obs"].dtype == object
            for i in range(num_envs):
                final, ref_final = info["final_obs"][i], ref_info["final_obs"][i]
                if done[i]:
                    assert final.dtype == ref_final.dtype == np.float32
                    np.testing.assert_allclose(final, ref_final, rtol=0, atol=OBS_TOL)
                else:
                    assert final is None and ref_final is None
            ended += done.sum()
        else:
            assert info == ref_info == {}
        inject(reference, envs.state, done)
    assert ended >= num_envs


def test_vector_env_disabled_autoreset_matches_sync_vector_env():
    """No autoreset: stepping an ended env raises as in ``SyncVectorEnv``, and
    ``reset(options={"reset_mask": mask})`` restarts only the masked envs."""
    num_envs = 4
    envs = JaxCartPoleVectorEnv(num_envs, autoreset_mode="Disabled")
    reference = sync_cartpoles(num_envs, AutoresetMode.DISABLED)
    assert envs.metadata["autoreset_mode"] is AutoresetMode.DISABLED
    envs.reset(seed=0)
    reference.reset(seed=0)
    inject(reference, envs.state, np.ones(num_envs, bool))
    rng = np.random.default_rng(4)
    restarts = 0
    for _ in range(60):
        actions = rng.integers(0, 2, num_envs)
        step, ref_step = envs.step(actions), reference.step(actions)
        assert_step_matches(step, ref_step, compare_obs=np.ones(num_envs, bool))
        assert step[4] == ref_step[4] == {}
        done = step[2] | step[3]
        if not done.any():
            continue
        with pytest.raises(AssertionError, match="reset them"):
            envs.step(actions)
        obs, info = envs.reset(options={"reset_mask": done.copy()})
        ref_obs, ref_info = reference.reset(options={"reset_mask": done.copy()})
        assert info == ref_info == {}
        np.testing.assert_array_equal(obs[~done], step[0][~done])  # the others carry on
        np.testing.assert_array_equal(ref_obs[~done], ref_step[0][~done])
        assert np.all(np.abs(obs[done]) <= 0.05)
        inject(reference, envs.state, done)
        restarts += done.sum()
    assert restarts >= num_envs
    # Gymnasium raises too (after stepping the envs before the ended one: checked last).
    while not (done := reference.step(np.ones(num_envs, int))[2]).any():
        pass
    with pytest.raises(AssertionError):
        reference.step(np.ones(num_envs, int))


@pytest.mark.parametrize(
    "mask, error",
    [
        ([True, False, False, False], TypeError),
        (np.array([True, False]), ValueError),
        (np.array([1, 0, 0, 0]), TypeError),
        (np.zeros(4, bool), ValueError),
    ],
    ids=["list", "shape", "dtype", "none"],
)
def test_invalid_reset_masks_raise_as_in_sync_vector_env(mask, error):
    envs = JaxCartPoleVectorEnv(num_envs=4, autoreset_mode="Disabled")
    reference = sync_cartpoles(4, AutoresetMode.DISABLED)
    messages = []
    for env in (envs, reference):
        env.reset(seed=0)
        with pytest.raises(error) as raised:
            env.reset(options={"reset_mask": mask})
        messages.append(str(raised.value))
    assert messages[0] == messages[1]


@pytest.mark.parametrize("mode", list(AutoresetMode) + [m.value for m in AutoresetMode])
def test_autoreset_mode_by_enum_or_value(mode):
    envs = gym.make_vec(
        ENV_ID, num_envs=2, vectorization_mode="vector_entry_point", autoreset_mode=mode
    )
    assert envs.metadata["autoreset_mode"] is AutoresetMode(mode)
    assert envs.autoreset_mode is AutoresetMode(mode)
    # The class's metadata keeps the default.
    assert JaxCartPoleVectorEnv.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP


@pytest.mark.parametrize(
    "mode, error",
    [("next_step", ValueError), ("NEXT_STEP", ValueError), ("", ValueError), (1, TypeError)],
)
def test_invalid_autoreset_mode_is_a_clear_error(mode, error):
    with pytest.raises(error, match=r"autoreset_mode must be .*'NextStep', 'SameStep', 'Disabled'"):
        JaxCartPoleVectorEnv(num_envs=2, autoreset_mode=mode)


def test_vector_env_outputs_are_fresh_writable_arrays():
    """Outputs are NumPy arrays of their own, so editing one or stepping again (which reuses the
    device buffer) changes nothing already returned."""
    gymnasium_obs = CartPoleVectorEnv(3).reset(seed=0)[0]
    for mode in AutoresetMode:
        envs = JaxCartPoleVectorEnv(num_envs=3, autoreset_mode=mode)
        obs, _ = envs.reset(seed=0)
        step = envs.step(np.array([1, 1, 1]))
        kept = [a.copy() for a in (obs, *step[:4])]
        for a in (obs, *step[:4]):
            assert isinstance(a, np.ndarray) and a.flags.writeable
        assert step[0].shape == (3, 4)
        # The memory layout of Gymnasium's CartPoleVectorEnv's observations (Fortran order).
        assert step[0].flags.f_contiguous == gymnasium_obs.flags.f_contiguous
        assert obs.flags.f_contiguous == gymnasium_obs.flags.f_contiguous
        envs.step(np.array([0, 0, 0]))
        for a, k in zip((obs, *step[:4]), kept):
            np.testing.assert_array_equal(a, k)


def test_vector_env_float32():
    envs = JaxCartPoleVectorEnv(num_envs=5, float64=False)
    reference = CartPoleVectorEnv(5)
    envs.reset(seed=0)
    reference.reset(seed=0)
    reference.state = envs.state.astype(np.float64)
    for _ in range(5):
        obs, *_ = envs.step(np.array([1, 0, 1, 0, 1]))
        ref_obs, *_ = reference.step(np.array([1, 0, 1, 0, 1]))
        np.testing.assert_allclose(obs, ref_obs, rtol=0, atol=OBS_TOL)


def test_vector_env_rejects_invalid_actions():
    envs = JaxCartPoleVectorEnv(num_envs=4)
    envs.reset(seed=0)
    for actions in ([0, 1, 2, 0], [0, -1, 1, 0], np.array([0, 1]), [0.5, 1, 0, 0], 1):
        with pytest.raises(AssertionError, match="invalid"):
            envs.step(actions)
    assert envs.step([0, 1, 1, 0])[0].shape == (4, 4)


@pytest.mark.skipif(not HAVE_PYGAME, reason="rendering needs pygame")
def test_render_matches_gymnasium_and_vector_render():
    env = gym.make(ENV_ID, render_mode="rgb_array")
    reference = gym.make("CartPole-v1", render_mode="rgb_array")
    env.reset(seed=5)
    reference.reset(seed=5)
    for action in (1, 1, 0):
        env.step(action)
        reference.step(action)
    frame = env.render()
    assert frame.shape == (400, 600, 3) and frame.dtype == np.uint8
    np.testing.assert_array_equal(frame, reference.render())

    envs = JaxCartPoleVectorEnv(num_envs=4, render_mode="rgb_array")
    envs.reset(seed=0)
    frames = envs.render()
    assert len(frames) == 4 and all(f.shape == (400, 600, 3) for f in frames)
    assert not np.array_equal(frames[0], frames[1])
    envs.close()
    env.close()


def test_sb3_check_env_and_short_ppo_run():
    pytest.importorskip("stable_baselines3")
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sb3_check_env(gym.make(ENV_ID).unwrapped)
    assert [str(w.message) for w in caught if "stable_baselines3" in w.filename] == []

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        # One epoch over the 2048-step rollout keeps this quick; the rest is SB3's defaults.
        model = PPO("MlpPolicy", gym.make(ENV_ID), n_epochs=1, seed=0, device="cpu", verbose=0)
        model.learn(2048)
    finally:
        torch.set_num_threads(threads)
    assert model.num_timesteps == 2048
    episodes = list(model.ep_info_buffer)  # SB3's Monitor: return and length per episode
    assert len(episodes) >= 20
    assert all(e["r"] == e["l"] for e in episodes)  # +1 per step, terminating step included
    assert all(8 <= e["l"] <= 500 for e in episodes)


@pytest.mark.parametrize("x64", [True, False], ids=["float64", "float32"])
def test_sin_cos_once_is_jnp_sin_and_cos_bit_for_bit(x64):
    """The vector step's sin and cos (a complex division by 1 + 0i, so that XLA evaluates them
    once) are jnp.sin and jnp.cos exactly, signed zeros and non-finite angles included."""
    import jax
    import jax.numpy as jnp

    from jaxcart.gym import kernels

    dtype = np.float64 if x64 else np.float32
    rng = np.random.default_rng(0)
    special = [0.0, -0.0, np.pi / 2, -np.pi, 1e-30, 1e30, np.inf, -np.inf, np.nan]
    theta = np.concatenate([rng.uniform(-4, 4, 20_000), rng.normal(0, 1e3, 1000), special])
    with kernels.precision(x64):
        theta = jnp.asarray(theta.astype(dtype))
        once = jax.jit(kernels.sin_cos_once)(theta)
        plain = jax.jit(lambda t: (jnp.sin(t), jnp.cos(t)))(theta)
    for a, b in zip(once, plain):
        a, b = np.asarray(a), np.asarray(b)
        assert a.dtype == b.dtype == dtype
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
        finite = ~np.isnan(b)
        np.testing.assert_array_equal(a[finite].view(np.uint8), b[finite].view(np.uint8))


@pytest.mark.parametrize("mode", list(AutoresetMode))
def test_vector_step_evaluates_sin_and_cos_once(mode):
    """XLA:CPU keeps one sin and one cos of the pole angle in the compiled vector step (it would
    recompute them in every fusion that uses them otherwise: benchmarks/RESULTS.md)."""
    from jaxcart.gym import kernels

    params = kernels.make_params(None, None, None)
    hlo = kernels.compiled_vector_step(kernels.compile_key(params), 64, mode, True).as_text()
    assert hlo.count(" sine(") == 1 and hlo.count(" cosine(") == 1


def test_vector_env_action_check_is_action_space_contains():
    """The vector env's fast action check accepts exactly what action_space.contains accepts."""
    from jaxcart.gym.adapter import _valid_actions

    space = JaxCartPoleVectorEnv(num_envs=4).action_space
    candidates = [np.array([0, 1, 1, 0], dtype=t) for t in ("int8", "uint8", "int32", "int64")]
    candidates += [
        np.array([0, 1, 2, 0]),
        np.array([0, -1, 1, 0]),
        np.array([0, 1, 1, 2**32]),
        np.array([0, 1, 1, -(2**62)]),
        np.array([255, 0, 0, 0], dtype=np.uint8),
        np.array([0, 1]),
        np.zeros((4, 1), dtype=np.int64),
        np.array([0.0, 1.0, 1.0, 0.0]),
        np.array([True, False, True, True]),
        [0, 1, 1, 0],
        1,
    ]
    for actions in candidates:
        assert _valid_actions(actions, space) == bool(space.contains(actions)), actions


# Pygame handles, the registry entry (its id differs) and per-step bookkeeping: not
# constants a user reads off the env.
RENDER_INTERNALS = {"clock", "isopen", "screen", "screens", "surf", "spec"}
VECTOR_BOOKKEEPING = {"steps", "prev_done", "steps_beyond_terminated"}


def public_constants(env: object, skip: set[str]) -> list[str]:
    """The public attributes Gymnasium's env sets on itself, less rendering and the state."""
    return sorted(n for n in vars(env) if not n.startswith("_") and n not in skip | {"state"})


def test_cartpole_env_attributes_read_the_same_on_both_envs():
    # The chapter's snippet, run unchanged on both envs.
    def snippet(env_id: str) -> tuple:
        env = gym.make(env_id)
        env.reset(seed=0)
        u = env.unwrapped
        return (
            env.observation_space,
            env.action_space,
            u.x_threshold,
            np.degrees(u.theta_threshold_radians),
            env.spec.max_episode_steps,
        )

    assert snippet(ENV_ID) == snippet("CartPole-v1")
    reference = gym.make("CartPole-v1").unwrapped
    ours = gym.make(ENV_ID).unwrapped
    names = public_constants(reference, RENDER_INTERNALS)
    assert {"x_threshold", "total_mass", "polemass_length", "kinematics_integrator"} <= set(names)
    for name in names:
        assert getattr(ours, name) == getattr(reference, name), name


def test_vector_env_attributes_read_as_gymnasiums_vector_cartpole():
    reference = CartPoleVectorEnv(num_envs=3)
    ours = JaxCartPoleVectorEnv(num_envs=3)
    for name in public_constants(reference, RENDER_INTERNALS | VECTOR_BOOKKEEPING):
        assert getattr(ours, name) == getattr(reference, name), name


def test_attributes_follow_the_params_and_setting_one_names_the_params_route():
    from jaxcart.core.cartpole import EnvParams

    env = gym.make(ENV_ID, params=EnvParams(masspole=0.2, length=1.0)).unwrapped
    assert (env.masspole, env.total_mass, env.polemass_length) == (0.2, 1.2, 0.2)
    with pytest.raises(AttributeError, match=r"params=EnvParams\(x_threshold=\.\.\.\)"):
        env.x_threshold = 3.0
