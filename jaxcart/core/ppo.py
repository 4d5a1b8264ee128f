"""PPO for CartPole, one run (one independent agent), in the order an iteration runs it.

1. Set-up: the actor-critic (:func:`make_network`) and the optimizer (:func:`make_optimizer`).
2. Rollout (:func:`collect_rollout`): ``num_steps`` steps of ``num_envs`` envs under the policy.
3. GAE (:func:`compute_gae`, applied by :func:`training_batch`): advantages and returns.
4. The loss (:func:`ppo_loss`) on one minibatch.
5. The update: one gradient step per minibatch (:func:`update_minibatch`), ``update_epochs``
   shuffled epochs of minibatches (:func:`update_epochs`).
6. One training iteration (:func:`train_iteration`): 2 to 5, and the iteration's metrics
   (:func:`prepare_update`, the update, :func:`finish_iteration`).

Arrays inside an iteration are time-major, ``[num_steps, num_envs, ...]``, and the training
batch is flat, ``[batch_size, ...]`` with ``batch_size = num_steps * num_envs``. The engine
(:mod:`jaxcart.engine.chunk`) vmaps the phases of :func:`train_iteration` over runs and scans
them over iterations (with many runs on a CPU device, the update in groups of runs). How some steps
are made fast lives in :mod:`jaxcart.core.tricks`; the logged metrics and their episode
window in :mod:`jaxcart.core.metrics`.

The update follows Stable-Baselines3's PPO so that its default run can be compared curve for
curve: per-minibatch advantage normalisation (unbiased std), clipped surrogate, unclipped
value MSE (no 1/2 factor), ``loss = pg + ent_coef * (-entropy) + vf_coef * value_mse``,
global grad-norm clipping, Adam; its logged metrics keep SB3's names and definitions.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax

from jaxcart.core import envs, networks, pytree
from jaxcart.core.config import (
    TRACED_FIELDS,
    PPOConfig,
    RecordedCode,
    recorded_code,
    untrusted_code,
)
from jaxcart.core.metrics import (
    EpisodeBuffer,
    custom_metrics,
    iteration_metrics,
    update_episode_buffer,
)
from jaxcart.core.networks import ActorCritic
from jaxcart.core.tricks import (
    categorical_entropy,
    categorical_log_prob,
    pack_batch,
    random_permutations,
    unpack_batch,
)

Array = jax.Array


@pytree.dataclass
class RunnerState:
    """Everything one run carries from iteration to iteration (``episodes`` and ``diverged_at``
    are bookkeeping: :mod:`jaxcart.core.metrics` and the engine's divergence guard)."""

    params: dict
    opt_state: optax.OptState
    env_state: Any  # the env's state pytree, fields [num_envs]
    obs: Array  # [num_envs, obs_dim]
    episode_return: Array  # [num_envs] running return of the current episodes
    episode_length: Array  # [num_envs] int32
    episodes: EpisodeBuffer  # the last finished episodes, for the logged means
    key: Array
    diverged_at: Array  # int32: -1 while healthy, else the (1-based) iteration that went non-finite
    best: Any = None  # with keep_best: the best policy so far (core.evaluation.BestPolicy)


class Transition(NamedTuple):
    """One rollout step of every env: fields ``[num_envs, ...]``, ``[T, num_envs, ...]`` stacked."""

    obs: Array
    action: Array
    log_prob: Array
    value: Array
    reward: Array
    terminated: Array
    truncated: Array
    final_obs: Array  # the true next observation, before any autoreset
    episode_return: Array  # return of the episode that ended here (valid where done)
    episode_length: Array


class Batch(NamedTuple):
    """Flattened training data; fields ``[batch, ...]``."""

    obs: Array
    action: Array
    log_prob: Array
    advantage: Array
    returns: Array
    value: Array | None  # V(obs) at collection, kept only for value-loss clipping


# 1. Set-up -----------------------------------------------------------------------------------
def make_network(config: PPOConfig) -> nn.Module:
    """The actor-critic of ``config``: its ``network``, or the built-in SB3 MLP its
    ``hidden_sizes``, ``activation``, ``linear_actor`` and ``weight_init`` describe. Maps
    observations ``[..., obs_dim]`` to ``(logits [..., num_actions], value [...])``."""
    if config.network is None:
        return ActorCritic.from_config(config)
    if isinstance(config.network, RecordedCode):  # read from a run, not resolved
        raise untrusted_code(recorded_code(config))
    return config.network


def make_optimizer(config: PPOConfig) -> optax.GradientTransformation:
    """Global-norm clipping then Adam's scaling; the learning rate is applied by the caller.

    The config's traced fields may be tracers: the optimizer state's structure does not depend
    on them.
    """
    return optax.chain(
        optax.clip_by_global_norm(config.max_grad_norm), optax.scale_by_adam(eps=config.adam_eps)
    )


# 2. Rollout ----------------------------------------------------------------------------------
def env_step(
    runner: RunnerState, _: None, network: nn.Module, env: envs.Env, env_params: Any
) -> tuple[RunnerState, Transition]:
    """One step of every env: sample actions ``[num_envs]`` from the policy, step (finished
    episodes reset on the same step) and record a :class:`Transition` (fields ``[num_envs,
    ...]``)."""
    key, act_key, env_key = jax.random.split(runner.key, 3)
    logits, value = networks.apply(network, runner.params, runner.obs)
    action = jax.random.categorical(act_key, logits)
    log_prob = categorical_log_prob(logits, action)
    obs, env_state, reward, terminated, truncated, info = env.step_batch(
        env_key, runner.env_state, action, env_params
    )
    done = terminated | truncated
    episode_return = runner.episode_return + reward
    episode_length = runner.episode_length + 1
    transition = Transition(
        obs=runner.obs,
        action=action,
        log_prob=log_prob,
        value=value,
        reward=reward,
        terminated=terminated,
        truncated=truncated,
        final_obs=info["final_obs"],
        episode_return=episode_return,
        episode_length=episode_length,
    )
    runner = runner.replace(
        obs=obs,
        env_state=env_state,
        episode_return=jnp.where(done, 0.0, episode_return),
        episode_length=jnp.where(done, 0, episode_length),
        key=key,
    )
    return runner, transition


def collect_rollout(
    runner: RunnerState, config: PPOConfig, env_params: Any
) -> tuple[RunnerState, Transition]:
    """Steps ``num_envs`` envs for ``num_steps`` steps, sampling actions from the policy.

    Returns:
        The advanced runner and a :class:`Transition` with fields ``[num_steps, num_envs, ...]``.
    """
    network, env = make_network(config), envs.make(config.env)
    step = functools.partial(env_step, network=network, env=env, env_params=env_params)
    return jax.lax.scan(step, runner, None, length=config.num_steps)


# 3. GAE --------------------------------------------------------------------------------------
def gae_step(gae_next: Array, xs: tuple[Array, Array]) -> tuple[Array, Array]:
    """``A_t = delta_t + gamma * lambda * (1 - done_t) * A_{t+1}`` for one step, ``[E]``."""
    delta_t, carry_t = xs
    gae = delta_t + carry_t * gae_next
    return gae, gae


def compute_gae(
    reward: Array,
    value: Array,
    next_value: Array,
    terminated: Array,
    truncated: Array,
    gamma: Array | float,
    gae_lambda: Array | float,
    bootstrap_truncation: bool = True,
) -> tuple[Array, Array]:
    """Generalised advantage estimation by a reverse ``lax.scan`` over time.

    Args:
        reward, value: ``[T, E]``; ``value[t] = V(obs_t)``.
        next_value: ``[T, E]``; V of the true next observation of step t (``V(final_obs)``
            where the episode ended, ``V(obs_{t+1})`` otherwise).
        terminated, truncated: ``[T, E]`` bool.
        bootstrap_truncation: when True a truncated (not terminated) step bootstraps from
            ``next_value``; when False truncation is treated as termination.

    Returns:
        ``(advantages, returns)``, both ``[T, E]``, with ``returns = advantages + value``.
    """
    done = terminated | truncated
    # A terminated step bootstraps nothing; a truncated one bootstraps from V(final_obs).
    stops_bootstrap = terminated if bootstrap_truncation else done
    delta = reward + gamma * next_value * (1.0 - stops_bootstrap) - value
    # Any episode end cuts the recursion: the next step belongs to a new episode.
    carry_on = gamma * gae_lambda * (1.0 - done)
    _, advantages = jax.lax.scan(
        gae_step, jnp.zeros_like(delta[0]), (delta, carry_on), reverse=True
    )
    return advantages, advantages + value


def training_batch(params: dict, rollout: Transition, config: PPOConfig) -> Batch:
    """GAE over ``rollout`` (fields ``[num_steps, num_envs, ...]``), bootstrapping from the
    values of its true next observations under ``params``, and the transitions flattened into
    one training batch, fields ``[batch_size, ...]``."""
    next_value = networks.apply(make_network(config), params, rollout.final_obs)[1]
    advantages, returns = compute_gae(
        rollout.reward,
        rollout.value,
        next_value,
        rollout.terminated,
        rollout.truncated,
        config.gamma,
        config.gae_lambda,
        config.bootstrap_truncation,
    )
    # the values at collection travel only when the loss clips around them: an unused column
    # made every epoch's gather of rows slower
    value = rollout.value if config.value_clip != "off" else None
    batch = Batch(rollout.obs, rollout.action, rollout.log_prob, advantages, returns, value)
    return jax.tree.map(lambda x: x.reshape((config.batch_size,) + x.shape[2:]), batch)


# 4. The loss ---------------------------------------------------------------------------------
def value_loss_of(value: Array, batch: Batch, config: PPOConfig) -> Array:
    """The value loss of predictions ``value [M]`` against ``batch.returns``, by
    ``config.value_clip``:

    - ``off`` (SB3's default): ``mean((R - V)^2)``;
    - ``sb3`` (SB3's ``clip_range_vf``): the prediction clipped to within ``clip_range_vf`` of
      the value at collection, ``V' = V_old + clip(V - V_old, -c, c)``, then ``mean((R - V')^2)``;
    - ``purejaxrl`` (PureJaxRL's ``_loss_fn``): ``0.5 * mean(max((V - R)^2, (V' - R)^2))``.
    """
    if config.value_clip == "off":
        return jnp.square(batch.returns - value).mean()
    c = config.clip_range_vf
    clipped = batch.value + jnp.clip(value - batch.value, -c, c)
    if config.value_clip == "sb3":
        return jnp.square(batch.returns - clipped).mean()
    unclipped_loss = jnp.square(value - batch.returns)
    return 0.5 * jnp.maximum(unclipped_loss, jnp.square(clipped - batch.returns)).mean()


def ppo_loss(
    params: dict,
    network: nn.Module,
    batch: Batch,
    config: PPOConfig,
) -> tuple[Array, dict[str, Array]]:
    """SB3's PPO loss on one minibatch (fields ``[M, ...]``), with ``config``'s coefficients.

    Returns:
        ``(loss, aux)``: the scalar loss and the scalars ``policy_gradient_loss, value_loss,
        entropy_loss, approx_kl, clip_fraction, loss``.
    """
    logits, value = networks.apply(network, params, batch.obs)
    log_prob = categorical_log_prob(logits, batch.action)
    advantage = batch.advantage
    if config.norm_adv and advantage.shape[0] > 1:
        ddof = 1 if config.adv_std == "sample" else 0  # torch's unbiased std, or jnp.std's
        advantage = (advantage - advantage.mean()) / (advantage.std(ddof=ddof) + 1e-8)
    log_ratio = log_prob - batch.log_prob
    ratio = jnp.exp(log_ratio)
    clipped = jnp.clip(ratio, 1.0 - config.clip_coef, 1.0 + config.clip_coef)
    pg_loss = -jnp.minimum(advantage * ratio, advantage * clipped).mean()
    value_loss = value_loss_of(value, batch, config)
    entropy_loss = -categorical_entropy(logits).mean()
    loss = pg_loss + config.ent_coef * entropy_loss + config.vf_coef * value_loss
    aux = {
        "policy_gradient_loss": pg_loss,
        "value_loss": value_loss,
        "entropy_loss": entropy_loss,
        "approx_kl": jax.lax.stop_gradient(((ratio - 1.0) - log_ratio).mean()),
        "clip_fraction": jax.lax.stop_gradient(
            (jnp.abs(ratio - 1.0) > config.clip_coef).astype(jnp.float32).mean()
        ),
        "loss": loss,
    }
    return loss, aux


# 5. The update -------------------------------------------------------------------------------

Carry = tuple[dict, optax.OptState]
"""``(params, opt_state)``, what the gradient steps carry."""


def update_minibatch(
    carry: Carry,
    rows: Array,
    like: Batch,
    network: nn.Module,
    config: PPOConfig,
    learning_rate: Array,
) -> tuple[Carry, dict[str, Array]]:
    """One gradient step on a minibatch of packed rows ``[M, obs_dim + 4]`` (+1 with value clipping) (fields and dtypes
    as ``like``'s); returns the new carry and the loss terms (scalars).

    With ``config.target_kl`` the carry also holds whether the epochs have stopped (SB3's
    rule): a minibatch whose approx KL exceeds ``1.5 * target_kl`` takes no step, nor does any
    after it; its loss terms still count (SB3 records them before the check), later ones are
    marked ``computed = False``.
    """
    if config.target_kl is None:
        params, opt_state = carry
    else:
        params, opt_state, stopped = carry
    minibatch = unpack_batch(rows, like)
    grad_fn = jax.value_and_grad(ppo_loss, has_aux=True)
    (_, aux), grads = grad_fn(params, network, minibatch, config)
    updates, new_opt_state = make_optimizer(config).update(grads, opt_state, params)
    new_params = jax.tree.map(lambda p, u: p - learning_rate * u, params, updates)
    if config.target_kl is None:
        return (new_params, new_opt_state), aux
    stop = stopped | (aux["approx_kl"] > 1.5 * config.target_kl)
    keep = functools.partial(jax.tree.map, lambda old, new: jnp.where(stop, old, new))
    aux = {**aux, "computed": ~stopped}
    return (keep(params, new_params), keep(opt_state, new_opt_state), stop), aux


def update_epochs(
    params: dict,
    opt_state: optax.OptState,
    batch: Batch,
    key: Array,
    learning_rate: Array,
    config: PPOConfig,
) -> tuple[dict, optax.OptState, dict[str, Array]]:
    """``update_epochs`` passes over ``batch`` (fields ``[B, ...]``) in shuffled minibatches.

    Returns:
        New params and optimizer state, and the loss terms per gradient step
        (``[update_epochs, num_minibatches]`` each).
    """
    minibatch_step = functools.partial(
        update_minibatch,
        like=batch,
        network=make_network(config),
        config=config,
        learning_rate=learning_rate,
    )
    rows = pack_batch(batch)  # [B, obs_dim + 4]
    shape = (config.num_minibatches, config.minibatch_size, rows.shape[-1])

    def epoch(carry: Carry, perm: Array) -> tuple[Carry, dict[str, Array]]:
        """One pass over ``rows`` in the order ``perm [B]``, as ``num_minibatches`` gradient
        steps; loss terms ``[num_minibatches]``."""
        return jax.lax.scan(minibatch_step, carry, rows[perm].reshape(shape))

    perms = random_permutations(key, config.update_epochs, config.batch_size)
    if config.target_kl is None:
        (params, opt_state), aux = jax.lax.scan(epoch, (params, opt_state), perms)
    else:
        start = (params, opt_state, jnp.zeros((), bool))
        (params, opt_state, _), aux = jax.lax.scan(epoch, start, perms)
    return params, opt_state, aux


def progress_remaining(config: PPOConfig, iteration: Array) -> Array:
    """The fraction of an annealed schedule left in iteration ``iteration`` (0-based), by
    ``config.anneal_progress``: ``start``, ``1 - i / num_iterations`` (PureJaxRL, CleanRL);
    ``sb3``, SB3's ``_current_progress_remaining``, which ``learn()`` updates after the rollout
    and before ``train()``, from the env steps collected so far: ``1 - (i + 1) x batch_size /
    total_timesteps`` (slightly negative in a last iteration that overshoots the total, as
    in SB3)."""
    if config.anneal_progress == "sb3":
        return 1.0 - (iteration + 1) * (config.batch_size / config.total_timesteps)
    return 1.0 - iteration / config.num_iterations


def learning_rate_at(config: PPOConfig, iteration: Array) -> Array:
    """Constant, or linearly annealed from ``learning_rate`` towards 0
    (:func:`progress_remaining`; rl-zoo3's ``lin_X``: ``progress_remaining * X``)."""
    if not config.anneal_lr:
        return config.learning_rate
    return config.learning_rate * progress_remaining(config, iteration)


def scheduled(config: PPOConfig, iteration: Array) -> PPOConfig:
    """``config`` with ``clip_coef`` annealed like the learning rate when ``anneal_clip``
    (SB3's ``clip_range`` schedule, read once per iteration before the update)."""
    if not config.anneal_clip:
        return config
    leaves, tree = jax.tree.flatten(config)  # the traced fields, unvalidated (may be tracers)
    leaves[TRACED_FIELDS.index("clip_coef")] = config.clip_coef * progress_remaining(
        config, iteration
    )
    return jax.tree.unflatten(tree, leaves)


# 6. One training iteration -------------------------------------------------------------------
def prepare_update(
    runner: RunnerState,
    config: PPOConfig,
    iteration: Array,
    env_params: Any,
) -> tuple[RunnerState, Transition, Batch, Array, Array]:
    """The iteration up to the update: rollout (2) and GAE (3) for one run.

    Returns:
        The runner after the rollout (its key advanced past the update's), the rollout
        (fields ``[num_steps, num_envs, ...]``), the training batch (fields ``[batch_size,
        ...]``), the update's PRNG key and the learning rate (scalar).
    """
    runner, rollout = collect_rollout(runner, config, env_params)
    batch = training_batch(runner.params, rollout, config)
    key, update_key = jax.random.split(runner.key)
    learning_rate = learning_rate_at(config, iteration)
    return runner.replace(key=key), rollout, batch, update_key, learning_rate


def finish_iteration(
    runner: RunnerState,
    rollout: Transition,
    batch: Batch,
    learning_rate: Array,
    params: dict,
    opt_state: optax.OptState,
    losses: dict[str, Array],
    config: PPOConfig,
) -> tuple[RunnerState, dict[str, Array]]:
    """The iteration after the update: the runner with the updated ``params`` and
    ``opt_state`` and its episode window, and the iteration's metrics (``losses``: the
    update's loss terms, ``[update_epochs, num_minibatches]`` each), the config's own
    ``metrics`` among them."""
    done = rollout.terminated | rollout.truncated
    episodes = update_episode_buffer(
        runner.episodes, done, rollout.episode_return, rollout.episode_length
    )
    metrics = iteration_metrics(
        episodes,
        done,
        rollout.episode_return,
        losses,
        batch.returns - batch.advantage,
        batch.returns,
        learning_rate,
    )
    if config.metrics:  # nothing is added to the program without them
        metrics |= custom_metrics(config.metrics, rollout, batch, losses)
    runner = runner.replace(params=params, opt_state=opt_state, episodes=episodes)
    return runner, metrics


def train_iteration(
    runner: RunnerState,
    config: PPOConfig,
    iteration: Array,
    env_params: Any,
) -> tuple[RunnerState, dict[str, Array]]:
    """One PPO iteration for one run: rollout, GAE, all epochs and minibatches, metrics.

    Three phases (:func:`prepare_update`, :func:`update_epochs`, :func:`finish_iteration`)
    so that the engine can vmap the update over runs differently from the rest.

    Args:
        runner: the run's state (no run axis).
        config: the run's config (its traced fields scalars: one run's values).
        iteration: int32 scalar, the 0-based index of this iteration (for the learning rate).

    Returns:
        The next runner state and scalar metrics named as in
        :data:`~jaxcart.core.metrics.METRIC_NAMES`, then ``config.metric_names``.
    """
    config = scheduled(config, iteration)
    runner, rollout, batch, update_key, learning_rate = prepare_update(
        runner, config, iteration, env_params
    )
    params, opt_state, losses = update_epochs(
        runner.params, runner.opt_state, batch, update_key, learning_rate, config
    )
    return finish_iteration(
        runner, rollout, batch, learning_rate, params, opt_state, losses, config
    )
