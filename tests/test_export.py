"""``python -m jaxcart.export``: SB3 zips and ONNX models of a trained policy, and the NumPy
policy's SB3-style ``predict``.

The zip's structure is checked without PyTorch by a loader that reads it as
``torch.load(weights_only=True)`` does (the same three globals allowed, tensors from the
archive's records), and its numbers by SB3's forward pass done in NumPy. With PyTorch and
Stable-Baselines3 installed, ``PPO.load`` opens the zip itself and scores what jaxcart's
Gymnasium evaluation scored."""

from __future__ import annotations

import io
import json
import pickle
import shutil
import zipfile
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from helpers import TINY

from jaxcart import export, load_policy
from jaxcart.core import networks
from jaxcart.core.config import PPOConfig
from jaxcart.core.networks import ActorCritic
from jaxcart.results.sb3_zip import sb3_zip_bytes
from jaxcart.run import lifecycle
from jaxcart.run.spec import RunOptions, RunSpec
from jaxcart.rundir import layout, reader
from jaxcart.rundir.policy import Policy
from jaxcart.rundir.reader import load_runs

SB3_FILES = {"data", "policy.pth", "policy.optimizer.pth", "_stable_baselines3_version"}
CONFIGS = {
    "tanh-64-64": PPOConfig(),
    "relu-32": PPOConfig(activation="relu", hidden_sizes=(32,)),
    "linear-actor": PPOConfig(linear_actor=True),
}
EVAL_EPISODES = 3


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    """A finished 2-seed TINY run, evaluated for a few Gymnasium episodes."""
    out = tmp_path_factory.mktemp("export") / "run"
    spec = RunSpec(TINY, preset="custom", num_seeds=2, seed=3)
    options = RunOptions(eval_episodes=EVAL_EPISODES, compile_cache=False)
    lifecycle.run_new(spec, out, options)
    return out


class _Storage:
    """What ``torch.FloatStorage`` stands for in the loader below."""


class _TorchLikeUnpickler(pickle.Unpickler):
    """Reads a ``torch.save`` archive's ``data.pkl`` as ``torch.load(weights_only=True)``
    would: only the globals that loader allows, each tensor from its ``data/{key}`` record."""

    ALLOWED = frozenset(
        {
            ("collections", "OrderedDict"),
            ("torch._utils", "_rebuild_tensor_v2"),
            ("torch", "FloatStorage"),
        }
    )

    def __init__(self, data: bytes, archive: zipfile.ZipFile, prefix: str) -> None:
        super().__init__(io.BytesIO(data))
        self.archive, self.prefix = archive, prefix

    def find_class(self, module: str, name: str):
        assert (module, name) in self.ALLOWED, f"weights_only would refuse {module}.{name}"
        if name == "OrderedDict":
            return super().find_class(module, name)
        if name == "FloatStorage":
            return _Storage
        return self.rebuild_tensor

    def persistent_load(self, pid):
        kind, storage_type, key, location, numel = pid
        assert (kind, storage_type, location) == ("storage", _Storage, "cpu")
        raw = self.archive.read(f"{self.prefix}data/{key}")
        assert len(raw) == 4 * numel
        return np.frombuffer(raw, "<f4")

    @staticmethod
    def rebuild_tensor(storage, offset, size, stride, requires_grad, hooks):
        assert offset == 0 and not requires_grad and not hooks
        array = storage[: int(np.prod(size))].reshape(size)
        assert array.strides == tuple(4 * s for s in stride)
        return array


def torch_like_load(data: bytes):
    """A ``torch.save`` archive's object, read without torch (see the class above)."""
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        names = archive.namelist()
        prefix = names[0].split("/")[0] + "/"
        assert all(n.startswith(prefix) for n in names)
        assert archive.read(prefix + "byteorder") == b"little"
        assert archive.read(prefix + "version").strip() == b"3"
        for info in archive.infolist():  # records are stored, data aligned as torch aligns
            assert info.compress_type == zipfile.ZIP_STORED
            if "/data/" in info.filename:
                start = info.header_offset + 30 + len(info.filename) + len(info.extra)
                assert start % 64 == 0
        return _TorchLikeUnpickler(archive.read(prefix + "data.pkl"), archive, prefix).load()


class _Stub:
    """A class named in a pickle that this test environment has no module for."""

    def __init__(self, module: str, name: str) -> None:
        self.module, self.name = module, name


class _StubUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str):
        if module.startswith(("torch", "stable_baselines3")):
            return _Stub(module, name)
        return super().find_class(module, name)


def read_sb3_zip(data: bytes) -> tuple[dict, dict, dict]:
    """``(data, policy state dict, optimizer state dict)`` of an SB3 zip, as SB3 reads it."""
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        assert SB3_FILES <= set(archive.namelist())
        entries = json.loads(archive.read("data"))
        decoded = {
            key: _StubUnpickler(io.BytesIO(_b64(value[":serialized:"]))).load()
            if isinstance(value, dict) and ":serialized:" in value
            else value
            for key, value in entries.items()
        }
        policy = torch_like_load(archive.read("policy.pth"))
        optimizer = torch_like_load(archive.read("policy.optimizer.pth"))
    return decoded, policy, optimizer


def _b64(text: str) -> bytes:
    import base64

    return base64.b64decode(text)


def sb3_forward(state: dict, prefix: str, out: str, obs: np.ndarray, activation: str):
    """SB3's ``ActorCriticPolicy`` head in NumPy: ``mlp_extractor.{prefix}`` then ``out``."""
    x, i = obs, 0
    while f"mlp_extractor.{prefix}.{i}.weight" in state:
        layer = f"mlp_extractor.{prefix}.{i}"
        x = networks.activate(
            x @ state[f"{layer}.weight"].T + state[f"{layer}.bias"], activation, np
        )
        i += 2  # Sequential(Linear, activation, Linear, activation, ...)
    return x @ state[f"{out}.weight"].T + state[f"{out}.bias"]


@pytest.mark.quick
@pytest.mark.parametrize("name", list(CONFIGS))
def test_sb3_zip_holds_the_network_sb3_would_rebuild(name):
    config = CONFIGS[name]
    params = ActorCritic.from_config(config).host_init(np.random.default_rng(0))
    data, state, optimizer = read_sb3_zip(sb3_zip_bytes(params, config))

    hidden = list(config.hidden_sizes)
    kwargs = data["policy_kwargs"]
    assert kwargs["net_arch"] == {"pi": [] if config.linear_actor else hidden, "vf": hidden}
    activation = kwargs["activation_fn"]
    assert (activation.module, activation.name) == (
        "torch.nn.modules.activation",
        {"tanh": "Tanh", "relu": "ReLU"}[config.activation],
    )
    policy_class = data["policy_class"]
    assert (policy_class.module, policy_class.name) == (
        "stable_baselines3.common.policies",
        "ActorCriticPolicy",
    )
    assert data["observation_space"] == gym.make("CartPole-v1").observation_space
    assert data["action_space"] == gym.spaces.Discrete(2)
    assert data["n_envs"] == config.num_envs and data["n_steps"] == config.num_steps
    # one optimizer entry per parameter tensor: PPO.load's load_state_dict checks the count
    assert optimizer["param_groups"][0]["params"] == list(range(len(state)))
    assert optimizer["param_groups"][0]["eps"] == pytest.approx(config.adam_eps)

    obs = np.random.default_rng(1).normal(size=(100, 4)).astype(np.float32)
    policy = Policy(networks.actor_params(params), activation=config.activation)
    logits = sb3_forward(state, "policy_net", "action_net", obs, config.activation)
    np.testing.assert_allclose(logits, policy.logits(obs), rtol=1e-5, atol=1e-6)
    value = sb3_forward(state, "value_net", "value_net", obs, config.activation)[:, 0]
    expected = ActorCritic.from_config(config).value(params, obs)
    np.testing.assert_allclose(value, np.asarray(expected), rtol=1e-5, atol=1e-5)


def test_export_command_writes_the_runs_seed(run, tmp_path, capsys):
    out = tmp_path / "policy.zip"
    assert export.main([str(run), "--to", "sb3", "--out", str(out), "--seed-index", "1"]) == 0
    assert f"wrote {out}: seed 1 of {run}" in capsys.readouterr().out
    _, state, _ = read_sb3_zip(out.read_bytes())
    policy = load_policy(run, seed_index=1)
    obs = np.random.default_rng(2).normal(size=(50, 4)).astype(np.float32)
    logits = sb3_forward(state, "policy_net", "action_net", obs, TINY.activation)
    np.testing.assert_allclose(logits, policy.logits(obs), rtol=1e-5, atol=1e-6)


def test_export_defaults_to_a_file_per_seed_in_the_run_directory(run, tmp_path, capsys):
    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    assert export.main([str(copy), "--to", "sb3"]) == 0
    assert export.main([str(copy), "--to", "sb3", "--seed-index", "1"]) == 0
    printed = capsys.readouterr().out
    for seed in (0, 1):
        out = layout.export_file(copy, ".zip", seed)
        assert out == copy / f"policy-seed{seed}.zip" and f"wrote {out}: seed {seed}" in printed
        _, state, _ = read_sb3_zip(out.read_bytes())
        obs = np.random.default_rng(2).normal(size=(5, 4)).astype(np.float32)
        logits = sb3_forward(state, "policy_net", "action_net", obs, TINY.activation)
        expected = load_policy(copy, seed_index=seed).logits(obs)  # the run still reads
        np.testing.assert_allclose(logits, expected, rtol=1e-5, atol=1e-6)
    reader.read_run_config(copy, verify=True)  # its manifest is not confused either
    assert load_runs([copy])[0].num_seeds == 2
    assert layout.export_file(copy, ".onnx", 2, 3, "best").name == "policy-best-combo003-seed2.onnx"
    missing = tmp_path / "missing"
    assert export.main([str(missing), "--to", "sb3"]) == 2
    assert capsys.readouterr().err.count("\n") == 1 and not missing.exists()


@pytest.mark.quick
@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--to", "sb3", "--out", "{tmp}/p.zip", "--policy", "best"], "no best policy was kept"),
        (["--to", "onnx", "--out", "{tmp}/p.zip"], "must end in .onnx for --to onnx"),
        (["--to", "sb3", "--out", "{tmp}/missing/p.zip"], "does not exist"),
        (
            ["--to", "sb3", "--out", "{tmp}/p.zip", "--seed-index", "2"],
            "--seed-index must be in [0, 2)",
        ),
        (["--to", "tflite", "--out", "{tmp}/p.zip"], "invalid choice: 'tflite'"),
    ],
)
def test_export_mistakes_are_one_line(run, tmp_path, capsys, args, message):
    argv = [str(run), *(a.replace("{tmp}", str(tmp_path)) for a in args)]
    assert export.main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err
    assert not list(tmp_path.iterdir())


def test_onnx_without_the_onnx_package_is_one_line(run, tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(__import__("sys").modules, "onnx", None)  # as if not installed
    assert export.main([str(run), "--to", "onnx", "--out", str(tmp_path / "p.onnx")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "pip install 'jaxcart[export]'" in err
    assert not (tmp_path / "p.onnx").exists()


def test_onnx_model_matches_load_policy_on_1000_observations(run, tmp_path):
    ort = pytest.importorskip("onnxruntime")
    out = tmp_path / "policy.onnx"
    assert export.main([str(run), "--to", "onnx", "--out", str(out), "--seed-index", "1"]) == 0
    session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    policy = load_policy(run, seed_index=1)
    # observations across and beyond CartPole's range, where the two actions' logits are near
    obs = (np.random.default_rng(3).normal(size=(1000, 4)) * [1.0, 2.0, 0.2, 2.0]).astype(
        np.float32
    )
    logits, action = session.run(["logits", "action"], {"obs": obs})
    np.testing.assert_allclose(logits, policy.logits(obs), rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(action, policy(obs))
    assert action.dtype == np.int64


@pytest.mark.quick
def test_predict_follows_sb3s_signature_and_return():
    config = CONFIGS["tanh-64-64"]
    params = ActorCritic.from_config(config).host_init(np.random.default_rng(4))
    policy = Policy(networks.actor_params(params), activation=config.activation, rng=0)
    obs = np.random.default_rng(5).normal(size=(64, 4)).astype(np.float32)

    actions, state = policy.predict(obs)
    assert actions.shape == (64,) and actions.dtype == np.int64 and state is None
    np.testing.assert_array_equal(actions, policy(obs))
    one, state = policy.predict(obs[0], state=None, episode_start=np.array([True]))
    assert isinstance(one, np.ndarray) and one.shape == () and one == policy(obs[0])
    hidden = (np.zeros(3),)
    assert policy.predict(obs, state=hidden)[1] is hidden  # passed through, as SB3's MLP does

    # deterministic=False samples from the policy's softmax (near uniform at initialisation)
    sampled = np.stack([policy.predict(obs, deterministic=False)[0] for _ in range(20)])
    assert 0.3 < sampled.mean() < 0.7 and (sampled != actions).any()


def test_stable_baselines3_loads_the_zip_and_scores_jaxcarts_evaluation(run, tmp_path):
    pytest.importorskip("torch")
    sb3 = pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.monitor import Monitor
    from stable_baselines3.common.vec_env import DummyVecEnv

    from jaxcart.core.solved import EVAL_SEED

    recorded = json.loads((run / "evaluation.json").read_text())["seeds"]
    for seed_index in (0, 1):
        out = tmp_path / f"seed{seed_index}.zip"
        export.main([str(run), "--to", "sb3", "--out", str(out), "--seed-index", str(seed_index)])
        model = sb3.PPO.load(out)
        env = gym.make("CartPole-v1")
        returns = []
        for episode in range(EVAL_EPISODES):  # the episodes jaxcart's evaluation played
            obs, _ = env.reset(seed=EVAL_SEED + episode)
            done, total = False, 0.0
            while not done:
                action, _ = model.predict(obs, deterministic=True)
                obs, reward, terminated, truncated, _ = env.step(action)
                total, done = total + reward, terminated or truncated
            returns.append(total)
        assert returns == recorded[seed_index]["gymnasium_returns"]

        # evaluate_policy scores SB3's model and jaxcart's policy (its predict) alike
        scores = []
        for agent in (model, load_policy(run, seed_index=seed_index)):
            vec_env = DummyVecEnv([lambda: Monitor(gym.make("CartPole-v1"))])
            vec_env.seed(7)
            scores.append(
                evaluate_policy(agent, vec_env, n_eval_episodes=4, return_episode_rewards=True)
            )
        assert scores[0] == scores[1]

    # the optimizer state loads too: training goes on from the exported policy
    model = sb3.PPO.load(out, env=gym.make("CartPole-v1"), n_steps=64, batch_size=32)
    model.learn(64)


@pytest.mark.parametrize("name", ["relu-32", "linear-actor"])
def test_stable_baselines3_rebuilds_relu_and_linear_actors(name, tmp_path):
    th = pytest.importorskip("torch")
    sb3 = pytest.importorskip("stable_baselines3")
    config = CONFIGS[name]
    params = ActorCritic.from_config(config).host_init(np.random.default_rng(6))
    (tmp_path / "p.zip").write_bytes(sb3_zip_bytes(params, config))
    model = sb3.PPO.load(tmp_path / "p.zip")
    obs = np.random.default_rng(7).normal(size=(200, 4)).astype(np.float32)
    with th.no_grad():
        logits = model.policy.get_distribution(th.as_tensor(obs)).distribution.logits.numpy()
    policy = Policy(networks.actor_params(params), activation=config.activation)
    # SB3's Categorical normalises logits (log-softmax): compare up to a per-row constant
    expected = policy.logits(obs)
    np.testing.assert_allclose(
        logits - logits[:, :1], expected - expected[:, :1], rtol=1e-5, atol=1e-5
    )
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], policy(obs))
