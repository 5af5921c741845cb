"""The task's environment from strings: gymnasium ids, import strings, wrappers, import path."""

from __future__ import annotations

import pickle
import sys

import gymnasium as gym
import numpy as np
import pytest

from actors.task import EnvSpec

ENVS = """
import gymnasium as gym
import numpy as np
from gymnasium import spaces


class Walk(gym.Env):
    def __init__(self, size=2):
        self.size = size
        box = spaces.Box(-1.0, 1.0, (size,), np.float32)
        self.observation_space = spaces.Dict({"a": box, "b": box})
        self.action_space = spaces.Discrete(2)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return self.observation_space.sample(), {}

    def step(self, action):
        return self.observation_space.sample(), 0.0, False, False, {}


def make_walk(size=3):
    return Walk(size)


def not_an_env():
    return 42


class Countdown(gym.Env):
    # Episode i (reset with seed i) lasts 1 + i steps; from 2 steps on it reports them.

    observation_space = spaces.Box(-1.0, 1.0, (1,), np.float32)
    action_space = spaces.Discrete(2)

    def reset(self, *, seed=None, options=None):
        self.left = self.length = 1 + seed
        return np.zeros(1, np.float32), {}

    def step(self, action):
        self.left -= 1
        done = self.left == 0
        info = {"episode_metrics": {"steps": self.length}} if done and self.length > 1 else {}
        return np.zeros(1, np.float32), 1.0, done, False, info


gym.register(id="Walk-v0", entry_point=f"{__name__}:Walk", max_episode_steps=5)
"""


@pytest.fixture
def folder(tmp_path):
    """A folder holding a user's module `my_envs`, on no path until an EnvSpec names it."""
    (tmp_path / "my_envs.py").write_text(ENVS)
    yield str(tmp_path)
    if str(tmp_path) in sys.path:
        sys.path.remove(str(tmp_path))
    sys.modules.pop("my_envs", None)
    gym.registry.pop("Walk-v0", None)  # imported afresh next time, it registers again


def test_gymnasium_id_with_kwargs() -> None:
    env = EnvSpec("Pendulum-v1", {"g": 9.0}).make()
    assert env.unwrapped.g == 9.0 and env.spec.max_episode_steps == 200


@pytest.mark.parametrize(
    "env_id, size",
    [("my_envs:Walk-v0", 4), ("my_envs:Walk", 4), ("my_envs:make_walk", 4)],
    ids=["registration", "class", "factory"],
)
def test_user_env_by_import_string_on_the_import_path(folder, env_id: str, size: int) -> None:
    env = EnvSpec(env_id, {"size": size}, import_path=(folder,)).make()
    assert env.observation_space["a"].shape == (size,)


def test_obs_wrapper_flattens_a_dict(folder) -> None:
    spec = EnvSpec(
        "my_envs:Walk",
        obs_wrapper="gymnasium.wrappers:FlattenObservation",
        import_path=(folder,),
    )
    env = spec.make()
    assert env.observation_space == gym.spaces.Box(-1.0, 1.0, (4,), np.float32)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (4,)
    # Only strings travel: the spec pickles small, and builds the same env elsewhere.
    assert pickle.loads(pickle.dumps(spec)) == spec


def test_episodes_report_the_environments_own_metrics(folder) -> None:
    from actors.evaluator import play_episodes

    played = play_episodes(
        lambda obs: np.zeros(len(obs), np.int64),
        env=EnvSpec("my_envs:Countdown", import_path=(folder,)),
        episodes=3,
        seed=0,
    )
    np.testing.assert_array_equal(played.returns, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(played.metrics["steps"], [np.nan, 2.0, 3.0])
    assert played.metric_means() == {"steps": 2.5}  # over the episodes that reported it


@pytest.mark.parametrize(
    "spec, message",
    [
        (EnvSpec("NoSuchEnv-v0"), "env_id='NoSuchEnv-v0' is not a gymnasium id"),
        (EnvSpec("missing_module:Env"), "cannot import missing_module"),
        (EnvSpec("my_envs:Walk", {"sise": 2}), r"env_kwargs \['sise'\] rejected by my_envs:Walk"),
        (EnvSpec("my_envs:not_an_env"), "gave int, not a gymnasium environment"),
        (EnvSpec("my_envs:Walk", obs_wrapper="my_envs:nope"), "my_envs has no 'nope'"),
    ],
    ids=["unknown-id", "no-module", "bad-kwargs", "not-an-env", "no-wrapper"],
)
def test_bad_env_is_one_line_naming_it(folder, spec: EnvSpec, message: str) -> None:
    spec = EnvSpec(spec.env_id, spec.env_kwargs, spec.obs_wrapper, (folder,))
    with pytest.raises(ValueError, match=message) as error:
        spec.make()
    assert "\n" not in str(error.value)


@pytest.fixture
def without_box2d(monkeypatch) -> None:
    """Box2D hidden from this process (``import Box2D`` raises), installed or not."""
    loaded = ("gymnasium.envs.box2d",)
    for name in [m for m in sys.modules if m.split(".")[0] == "Box2D" or m.startswith(loaded)]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "Box2D", None)


@pytest.mark.parametrize("env_id", ["LunarLander-v3", "lunarlander_example.envs:lunar_lander"])
def test_a_missing_gymnasium_extra_is_named_also_behind_a_factory(without_box2d, env_id) -> None:
    with pytest.raises(ValueError) as error:
        EnvSpec(env_id, {"continuous": True}).make()
    assert str(error.value).startswith(
        f"env_id={env_id!r} needs a dependency that is not installed: "
        'pip install "gymnasium[box2d]"'
    )
    assert "\n" not in str(error.value)


def test_a_factory_whose_import_fails_names_the_missing_package(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(sys, "path", list(sys.path))  # the import path goes with the test
    (tmp_path / "needs_more.py").write_text("def make():\n    import not_installed_pkg\n")
    with pytest.raises(ValueError) as error:
        EnvSpec("needs_more:make", import_path=(str(tmp_path),)).make()
    assert str(error.value) == (
        "env_id='needs_more:make' needs a package that is not installed: No module named "
        "'not_installed_pkg'"
    )
