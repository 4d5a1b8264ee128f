"""GAE against a NumPy loop and a hand-worked case, PPO loss known answers, and probe
environments that catch sign and wiring bugs in the update in seconds."""

from __future__ import annotations

import dataclasses

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxcart.core.config import PPOConfig, preset
from jaxcart.core.metrics import EpisodeBuffer, explained_variance, update_episode_buffer
from jaxcart.core.networks import ActorCritic
from jaxcart.core.ppo import (
    Batch,
    compute_gae,
    learning_rate_at,
    make_optimizer,
    ppo_loss,
    scheduled,
    update_epochs,
)
from jaxcart.core.tricks import (
    categorical_entropy,
    categorical_log_prob,
    pack_batch,
    unpack_batch,
)


def gae_numpy(reward, value, next_value, terminated, truncated, gamma, lam, bootstrap_truncation):
    """Plain loops over envs and time, written from the GAE definition."""
    T, E = reward.shape
    adv = np.zeros((T, E))
    for e in range(E):
        running = 0.0
        for t in reversed(range(T)):
            if terminated[t, e]:
                target = reward[t, e]
            elif truncated[t, e] and not bootstrap_truncation:
                target = reward[t, e]
            else:
                target = reward[t, e] + gamma * next_value[t, e]
            delta = target - value[t, e]
            episode_ends = terminated[t, e] or truncated[t, e]
            running = delta + (0.0 if episode_ends else gamma * lam * running)
            adv[t, e] = running
    return adv, adv + value


@pytest.mark.parametrize("bootstrap_truncation", [True, False])
def test_gae_matches_numpy_loop(bootstrap_truncation):
    rng = np.random.default_rng(0)
    T, E = 64, 7
    reward = rng.normal(size=(T, E))
    value = rng.normal(size=(T, E))
    next_value = rng.normal(size=(T, E))
    terminated = rng.random((T, E)) < 0.1
    truncated = rng.random((T, E)) < 0.1  # some steps both: terminated must win
    assert (terminated & truncated).any() and (truncated & ~terminated).any()
    expected_adv, expected_ret = gae_numpy(
        reward, value, next_value, terminated, truncated, 0.97, 0.9, bootstrap_truncation
    )
    adv, ret = jax.jit(compute_gae, static_argnums=7)(
        jnp.asarray(reward, jnp.float32),
        jnp.asarray(value, jnp.float32),
        jnp.asarray(next_value, jnp.float32),
        jnp.asarray(terminated),
        jnp.asarray(truncated),
        0.97,
        0.9,
        bootstrap_truncation,
    )
    chex.assert_shape([adv, ret], (T, E))
    np.testing.assert_allclose(np.asarray(adv), expected_adv, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.asarray(ret), expected_ret, rtol=1e-5, atol=1e-5)


def test_gae_hand_worked_three_steps():
    """gamma = lambda = 0.5, rewards 1, values V(s0..s2) = 1, 2, 3.

    step 2 terminated:                     delta2 = 1 - 3 = -2;            A2 = -2
    step 1 truncated, V(final_obs) = 4:    delta1 = 1 + 0.5*4 - 2 = 1;     A1 = 1 (episode ends)
    step 0 continues into s1, V(s1) = 2:   delta0 = 1 + 0.5*2 - 1 = 1;     A0 = 1 + 0.25*A1 = 1.25
    Without truncation bootstrapping:      delta1 = 1 - 2 = -1 = A1;       A0 = 1 - 0.25 = 0.75
    """
    reward = jnp.ones((3, 1))
    value = jnp.array([[1.0], [2.0], [3.0]])
    next_value = jnp.array(
        [[2.0], [4.0], [10.0]]
    )  # V(s1), V(final_obs of step 1), V(final_obs of step 2)
    terminated = jnp.array([[False], [False], [True]])
    truncated = jnp.array([[False], [True], [False]])
    adv, ret = compute_gae(reward, value, next_value, terminated, truncated, 0.5, 0.5, True)
    np.testing.assert_allclose(np.asarray(adv)[:, 0], [1.25, 1.0, -2.0])
    np.testing.assert_allclose(np.asarray(ret)[:, 0], [2.25, 3.0, 1.0])
    adv, _ = compute_gae(reward, value, next_value, terminated, truncated, 0.5, 0.5, False)
    np.testing.assert_allclose(np.asarray(adv)[:, 0], [0.75, -1.0, -2.0])


def _setup_loss(num=256, seed=0):
    network = ActorCritic()
    params = network.host_init(np.random.default_rng(seed))
    obs = jax.random.normal(jax.random.PRNGKey(seed + 1), (num, 4))
    logits, value = network.apply(params, obs)
    action = jax.random.categorical(jax.random.PRNGKey(seed + 2), logits)
    log_prob = jax.nn.log_softmax(logits)[jnp.arange(num), action]
    advantage = jax.random.normal(jax.random.PRNGKey(seed + 3), (num,))
    returns = value + jax.random.normal(jax.random.PRNGKey(seed + 4), (num,))
    # the values at collection: near the current ones, so that value clipping bites on some
    old_value = value + 0.3 * jax.random.normal(jax.random.PRNGKey(seed + 5), (num,))
    batch = Batch(obs, action, log_prob, advantage, returns, old_value)
    return network, params, batch, value


def _config(**kw):
    return PPOConfig(**kw)


@pytest.mark.slow
def test_loss_at_ratio_one():
    """Fresh data from the same params: ratio 1, KL 0, nothing clipped, pg loss = -mean(A)."""
    network, params, batch, value = _setup_loss()
    loss, aux = ppo_loss(params, network, batch, _config(ent_coef=0.0, norm_adv=False))
    assert float(aux["approx_kl"]) == pytest.approx(0.0, abs=1e-7)
    assert float(aux["clip_fraction"]) == 0.0
    assert float(aux["policy_gradient_loss"]) == pytest.approx(
        -float(batch.advantage.mean()), abs=1e-6
    )
    expected_value_loss = float(jnp.mean((batch.returns - value) ** 2))
    assert float(aux["value_loss"]) == pytest.approx(expected_value_loss, rel=1e-5)
    assert float(loss) == pytest.approx(
        float(aux["policy_gradient_loss"]) + 0.5 * expected_value_loss, rel=1e-5
    )
    # normalised advantages have mean 0, so the surrogate at ratio 1 is 0
    _, aux = ppo_loss(params, network, batch, _config(norm_adv=True))
    assert float(aux["policy_gradient_loss"]) == pytest.approx(0.0, abs=1e-6)


def _actor_grad(params, network, batch, hp):
    def pg_only(p):
        config = dataclasses.replace(hp, norm_adv=False)
        return ppo_loss(p, network, batch, config)[1]["policy_gradient_loss"]

    return jax.grad(pg_only)(params)["params"]["actor"]


@pytest.mark.slow
def test_zero_policy_gradient_where_clipped():
    """ratio = e > 1 + clip with positive advantages: every sample clipped, zero gradient;
    with negative advantages the unclipped branch is the minimum and the gradient is not zero."""
    network, params, batch, _ = _setup_loss()
    pushed = batch._replace(log_prob=batch.log_prob - 1.0, advantage=jnp.abs(batch.advantage) + 0.1)
    _, aux = ppo_loss(params, network, pushed, _config(norm_adv=False))
    assert float(aux["clip_fraction"]) == 1.0
    grads = _actor_grad(params, network, pushed, _config())
    assert all(float(jnp.abs(g).max()) == 0.0 for g in jax.tree.leaves(grads))

    negative = pushed._replace(advantage=-pushed.advantage)
    grads = _actor_grad(params, network, negative, _config())
    assert max(float(jnp.abs(g).max()) for g in jax.tree.leaves(grads)) > 1e-4


@pytest.mark.slow
def test_entropy_loss_is_negative_mean_entropy():
    network, params, batch, _ = _setup_loss()
    logits, _ = network.apply(params, batch.obs)
    p = jax.nn.softmax(logits)
    entropy = -(p * jnp.log(p)).sum(-1).mean()
    _, aux = ppo_loss(params, network, batch, _config(norm_adv=True))
    assert float(aux["entropy_loss"]) == pytest.approx(-float(entropy), rel=1e-5)
    # the 0.01 policy head starts near uniform: entropy close to log 2
    assert float(entropy) == pytest.approx(np.log(2), abs=0.01)


def test_explained_variance():
    y = jnp.array([1.0, 2.0, 3.0, 4.0])
    assert float(explained_variance(y, y)) == 1.0
    assert float(explained_variance(jnp.zeros(4), y)) == pytest.approx(
        1.0 - float(jnp.var(y)) / float(jnp.var(y))
    )
    assert np.isnan(float(explained_variance(y, jnp.ones(4))))


def test_episode_buffer_keeps_last_100_in_order():
    T, E = 60, 3
    done = np.zeros((T, E), bool)
    done[::2, :] = True  # 30 x 3 = 90 episodes per rollout
    returns = np.arange(T * E, dtype=np.float32).reshape(T, E)
    empty = EpisodeBuffer(jnp.zeros(100), jnp.zeros(100), jnp.zeros(100, bool))
    done_j, returns_j = jnp.asarray(done), jnp.asarray(returns)
    buf = update_episode_buffer(empty, done_j, returns_j, returns_j)
    assert int(buf.valid.sum()) == 90
    np.testing.assert_allclose(
        np.sort(np.asarray(buf.returns)[np.asarray(buf.valid)]), np.sort(returns[done])
    )
    buf = update_episode_buffer(buf, done_j, returns_j + 1000, returns_j)
    kept = np.sort(np.asarray(buf.returns)[np.asarray(buf.valid)])
    assert len(kept) == 100
    # the newest 90 plus the 10 most recent of the first rollout
    expected = np.sort(np.concatenate([returns[done][-10:], returns[done] + 1000]))
    np.testing.assert_allclose(kept, expected)


def _scatter_window(buffer, done, episode_return, episode_length):
    """The episode window as it was computed before the top_k version: the reference."""
    valid = jnp.concatenate([buffer.valid, done.reshape(-1)])
    returns = jnp.concatenate([buffer.returns, episode_return.reshape(-1).astype(jnp.float32)])
    lengths = jnp.concatenate([buffer.lengths, episode_length.reshape(-1).astype(jnp.float32)])
    rank = jnp.cumsum(valid[::-1])[::-1]
    slot = jnp.where(valid & (rank <= 100), 100 - rank, 100)
    empty = jnp.zeros((100,), jnp.float32)
    return EpisodeBuffer(
        returns=empty.at[slot].set(returns, mode="drop"),
        lengths=empty.at[slot].set(lengths, mode="drop"),
        valid=jnp.zeros((100,), bool).at[slot].set(True, mode="drop"),
    )


@pytest.mark.parametrize("steps, envs", [(2048, 1), (128, 4), (7, 3), (60, 3)])
def test_episode_window_is_bit_identical_to_the_scatter_version(steps, envs):
    """Random rollouts (from no episode to every step an episode end) and random buffers
    (any valid pattern, not only what the function leaves): the same window, bit for bit."""
    rng = np.random.default_rng(steps * envs)
    new, ref = jax.jit(update_episode_buffer), jax.jit(_scatter_window)
    for p_done in (0.0, 0.003, 0.05, 0.5, 1.0):
        buffer = EpisodeBuffer(
            jnp.asarray(rng.normal(size=100).astype(np.float32)),
            jnp.asarray(rng.integers(1, 500, 100).astype(np.float32)),
            jnp.asarray(rng.random(100) < rng.random()),
        )
        done = jnp.asarray(rng.random((steps, envs)) < p_done)
        returns = jnp.asarray(rng.normal(size=(steps, envs)).astype(np.float32) * 100)
        lengths = jnp.asarray(rng.integers(1, 500, (steps, envs)).astype(np.int32))
        for _ in range(3):  # and the window it leaves, fed back
            a, b = new(buffer, done, returns, lengths), ref(buffer, done, returns, lengths)
            for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
                np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
            buffer, done = a, jnp.roll(done, 1, axis=0)


@pytest.mark.slow
def test_categorical_helpers_match_distrax():
    import distrax

    logits = jax.random.normal(jax.random.PRNGKey(0), (50, 2)) * 3
    action = jax.random.randint(jax.random.PRNGKey(1), (50,), 0, 2)
    dist = distrax.Categorical(logits=logits)
    np.testing.assert_allclose(
        categorical_log_prob(logits, action), dist.log_prob(action), rtol=1e-6, atol=1e-6
    )
    np.testing.assert_allclose(categorical_entropy(logits), dist.entropy(), rtol=1e-6, atol=1e-6)
    # sampling frequencies follow the softmax
    probs = jax.nn.softmax(jnp.array([0.3, -0.4]))
    draws = jax.random.categorical(jax.random.PRNGKey(2), jnp.array([0.3, -0.4]), shape=(100_000,))
    assert abs(float((draws == 0).mean()) - float(probs[0])) < 0.01


# Probe environments: one-step episodes (every step terminates), so the right value is the
# reward itself and the right policy is greedy in it. Driven through the real GAE and update.
PROBE = PPOConfig(
    num_envs=8,
    num_steps=16,
    minibatch_size=32,
    update_epochs=4,
    learning_rate=3e-3,
    hidden_sizes=(16,),
)


def _train_on_probe(reward_fn, iterations: int = 40, seed: int = 0):
    """PPO's own GAE + update on a one-step probe env; returns (params, network)."""
    network = ActorCritic(hidden_sizes=(16,))
    params = jax.tree.map(jnp.asarray, network.host_init(np.random.default_rng(seed)))
    hp = PROBE
    shape = (PROBE.num_steps, PROBE.num_envs)

    def iteration(carry, key):
        params, opt_state = carry
        obs_key, act_key, update_key = jax.random.split(key, 3)
        obs = jax.random.normal(obs_key, (*shape, 4))
        logits, value = network.apply(params, obs)
        action = jax.random.categorical(act_key, logits)
        reward = reward_fn(obs, action)
        terminated, truncated = jnp.ones(shape, bool), jnp.zeros(shape, bool)
        advantage, returns = compute_gae(
            reward, value, jnp.zeros(shape), terminated, truncated, hp.gamma, hp.gae_lambda
        )
        log_prob = categorical_log_prob(logits, action)
        batch = Batch(obs, action, log_prob, advantage, returns, value)
        batch = jax.tree.map(lambda x: x.reshape((PROBE.batch_size, *x.shape[2:])), batch)
        params, opt_state, _ = update_epochs(
            params, opt_state, batch, update_key, hp.learning_rate, PROBE
        )
        return (params, opt_state), None

    opt_state = make_optimizer(hp).init(params)
    keys = jax.random.split(jax.random.PRNGKey(seed), iterations)
    (params, _), _ = jax.jit(lambda c, k: jax.lax.scan(iteration, c, k))((params, opt_state), keys)
    return params, network


@pytest.mark.slow
def test_probe_constant_reward_value_learns_it():
    """Reward 1 on every (terminating) step: V(s) must reach 1 everywhere."""
    params, network = _train_on_probe(lambda obs, action: jnp.ones(action.shape))
    obs = jax.random.normal(jax.random.PRNGKey(99), (256, 4))
    value = np.asarray(network.value(params, obs))
    assert np.abs(value - 1.0).mean() < 0.05, value.mean()


def test_probe_action_dependent_reward_policy_learns_it():
    """Reward 1 for action 1, 0 for action 0: the policy must pick action 1 (a flipped sign in
    the surrogate or the advantages would teach action 0)."""
    params, network = _train_on_probe(lambda obs, action: (action == 1).astype(jnp.float32))
    obs = jax.random.normal(jax.random.PRNGKey(99), (256, 4))
    p_one = np.asarray(jax.nn.softmax(network.logits(params, obs))[:, 1])
    assert p_one.mean() > 0.95, p_one.mean()
    value = np.asarray(network.value(params, obs))
    assert abs(value.mean() - p_one.mean()) < 0.1  # V = expected reward under the policy


@pytest.mark.slow
def test_probe_observation_dependent_reward_policy_reads_the_observation():
    """Reward 1 when the action matches the sign of obs[0]: the policy must use its input."""
    reward = lambda obs, action: (action == (obs[..., 0] > 0)).astype(jnp.float32)
    params, network = _train_on_probe(reward, iterations=80)
    obs = jax.random.normal(jax.random.PRNGKey(99), (512, 4))
    action = np.asarray(network.logits(params, obs).argmax(-1))
    accuracy = (action == (np.asarray(obs[:, 0]) > 0)).mean()
    assert accuracy > 0.9, accuracy


def test_packed_batch_round_trips_exactly():
    """The update shuffles one packed array of rows: unpacking a gathered minibatch gives
    exactly the fields of the same rows, with their dtypes (int actions, float32 fields)."""
    rng = np.random.default_rng(3)
    batch = Batch(
        obs=jnp.asarray(rng.standard_normal((10, 4)), jnp.float32),
        action=jnp.asarray(rng.integers(0, 2, 10), jnp.int32),
        log_prob=jnp.asarray(-rng.random(10), jnp.float32),
        advantage=jnp.asarray(rng.standard_normal(10), jnp.float32),
        returns=jnp.asarray(rng.standard_normal(10) * 100, jnp.float32),
        value=jnp.asarray(rng.standard_normal(10), jnp.float32),
    )
    rows = pack_batch(batch)
    assert rows.shape == (10, 9)
    perm = jnp.asarray(rng.permutation(10))
    out = unpack_batch(rows[perm], batch)
    for name, got, field in zip(Batch._fields, out, batch):
        assert got.dtype == field.dtype, name
        np.testing.assert_array_equal(np.asarray(got), np.asarray(field)[np.asarray(perm)])


# The peers' losses, re-derived plainly from their sources' formulas -----------------------
def _sb3_loss(params, network, batch, clip, vf_coef, ent_coef, clip_range_vf=None):
    """SB3 2.x ``PPO.train``: advantages normalised with torch's unbiased std, the clipped
    surrogate, the value MSE (the prediction clipped around the old value when
    ``clip_range_vf`` is set), ``loss = pg + ent_coef * (-entropy) + vf_coef * value_loss``."""
    logits, values = network.apply(params, batch.obs)
    log_p = jax.nn.log_softmax(logits)
    log_prob = log_p[jnp.arange(len(batch.action)), batch.action]
    adv = batch.advantage
    adv = (adv - adv.mean()) / (jnp.std(adv, ddof=1) + 1e-8)
    ratio = jnp.exp(log_prob - batch.log_prob)
    policy_loss = -jnp.minimum(adv * ratio, adv * jnp.clip(ratio, 1 - clip, 1 + clip)).mean()
    if clip_range_vf is not None:
        values = batch.value + jnp.clip(values - batch.value, -clip_range_vf, clip_range_vf)
    value_loss = jnp.mean((batch.returns - values) ** 2)
    entropy = -(jnp.exp(log_p) * log_p).sum(-1)
    return policy_loss + ent_coef * -entropy.mean() + vf_coef * value_loss


def _purejaxrl_loss(params, network, batch, clip_eps, vf_coef, ent_coef):
    """PureJaxRL's ``_loss_fn`` (ppo.py): the value clipped by ``clip_eps`` around the old value,
    half the mean of the larger squared error, advantages normalised with ``jnp.std``
    (population), ``total = loss_actor + vf_coef * value_loss - ent_coef * entropy``."""
    logits, value = network.apply(params, batch.obs)
    log_p = jax.nn.log_softmax(logits)
    log_prob = log_p[jnp.arange(len(batch.action)), batch.action]
    value_pred_clipped = batch.value + jnp.clip(value - batch.value, -clip_eps, clip_eps)
    value_losses = jnp.square(value - batch.returns)
    value_losses_clipped = jnp.square(value_pred_clipped - batch.returns)
    value_loss = 0.5 * jnp.maximum(value_losses, value_losses_clipped).mean()
    ratio = jnp.exp(log_prob - batch.log_prob)
    gae = (batch.advantage - batch.advantage.mean()) / (batch.advantage.std() + 1e-8)
    loss_actor1 = ratio * gae
    loss_actor2 = jnp.clip(ratio, 1.0 - clip_eps, 1.0 + clip_eps) * gae
    loss_actor = -jnp.minimum(loss_actor1, loss_actor2).mean()
    entropy = -(jnp.exp(log_p) * log_p).sum(-1).mean()
    return loss_actor + vf_coef * value_loss - ent_coef * entropy


def _assert_same_loss_and_gradient(config, reference):
    network, params, batch, _ = _setup_loss(num=128, seed=7)
    # a policy moved off the one that collected the data, so ratios and clipping matter
    params = jax.tree.map(lambda p: p * 1.3, params)
    ours = jax.value_and_grad(lambda p: ppo_loss(p, network, batch, config)[0])(params)
    theirs = jax.value_and_grad(lambda p: reference(p, network, batch))(params)
    np.testing.assert_allclose(float(ours[0]), float(theirs[0]), rtol=1e-5)
    for a, b in zip(jax.tree.leaves(ours[1]), jax.tree.leaves(theirs[1])):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-4, atol=1e-6)


@pytest.mark.slow
def test_the_purejaxrl_preset_loss_is_purejaxrls():
    config = preset("purejaxrl")
    assert (config.value_clip, config.adv_std, config.bootstrap_truncation) == (
        "purejaxrl",
        "population",
        False,
    )
    _assert_same_loss_and_gradient(
        config,
        lambda p, n, b: _purejaxrl_loss(p, n, b, 0.2, config.vf_coef, config.ent_coef),
    )


@pytest.mark.slow
def test_the_sb3_preset_loss_is_sb3s_with_and_without_clip_range_vf():
    config = preset("sb3", ent_coef=0.01)
    _assert_same_loss_and_gradient(config, lambda p, n, b: _sb3_loss(p, n, b, 0.2, 0.5, 0.01))
    clipped = preset("sb3", ent_coef=0.01, value_clip="sb3", clip_range_vf=0.1)
    _assert_same_loss_and_gradient(
        clipped, lambda p, n, b: _sb3_loss(p, n, b, 0.2, 0.5, 0.01, clip_range_vf=0.1)
    )


@pytest.mark.slow
def test_target_kl_stops_before_the_step_that_would_exceed_it():
    """A tiny target_kl: the first minibatch (ratio 1, KL 0) takes its step, the second sees
    KL > 1.5 x target and stops every later step, as SB3 does."""
    network, params, batch, _ = _setup_loss(num=128, seed=2)
    config = PPOConfig(num_steps=128, minibatch_size=32, update_epochs=3, target_kl=1e-9)
    opt_state = make_optimizer(config).init(params)
    key = jax.random.PRNGKey(0)
    new_params, _, aux = update_epochs(params, opt_state, batch, key, 3e-4, config)
    assert np.asarray(aux["computed"]).tolist() == [[True, True, False, False]] + [[False] * 4] * 2
    # exactly one gradient step: the first minibatch of the first epoch's permutation
    from jaxcart.core.ppo import update_minibatch
    from jaxcart.core.tricks import pack_batch, random_permutations

    perm = random_permutations(key, 3, 128)[0]
    rows = pack_batch(batch)[perm][:32]
    (one_step, _), _ = update_minibatch(
        (params, opt_state), rows, batch, network, dataclasses.replace(config, target_kl=None), 3e-4
    )
    moved = 0.0
    for a, b, c in zip(*map(jax.tree.leaves, (new_params, one_step, params))):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-9)
        moved = max(moved, float(np.abs(np.asarray(a) - np.asarray(c)).max()))
    assert moved > 1e-5  # the one step was taken


def sb3_progress_remaining(iteration: np.ndarray, n_steps: int, n_envs: int, total: int):
    """SB3's progress in iteration ``iteration`` (from 0), from ``OnPolicyAlgorithm.learn()``:
    ``collect_rollouts()`` adds ``n_steps * n_envs`` to ``num_timesteps``, then
    ``_update_current_progress_remaining(num_timesteps, total_timesteps)`` sets ``1 -
    num_timesteps / total_timesteps``, then ``train()`` reads the schedules with it."""
    num_timesteps = (iteration + 1) * n_steps * n_envs
    return 1.0 - num_timesteps / total


def test_lin_schedules_follow_sb3s_update_order():
    # rl-zoo3's CartPole-v1: learning_rate lin_0.001, clip_range lin_0.2; linear_schedule(X)
    # is `lambda progress_remaining: progress_remaining * X`
    config = PPOConfig(
        num_envs=8,
        num_steps=32,
        minibatch_size=256,
        total_timesteps=100_000,
        learning_rate=1e-3,
        clip_coef=0.2,
        anneal_lr=True,
        anneal_clip=True,
        anneal_progress="sb3",
    )
    assert config.num_iterations == 391  # SB3 collects while num_timesteps < total_timesteps
    k = np.arange(config.num_iterations)
    lr = jax.jit(jax.vmap(lambda i: learning_rate_at(config, i)))(k)
    clip = jax.jit(jax.vmap(lambda i: scheduled(config, i).clip_coef))(k)
    progress = sb3_progress_remaining(k, 32, 8, 100_000)
    np.testing.assert_allclose(lr / 1e-3, progress, atol=1e-6)  # float32 arithmetic
    np.testing.assert_allclose(clip / 0.2, progress, atol=1e-6)
    assert lr[0] < 1e-3 and lr[-1] < 0  # the first update is already one rollout in
    # PureJaxRL's and CleanRL's order (the default) starts at X: one iteration behind SB3's
    start = dataclasses.replace(config, anneal_progress="start", total_timesteps=391 * 256)
    lr_start = jax.vmap(lambda i: learning_rate_at(start, i))(k)
    whole = sb3_progress_remaining(k, 32, 8, start.total_timesteps)
    np.testing.assert_allclose(lr_start[1:] / 1e-3, whole[:-1], atol=1e-6)
    assert lr_start[0] == 1e-3
    with pytest.raises(ValueError, match="anneal_progress must be 'start' or 'sb3'"):
        dataclasses.replace(config, anneal_progress="end")


@pytest.mark.slow
def test_an_annealed_clip_range_reaches_the_update():
    from helpers import TINY

    from jaxcart.engine.loop import train

    base = dataclasses.replace(TINY, anneal_lr=False, anneal_progress="sb3")
    constant = train(base, 1)
    annealed = train(dataclasses.replace(base, anneal_clip=True), 1)
    fractions = [r.metrics["train/clip_fraction"][:, 0] for r in (constant, annealed)]
    # the last iteration clips at 0.2 x (1 - 32 x 128 / 4096) = 0: every step that moved the
    # policy is clipped
    assert fractions[1][-1] > 0.5 and fractions[0][-1] < 0.1, fractions
