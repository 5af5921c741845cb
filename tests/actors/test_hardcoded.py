"""The adapters that turn a user's py_trees tree or callable into a batched hard-coded policy."""

from __future__ import annotations

import pickle
import sys

import numpy as np
import py_trees
import pytest
from gymnasium import spaces
from py_trees.common import Access, Status

from actors.hardcoded import (
    ACTION_KEY,
    OBSERVATION_KEY,
    CallablePolicy,
    ImportedPolicy,
    TreePolicy,
    check_acts,
    make_hardcoded_policy,
    probe_batched,
    required_policy,
)

OBS = spaces.Box(-10.0, 10.0, (2,), np.float32)
BOX = spaces.Box(-1.0, 1.0, (1,), np.float32)
THREE = spaces.Discrete(3)
BATCH = np.array([[0.0, 0.3], [0.5, -0.5], [2.0, 1.0]], np.float32)
# Hand-computed: a = clip(x1 - x0, -1, 1) -> 0.3, -1.0 (clipped from -1), -1.0 (from -1.0).
EXPECTED = np.array([[0.3], [-1.0], [-1.0]], np.float32)
# Discrete: 0 if x1 < x0, 2 if x1 > x0, else 1 -> 2, 0, 0.
EXPECTED_MOVES = np.array([2, 0, 0], np.int64)


class Difference(py_trees.behaviour.Behaviour):
    """Writes clip(x1 - x0) (or the discrete move toward it) and succeeds."""

    def __init__(self, *, discrete: bool = False) -> None:
        super().__init__("Difference")
        self.discrete = discrete
        self.ticks = 0
        self.blackboard = self.attach_blackboard_client(name="Difference")
        self.blackboard.register_key(OBSERVATION_KEY, access=Access.READ)
        self.blackboard.register_key(ACTION_KEY, access=Access.WRITE)

    def update(self) -> Status:
        self.ticks += 1
        x0, x1 = self.blackboard.get(OBSERVATION_KEY)
        if self.discrete:
            self.blackboard.set(ACTION_KEY, 1 + int(np.sign(x1 - x0)))
        else:
            self.blackboard.set(ACTION_KEY, float(np.clip(x1 - x0, -1.0, 1.0)))
        return Status.SUCCESS


class Silent(py_trees.behaviour.Behaviour):
    """Fails without writing an action."""

    def update(self) -> Status:
        return Status.FAILURE


def one(obs: np.ndarray) -> np.ndarray:
    """An unbatched callable: indexes the observation's features."""
    return np.array([np.clip(obs[1] - obs[0], -1.0, 1.0)])


def batch_only(obs: np.ndarray) -> np.ndarray:
    """A batched callable that fails on a single observation."""
    return np.clip(obs[:, 1:2] - obs[:, 0:1], -1.0, 1.0)


@pytest.mark.parametrize("wrap", [False, True], ids=["root", "BehaviourTree"])
def test_tree_is_ticked_once_per_observation(wrap: bool) -> None:
    leaf = Difference()
    tree = py_trees.trees.BehaviourTree(leaf) if wrap else leaf
    policy = TreePolicy(tree, OBS, BOX)
    actions = policy(BATCH)
    assert actions.dtype == np.float32 and actions.shape == (3, 1)
    np.testing.assert_allclose(actions, EXPECTED, rtol=1e-6)
    assert leaf.ticks == 3
    np.testing.assert_allclose(policy(BATCH[0]), EXPECTED[0], rtol=1e-6)  # one observation


def test_tree_writes_discrete_moves() -> None:
    actions = TreePolicy(Difference(discrete=True), OBS, THREE)(BATCH)
    assert actions.dtype == np.int64
    np.testing.assert_array_equal(actions, EXPECTED_MOVES)


def test_tree_that_writes_no_action_is_named() -> None:
    policy = TreePolicy(Silent("Silent"), OBS, BOX, name="mine:tree")
    with pytest.raises(RuntimeError, match=r"mine:tree: the tick ended FAILURE on 'Silent'"):
        policy(BATCH)


def test_a_stale_action_does_not_leak_into_the_next_tick() -> None:
    TreePolicy(Difference(), OBS, BOX)(BATCH)  # leaves an action on the blackboard
    with pytest.raises(RuntimeError, match="without writing /graft/action"):
        TreePolicy(Silent("Silent"), OBS, BOX)(BATCH)


def test_tree_action_of_the_wrong_size_is_refused() -> None:
    two = spaces.Box(-1.0, 1.0, (2,), np.float32)
    with pytest.raises(ValueError, match=r"shape \(\); the action space .* needs \[2\]"):
        TreePolicy(Difference(), OBS, two)(BATCH)


def either(obs: np.ndarray) -> np.ndarray:
    """Works on one observation and on a batch alike."""
    return np.clip(obs[..., 1:] - obs[..., :1], -1.0, 1.0)


@pytest.mark.parametrize(
    "policy, batched",
    [
        (one, False),
        (batch_only, True),
        (lambda obs: np.clip(obs[..., 1:] - obs[..., :1], -1, 1), True),
    ],
    ids=["one-at-a-time", "batch-only", "either"],
)
def test_callable_is_probed_and_adapted(policy, batched: bool) -> None:
    adapted = CallablePolicy(policy, OBS, BOX)
    assert adapted.batched is batched
    actions = adapted(BATCH)
    assert actions.dtype == np.float32 and actions.shape == (3, 1)
    np.testing.assert_allclose(actions, EXPECTED, rtol=1e-6)


def test_stateful_callable_is_called_once_per_observation() -> None:
    class Counter:
        """Returns how often it was called: not the same on a batch as row by row."""

        def __init__(self) -> None:
            self.calls = 0

        def __call__(self, obs: np.ndarray) -> np.ndarray:
            self.calls += 1
            return np.full(np.shape(obs)[:-1] + (1,), float(self.calls), np.float32)

    counter = Counter()
    assert not probe_batched(counter, OBS, BOX)
    adapted = CallablePolicy(counter, OBS, BOX, batched=False)
    counter.calls = 0
    np.testing.assert_array_equal(adapted(BATCH), [[1.0], [2.0], [3.0]])


def test_batched_attribute_skips_the_probe() -> None:
    calls = []

    def declared(obs: np.ndarray) -> np.ndarray:
        calls.append(obs.shape)
        return batch_only(obs)

    declared.batched = True  # type: ignore[attr-defined]
    adapted = CallablePolicy(declared, OBS, BOX)
    assert adapted.batched and not calls  # never probed
    adapted(BATCH)
    assert calls == [(3, 2)]


def test_batched_callable_of_the_wrong_shape_is_refused() -> None:
    def wrong(obs: np.ndarray) -> np.ndarray:
        return np.zeros((len(obs), 2))

    wrong.batched = True  # type: ignore[attr-defined]
    with pytest.raises(ValueError, match=r"returned actions of shape \(3, 2\) for 3"):
        CallablePolicy(wrong, OBS, BOX, name="mine:wrong")(BATCH)


def test_probe_leaves_global_random_state_alone() -> None:
    np.random.seed(123)
    expected = np.random.random()
    np.random.seed(123)
    probe_batched(one, OBS, BOX)
    assert np.random.random() == expected


@pytest.fixture
def user_module(tmp_path, monkeypatch):
    """A module of factories in a folder that is not on sys.path."""
    (tmp_path / "my_factories.py").write_text(
        "import numpy as np\n"
        "import py_trees\n"
        "SEEN = {}\n"
        "class Move(py_trees.behaviour.Behaviour):\n"
        "    def __init__(self):\n"
        "        super().__init__('Move')\n"
        "        self.bb = self.attach_blackboard_client(name='Move', namespace='/graft')\n"
        "        self.bb.register_key('observation', access=py_trees.common.Access.READ)\n"
        "        self.bb.register_key('action', access=py_trees.common.Access.WRITE)\n"
        "    def update(self):\n"
        "        x0, x1 = self.bb.observation\n"
        "        self.bb.action = 1 + int(np.sign(x1 - x0))\n"
        "        return py_trees.common.Status.SUCCESS\n"
        "def one(obs):\n"
        "    return np.array([np.clip(obs[1] - obs[0], -1.0, 1.0)])\n"
        "def tree(action_space):\n"
        "    SEEN['tree'] = action_space\n"
        "    return Move()\n"
        "def plain():\n"
        "    return one\n"
        "def both(observation_space, action_space, **extra):\n"
        "    SEEN['both'] = (observation_space, action_space, extra)\n"
        "    return one\n"
        "NOT_A_FACTORY = 3\n"
        "def junk():\n"
        "    return 'a string'\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))  # removed again after the test
    yield str(tmp_path)
    sys.modules.pop("my_factories", None)


def test_factory_gets_only_the_spaces_it_accepts(user_module) -> None:
    import my_factories

    tree = make_hardcoded_policy("my_factories:tree", OBS, THREE)
    assert isinstance(tree, TreePolicy) and my_factories.SEEN["tree"] is THREE
    np.testing.assert_array_equal(tree(BATCH), EXPECTED_MOVES)
    assert isinstance(make_hardcoded_policy("my_factories:plain", OBS, BOX), CallablePolicy)
    make_hardcoded_policy("my_factories:both", OBS, BOX)
    assert my_factories.SEEN["both"] == (OBS, BOX, {})


@pytest.mark.parametrize(
    "spec, message",
    [
        ("my_factories", "not an import string 'package.module:name'"),
        ("no_such_module:tree", "cannot import no_such_module"),
        ("my_factories:nope", "module my_factories has no 'nope'"),
        ("my_factories:NOT_A_FACTORY", "names a int, not a factory"),
        ("my_factories:junk", "returned a str; the factory must return a py_trees tree"),
    ],
)
def test_bad_hardcoded_policy_is_one_line_naming_it(user_module, spec: str, message: str) -> None:
    with pytest.raises(ValueError, match=message) as error:
        make_hardcoded_policy(spec, OBS, BOX)
    assert "\n" not in str(error.value) and repr(spec) in str(error.value)


def test_imported_policy_finds_its_module_on_the_import_path(tmp_path) -> None:
    (tmp_path / "path_only.py").write_text(
        "import numpy as np\n"
        "def plain():\n"
        "    return lambda obs: np.clip(obs[..., 1:] - obs[..., :1], -1.0, 1.0)\n"
    )
    policy = ImportedPolicy("path_only:plain", OBS, BOX, import_path=[str(tmp_path)])
    try:
        np.testing.assert_allclose(policy(BATCH), EXPECTED, rtol=1e-6)
        clone = pickle.loads(pickle.dumps(policy))  # ships without the built policy
        assert clone._policy is None and clone.import_path == (str(tmp_path),)
        np.testing.assert_allclose(clone(BATCH), EXPECTED, rtol=1e-6)
    finally:
        sys.path.remove(str(tmp_path))
        sys.modules.pop("path_only", None)


def test_method_without_a_hardcoded_policy_says_what_to_set() -> None:
    with pytest.raises(ValueError, match="options improves a hard-coded policy.*hardcoded_policy:"):
        required_policy(None, OBS, BOX, method="options")


EIGHT = spaces.Box(-1.0, 1.0, (8,), np.float32)
"""An observation space a two-feature tree was not written for."""


def test_tree_that_fails_on_the_tasks_observations_names_the_leaf_and_the_shape() -> None:
    tree = py_trees.composites.Sequence("Root", memory=False, children=[Difference()])
    policy = TreePolicy(tree, EIGHT, BOX, name="mine:tree")
    with pytest.raises(ValueError) as error:
        check_acts(policy, EIGHT, name="mine:tree")
    assert str(error.value) == (
        "hardcoded_policy='mine:tree' fails on the task's observations: leaf 'Difference' "
        "(Difference) raised ValueError: too many values to unpack (expected 2) on an "
        "observation of shape (8,)"
    )


def test_callable_that_fails_on_the_tasks_observations_names_the_shape() -> None:
    policy = CallablePolicy(lambda obs: obs["x"], EIGHT, BOX, batched=False, name="mine:f")
    with pytest.raises(ValueError, match=r"^hardcoded_policy='mine:f' fails on the task's "
                       r"observations: raised IndexError: .* of shape \(8,\)$"):  # fmt: skip
        check_acts(policy, EIGHT, name="mine:f")


def test_graft_refusals_pass_through_the_observation_check_as_they_are() -> None:
    with pytest.raises(RuntimeError, match=r"^mine:tree: the tick ended FAILURE on 'Silent'"):
        check_acts(TreePolicy(Silent("Silent"), OBS, BOX, name="mine:tree"), OBS, name="x")
    check_acts(TreePolicy(Difference(), OBS, BOX), OBS, name="x")  # a tree that fits


def test_required_policy_is_tried_on_the_tasks_observations(user_module) -> None:
    with pytest.raises(ValueError, match=r"leaf 'Move' \(Move\) raised ValueError: .* \(8,\)$"):
        required_policy("my_factories:tree", EIGHT, BOX, method="backbone_td3")
