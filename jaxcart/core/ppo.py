"""PPO for CartPole as one compiled program: rollout, GAE and update fused in one step.

Everything here describes a single seed (one independent agent); :func:`train_chunk` vmaps it
over a leading seed axis and scans it over iterations. Arrays inside an iteration are
time-major: ``[num_steps, num_envs, ...]``.

The update follows Stable-Baselines3's PPO so that its default run can be compared curve for
curve: per-minibatch advantage normalisation (unbiased std), clipped surrogate, unclipped
value MSE (no 1/2 factor), ``loss = pg + ent_coef * (-entropy) + vf_coef * value_mse``,
global grad-norm clipping, Adam; its logged metrics keep SB3's names and definitions.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from jaxcart.core import env as cartpole
from jaxcart.core.config import TRACED_FIELDS, PPOConfig
from jaxcart.core.networks import ActorCritic

Array = jax.Array

EPISODE_WINDOW = 100
"""SB3 reports episode return/length means over the last 100 finished episodes."""

METRIC_NAMES = (
    "rollout/ep_rew_mean",
    "rollout/ep_len_mean",
    "rollout/ep_rew_max",
    "train/approx_kl",
    "train/clip_fraction",
    "train/entropy_loss",
    "train/policy_gradient_loss",
    "train/value_loss",
    "train/loss",
    "train/explained_variance",
    "train/learning_rate",
)
"""Per-iteration metrics computed in the compiled step (``time/fps`` is added by the host)."""


@jax.tree_util.register_pytree_with_keys_class
class Hyperparams:
    """The traced float hyperparameters (:data:`~jaxcart.core.config.TRACED_FIELDS`, declared on
    :class:`PPOConfig`) as arrays: scalars for one run, ``[S]`` for S runs.

    Read them as attributes (``hp.clip_coef``); a pytree whose leaves are named by field.
    """

    __slots__ = ("_values",)

    def __init__(self, **values: Array) -> None:
        missing = set(TRACED_FIELDS) - set(values)
        unknown = set(values) - set(TRACED_FIELDS)
        if missing or unknown:
            raise TypeError(
                f"Hyperparams needs exactly {TRACED_FIELDS}; missing {missing}, unknown {unknown}"
            )
        object.__setattr__(self, "_values", {name: values[name] for name in TRACED_FIELDS})

    def __getattr__(self, name: str) -> Array:
        try:
            return self._values[name]
        except KeyError:
            raise AttributeError(name) from None

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("Hyperparams is immutable; use .replace(name=value)")

    def __repr__(self) -> str:
        return f"Hyperparams({', '.join(f'{k}={v!r}' for k, v in self._values.items())})"

    def replace(self, **changes: Array) -> Hyperparams:
        """A copy with some values replaced."""
        return Hyperparams(**{**self._values, **changes})

    def tree_flatten_with_keys(self):
        return [(jax.tree_util.GetAttrKey(k), v) for k, v in self._values.items()], None

    @classmethod
    def tree_unflatten(cls, aux: None, leaves: list[Array]) -> Hyperparams:
        obj = object.__new__(cls)
        object.__setattr__(obj, "_values", dict(zip(TRACED_FIELDS, leaves)))
        return obj

    @classmethod
    def from_config(cls, config: PPOConfig) -> Hyperparams:
        """Scalar float32 hyperparameters taken from ``config``."""
        return cls(**{name: jnp.float32(getattr(config, name)) for name in TRACED_FIELDS})


@struct.dataclass
class EpisodeBuffer:
    """Returns and lengths of the last ``EPISODE_WINDOW`` finished episodes (``valid`` marks
    filled slots; order inside the window does not matter for the means)."""

    returns: Array  # [EPISODE_WINDOW] float32
    lengths: Array  # [EPISODE_WINDOW] float32
    valid: Array  # [EPISODE_WINDOW] bool


@struct.dataclass
class RunnerState:
    """Everything one seed carries from iteration to iteration."""

    params: dict
    opt_state: optax.OptState
    env_state: cartpole.EnvState  # fields [num_envs]
    obs: Array  # [num_envs, 4]
    episode_return: Array  # [num_envs] running return of the current episodes
    episode_length: Array  # [num_envs] int32
    episodes: EpisodeBuffer
    key: Array
    diverged_at: Array  # int32: -1 while healthy, else the (1-based) iteration that went non-finite


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


def make_network(config: PPOConfig) -> ActorCritic:
    """The actor-critic described by ``config``."""
    return ActorCritic.from_config(config)


def make_optimizer(hp: Hyperparams) -> optax.GradientTransformation:
    """Global-norm clipping then Adam's scaling; the learning rate is applied by the caller.

    The hyperparameters may be tracers: the optimizer state's structure does not depend on them.
    """
    return optax.chain(
        optax.clip_by_global_norm(hp.max_grad_norm), optax.scale_by_adam(eps=hp.adam_eps)
    )


def initial_runners(
    params: dict, obs: np.ndarray, keys: np.ndarray, config: PPOConfig
) -> RunnerState:
    """Runners at iteration 0 from host-drawn parameters and reset observations (NumPy).

    Args:
        params: network parameters with a leading seed axis, leaves ``[S, ...]``.
        obs: reset observations ``[S, num_envs, 4]`` (they are the env state: velocities and
            angles are the observation, and the step counters start at 0).
        keys: raw PRNG keys ``[S, 2]`` uint32.

    Returns:
        A :class:`RunnerState` with NumPy leaves ``[S, ...]``: Adam's moments and count at 0,
        no finished episodes, not diverged.
    """
    num_seeds, num_envs = obs.shape[:2]
    one_seed = jax.tree.map(lambda x: x[0], params)
    opt_shapes = jax.eval_shape(make_optimizer(Hyperparams.from_config(config)).init, one_seed)
    zeros = lambda shape, dtype: np.zeros((num_seeds, *shape), dtype)
    window = (EPISODE_WINDOW,)
    return RunnerState(
        params=params,
        opt_state=jax.tree.map(lambda s: zeros(s.shape, s.dtype), opt_shapes),
        env_state=cartpole.EnvState(
            obs[..., 0], obs[..., 1], obs[..., 2], obs[..., 3], zeros((num_envs,), np.int32)
        ),
        obs=obs,
        episode_return=zeros((num_envs,), obs.dtype),
        episode_length=zeros((num_envs,), np.int32),
        episodes=EpisodeBuffer(
            zeros(window, np.float32), zeros(window, np.float32), zeros(window, bool)
        ),
        key=keys,
        diverged_at=np.full((num_seeds,), -1, np.int32),
    )


def collect_rollout(
    runner: RunnerState, config: PPOConfig, env_params: cartpole.EnvParams
) -> tuple[RunnerState, Transition]:
    """Steps ``num_envs`` envs for ``num_steps`` steps, sampling actions from the policy.

    Returns:
        The advanced runner and a :class:`Transition` with fields ``[num_steps, num_envs, ...]``.
    """
    network = make_network(config)

    def one_step(runner: RunnerState, _) -> tuple[RunnerState, Transition]:
        key, act_key, env_key = jax.random.split(runner.key, 3)
        logits, value = network.apply(runner.params, runner.obs)
        action = jax.random.categorical(act_key, logits)
        log_prob = categorical_log_prob(logits, action)
        obs, env_state, reward, terminated, truncated, info = cartpole.step_batch(
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

    return jax.lax.scan(one_step, runner, None, length=config.num_steps)


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

    def backwards(gae_next: Array, xs: tuple[Array, Array]) -> tuple[Array, Array]:
        delta_t, carry_t = xs
        gae = delta_t + carry_t * gae_next
        return gae, gae

    _, advantages = jax.lax.scan(
        backwards, jnp.zeros_like(delta[0]), (delta, carry_on), reverse=True
    )
    return advantages, advantages + value


def categorical_log_prob(logits: Array, action: Array) -> Array:
    """``log pi(action)`` for logits ``[..., A]`` and integer actions ``[...]``.

    (Plain ``jax.nn``; ``tests/test_ppo.py`` checks it against ``distrax.Categorical``, whose
    TensorFlow-Probability import would add over a second to every start.)
    """
    log_p = jax.nn.log_softmax(logits)
    # a one-hot sum fuses with its neighbours, where a gather would be a kernel of its own
    return (log_p * jax.nn.one_hot(action, logits.shape[-1], dtype=log_p.dtype)).sum(-1)


def categorical_entropy(logits: Array) -> Array:
    """Entropy of the categorical distribution with ``logits`` ``[..., A]``."""
    log_p = jax.nn.log_softmax(logits)
    return -(jnp.exp(log_p) * log_p).sum(-1)


def ppo_loss(
    params: dict,
    network: ActorCritic,
    batch: Batch,
    hp: Hyperparams,
    norm_adv: bool = True,
) -> tuple[Array, dict[str, Array]]:
    """SB3's PPO loss on one minibatch (fields ``[M, ...]``).

    Returns:
        ``(loss, aux)`` with aux keys ``policy_gradient_loss, value_loss, entropy_loss,
        approx_kl, clip_fraction``.
    """
    logits, value = network.apply(params, batch.obs)
    log_prob = categorical_log_prob(logits, batch.action)
    advantage = batch.advantage
    if norm_adv and advantage.shape[0] > 1:
        advantage = (advantage - advantage.mean()) / (advantage.std(ddof=1) + 1e-8)
    log_ratio = log_prob - batch.log_prob
    ratio = jnp.exp(log_ratio)
    clipped = jnp.clip(ratio, 1.0 - hp.clip_coef, 1.0 + hp.clip_coef)
    pg_loss = -jnp.minimum(advantage * ratio, advantage * clipped).mean()
    value_loss = jnp.square(batch.returns - value).mean()
    entropy_loss = -categorical_entropy(logits).mean()
    loss = pg_loss + hp.ent_coef * entropy_loss + hp.vf_coef * value_loss
    aux = {
        "policy_gradient_loss": pg_loss,
        "value_loss": value_loss,
        "entropy_loss": entropy_loss,
        "approx_kl": jax.lax.stop_gradient(((ratio - 1.0) - log_ratio).mean()),
        "clip_fraction": jax.lax.stop_gradient(
            (jnp.abs(ratio - 1.0) > hp.clip_coef).astype(jnp.float32).mean()
        ),
        "loss": loss,
    }
    return loss, aux


def update_epochs(
    params: dict,
    opt_state: optax.OptState,
    batch: Batch,
    key: Array,
    hp: Hyperparams,
    learning_rate: Array,
    config: PPOConfig,
) -> tuple[dict, optax.OptState, dict[str, Array]]:
    """``update_epochs`` passes over ``batch`` (fields ``[B, ...]``) in shuffled minibatches.

    Returns:
        New params and optimizer state, and the loss terms per gradient step
        (``[update_epochs, num_minibatches]`` each).
    """
    network = make_network(config)
    optimizer = make_optimizer(hp)
    grad_fn = jax.value_and_grad(ppo_loss, has_aux=True)
    rows = pack_batch(batch)

    def minibatch_step(carry, minibatch: Array):
        params, opt_state = carry
        minibatch = unpack_batch(minibatch, batch)
        (_, aux), grads = grad_fn(params, network, minibatch, hp, config.norm_adv)
        updates, opt_state = optimizer.update(grads, opt_state, params)
        params = jax.tree.map(lambda p, u: p - learning_rate * u, params, updates)
        return (params, opt_state), aux

    def epoch(carry, perm: Array):
        # one gather of whole rows per epoch, rather than one per field
        shape = (config.num_minibatches, config.minibatch_size, rows.shape[-1])
        return jax.lax.scan(minibatch_step, carry, rows[perm].reshape(shape))

    perms = random_permutations(key, config.update_epochs, config.batch_size)
    (params, opt_state), aux = jax.lax.scan(epoch, (params, opt_state), perms)
    return params, opt_state, aux


def pack_batch(batch: Batch) -> Array:
    """The batch as one array of rows ``[B, obs_dim + 4]``: observation, action, log-prob,
    advantage, return (the action as a float, exact for any action index below 2**24), so a
    shuffle is one gather of contiguous rows."""
    columns = [batch.action, batch.log_prob, batch.advantage, batch.returns]
    dtype = jnp.result_type(batch.obs, *columns[1:])  # no float field loses precision
    columns = [batch.obs.astype(dtype)] + [c.astype(dtype)[:, None] for c in columns]
    return jnp.concatenate(columns, axis=-1)


def unpack_batch(rows: Array, like: Batch) -> Batch:
    """:func:`pack_batch` undone for rows ``[M, obs_dim + 4]``, with ``like``'s dtypes."""
    obs_dim = like.obs.shape[-1]
    column = lambda i, field: rows[:, obs_dim + i].astype(field.dtype)
    return Batch(
        obs=rows[:, :obs_dim].astype(like.obs.dtype),
        action=column(0, like.action),
        log_prob=column(1, like.log_prob),
        advantage=column(2, like.advantage),
        returns=column(3, like.returns),
    )


def random_permutations(key: Array, num: int, size: int) -> Array:
    """``num`` independent random permutations of ``range(size)``, shape ``[num, size]``.

    Each round sorts one uint32 per element: random high bits with the index in the low
    bits, so a single-operand integer sort does the shuffle (about 10x faster on CPU than
    ``jax.random.permutation``'s key-value sorts). Elements whose random bits tie keep their
    relative order within a round; a second round (when the index takes more than 12 bits)
    makes such ties negligible.
    """
    index_bits = max(1, (size - 1).bit_length())
    if index_bits > 24:
        raise ValueError(f"batch of {size} transitions is too large to shuffle (max 2**24)")
    low = jnp.uint32((1 << index_bits) - 1)
    perms = jnp.broadcast_to(jnp.arange(size, dtype=jnp.uint32), (num, size))
    for round_key in jax.random.split(key, 1 if index_bits <= 12 else 2):
        bits = jax.random.bits(round_key, (num, size), jnp.uint32)
        order = jnp.sort((bits & ~low) | jnp.arange(size, dtype=jnp.uint32), axis=-1) & low
        perms = jnp.take_along_axis(perms, order.astype(jnp.int32), axis=-1)
    return perms.astype(jnp.int32)


def update_episode_buffer(buffer: EpisodeBuffer, rollout: Transition) -> EpisodeBuffer:
    """Adds the episodes that ended during ``rollout`` and keeps the most recent window."""
    done = (rollout.terminated | rollout.truncated).reshape(-1)
    valid = jnp.concatenate([buffer.valid, done])
    returns = jnp.concatenate(
        [buffer.returns, rollout.episode_return.reshape(-1).astype(jnp.float32)]
    )
    lengths = jnp.concatenate(
        [buffer.lengths, rollout.episode_length.reshape(-1).astype(jnp.float32)]
    )
    # rank 1 = the most recently finished episode (time-major, then env order, as SB3 fills).
    rank = jnp.cumsum(valid[::-1])[::-1]
    slot = jnp.where(valid & (rank <= EPISODE_WINDOW), EPISODE_WINDOW - rank, EPISODE_WINDOW)
    empty = jnp.zeros((EPISODE_WINDOW,), jnp.float32)
    return EpisodeBuffer(
        returns=empty.at[slot].set(returns, mode="drop"),
        lengths=empty.at[slot].set(lengths, mode="drop"),
        valid=jnp.zeros((EPISODE_WINDOW,), bool).at[slot].set(True, mode="drop"),
    )


def explained_variance(y_pred: Array, y_true: Array) -> Array:
    """``1 - Var[y_true - y_pred] / Var[y_true]`` (NaN when ``y_true`` is constant), as SB3."""
    var_y = jnp.var(y_true)
    return jnp.where(
        var_y == 0, jnp.nan, 1.0 - jnp.var(y_true - y_pred) / jnp.where(var_y == 0, 1.0, var_y)
    )


def learning_rate_at(hp: Hyperparams, iteration: Array, config: PPOConfig) -> Array:
    """Constant, or linearly annealed from ``learning_rate`` towards 0 over the iterations."""
    if not config.anneal_lr:
        return hp.learning_rate
    return hp.learning_rate * (1.0 - iteration / config.num_iterations)


def training_batch(params: dict, rollout: Transition, hp: Hyperparams, config: PPOConfig) -> Batch:
    """GAE over ``rollout`` (fields ``[num_steps, num_envs, ...]``), bootstrapping from the
    values of its true next observations under ``params``, and the transitions flattened into
    one training batch, fields ``[batch_size, ...]``."""
    next_value = make_network(config).value(params, rollout.final_obs)
    advantages, returns = compute_gae(
        rollout.reward,
        rollout.value,
        next_value,
        rollout.terminated,
        rollout.truncated,
        hp.gamma,
        hp.gae_lambda,
        config.bootstrap_truncation,
    )
    batch = Batch(
        obs=rollout.obs,
        action=rollout.action,
        log_prob=rollout.log_prob,
        advantage=advantages,
        returns=returns,
    )
    return jax.tree.map(lambda x: x.reshape((config.batch_size,) + x.shape[2:]), batch)


def train_iteration(
    runner: RunnerState,
    hp: Hyperparams,
    iteration: Array,
    config: PPOConfig,
    env_params: cartpole.EnvParams,
) -> tuple[RunnerState, dict[str, Array]]:
    """One PPO iteration for one seed: rollout, GAE, all epochs and minibatches.

    Returns:
        The next runner state and scalar metrics named as in :data:`METRIC_NAMES`.
    """
    runner, rollout = collect_rollout(runner, config, env_params)
    batch = training_batch(runner.params, rollout, hp, config)
    key, update_key = jax.random.split(runner.key)
    learning_rate = learning_rate_at(hp, iteration, config)
    params, opt_state, aux = update_epochs(
        runner.params, runner.opt_state, batch, update_key, hp, learning_rate, config
    )
    episodes = update_episode_buffer(runner.episodes, rollout)
    count = episodes.valid.sum()
    nan = jnp.float32(jnp.nan)
    metrics = {
        "rollout/ep_rew_mean": jnp.where(
            count > 0, (episodes.returns * episodes.valid).sum() / jnp.maximum(count, 1), nan
        ),
        "rollout/ep_len_mean": jnp.where(
            count > 0, (episodes.lengths * episodes.valid).sum() / jnp.maximum(count, 1), nan
        ),
        # Best episode finished during this rollout (not an SB3 metric; sweeps rank by the
        # first time it reaches 500).
        "rollout/ep_rew_max": jnp.nan_to_num(
            jnp.max(
                jnp.where(rollout.terminated | rollout.truncated, rollout.episode_return, -jnp.inf)
            ),
            neginf=jnp.nan,
        ).astype(jnp.float32),
        # SB3 resets its KL list every epoch, so it logs the last epoch's mean.
        "train/approx_kl": aux["approx_kl"][-1].mean(),
        "train/clip_fraction": aux["clip_fraction"].mean(),
        "train/entropy_loss": aux["entropy_loss"].mean(),
        "train/policy_gradient_loss": aux["policy_gradient_loss"].mean(),
        "train/value_loss": aux["value_loss"].mean(),
        "train/loss": aux["loss"][-1, -1],
        "train/explained_variance": explained_variance(
            batch.returns - batch.advantage, batch.returns
        ),
        "train/learning_rate": jnp.asarray(learning_rate, jnp.float32),
    }
    new_runner = runner.replace(params=params, opt_state=opt_state, episodes=episodes, key=key)
    return guard_divergence(runner, new_runner, metrics, iteration)


def guard_divergence(
    old: RunnerState, new: RunnerState, metrics: dict[str, Array], iteration: Array
) -> tuple[RunnerState, dict[str, Array]]:
    """Marks a seed whose update produced non-finite parameters or losses.

    Records ``diverged_at`` (1-based, as metrics.csv numbers iterations) the first time, and
    reports NaN metrics for every later iteration. It selects nothing: keeping the old state
    alive beside the new one, leaf by leaf, in every iteration made the compiled program about
    a third slower to compile. :func:`train_chunk` instead rolls a marked seed back to its
    state at the start of the chunk (the last state a checkpoint can hold), so the seed keeps
    finite parameters and later chunks leave it untouched.
    """
    finite = jnp.all(jnp.array([jnp.all(jnp.isfinite(x)) for x in jax.tree.leaves(new.params)]))
    for name in ("train/loss", "train/value_loss", "train/policy_gradient_loss"):
        finite &= jnp.isfinite(metrics[name])
    frozen = old.diverged_at >= 0
    # recorded 1-based, as metrics.csv numbers iterations
    diverged_at = jnp.where(frozen | finite, old.diverged_at, (iteration + 1).astype(jnp.int32))
    metrics = {k: jnp.where(frozen, jnp.nan, v) for k, v in metrics.items()}
    return new.replace(diverged_at=diverged_at), metrics


def roll_back_diverged(start: RunnerState, end: RunnerState) -> RunnerState:
    """``end``, except that every seed marked diverged (``diverged_at >= 0``, leaves ``[S]``)
    gets its ``start`` state back, with its ``diverged_at`` kept."""
    diverged = end.diverged_at >= 0

    def pick(s: Array, e: Array) -> Array:
        return jnp.where(diverged.reshape(diverged.shape + (1,) * (e.ndim - 1)), s, e)

    return jax.tree.map(pick, start, end).replace(diverged_at=end.diverged_at)


def train_chunk(
    runners: RunnerState,
    hps: Hyperparams,
    start_iteration: Array,
    config: PPOConfig,
    env_params: cartpole.EnvParams,
    chunk_size: int,
) -> tuple[RunnerState, dict[str, Array]]:
    """Scans ``chunk_size`` iterations of every seed; jit this (config, env_params static-ish).

    Args:
        runners: a :class:`RunnerState` with a leading seed axis ``[S]``.
        hps: :class:`Hyperparams` with leaves ``[S]``.
        start_iteration: int32 scalar, the index of the chunk's first iteration. When
            ``chunk_size`` does not divide the run, iterations at or past
            ``config.num_iterations`` are skipped (state unchanged, metrics NaN) by a
            ``lax.cond``, so one compiled chunk serves any number of iterations; when it does,
            the guard is left out (a smaller program that compiles faster).

    Returns:
        Runners after the chunk (a seed that diverged during it rolled back to its state at the
        chunk's start, see :func:`guard_divergence`) and metrics with leaves
        ``[chunk_size, S]``.
    """
    seeds_iteration = jax.vmap(train_iteration, in_axes=(0, 0, None, None, None))

    def run(runners: RunnerState, iteration: Array):
        return seeds_iteration(runners, hps, iteration, config, env_params)

    num_runs = runners.key.shape[0]

    def skip(runners: RunnerState, iteration: Array):
        return runners, {name: jnp.full((num_runs,), jnp.nan, jnp.float32) for name in METRIC_NAMES}

    def body(runners: RunnerState, offset: Array):
        iteration = start_iteration + offset
        if config.num_iterations % chunk_size == 0:  # chunks tile the run: no guard needed
            return run(runners, iteration)
        return jax.lax.cond(iteration < config.num_iterations, run, skip, runners, iteration)

    end, metrics = jax.lax.scan(body, runners, jnp.arange(chunk_size, dtype=jnp.int32))
    return roll_back_diverged(runners, end), metrics


__all__ = [
    "METRIC_NAMES",
    "Batch",
    "EpisodeBuffer",
    "Hyperparams",
    "RunnerState",
    "Transition",
    "collect_rollout",
    "compute_gae",
    "explained_variance",
    "initial_runners",
    "make_network",
    "make_optimizer",
    "ppo_loss",
    "train_chunk",
    "train_iteration",
    "training_batch",
    "update_epochs",
]
