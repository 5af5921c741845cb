"""`graft` refuses every bad value in one line naming the field, the value and what is
allowed, with exit status 2, before Ray starts (these tests never start it)."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from graft.cli import main
from graft.config import PRESETS, load_preset, preset_descriptions, preset_names
from graft.placement import local_cpus

TRAIN = ["train", "--preset", "pendulum-td3"]


@pytest.fixture(autouse=True)
def _no_ray_address(monkeypatch, tmp_path) -> None:
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.chdir(tmp_path)  # a run folder written by mistake would land here


def _refused(argv: list[str], capsys) -> str:
    """The one line `graft argv` printed on stderr when it refused (exit status 2)."""
    with pytest.raises(SystemExit) as exit:
        main(argv)
    assert exit.value.code == 2
    err = capsys.readouterr().err
    assert err.endswith("\n") and err.count("\n") == 1, err  # one line, no traceback
    return err.rstrip("\n")


BAD_INPUTS = {
    "type error in a section field": (
        [*TRAIN, "--set", "td3.batch_size=abc"],
        "graft train: td3.batch_size='abc' must be an integer",
    ),
    "type error, a list field": (
        [*TRAIN, "--set", "td3.hidden_sizes=wide"],
        "graft train: td3.hidden_sizes='wide' must be a list of integers",
    ),
    "type error, a boolean field": (
        [*TRAIN, "--set", "backbone.observe_backbone=maybe"],
        "graft train: backbone.observe_backbone='maybe' must be true or false",
    ),
    "type error, a top-level number": (
        [*TRAIN, "--set", "updates_per_env_step=fast"],
        "graft train: updates_per_env_step='fast' must be a number",
    ),
    "a value the section refuses": (
        [*TRAIN, "--set", "td3.batch_size=0"],
        "graft train: td3.batch_size=0 must be >= 1.",
    ),
    "unknown --set key with a close match": (
        [*TRAIN, "--set", "td3.batchsize=256"],
        "graft train: unknown field td3.batchsize (did you mean td3.batch_size?)",
    ),
    "unknown top-level --set key": (
        [*TRAIN, "--set", "lerning_starts=10"],
        "graft train: unknown field lerning_starts (did you mean learning_starts?)",
    ),
    "unknown section": (
        [*TRAIN, "--set", "td4.gamma=0.9"],
        "graft train: unknown field td4 (did you mean td3?)",
    ),
    "--set without a value": (
        [*TRAIN, "--set", "td3.gamma"],
        "graft train: --set 'td3.gamma': expected key=value, e.g. backbone.correction_limit=0.5",
    ),
    "--set value that is not YAML": (
        [*TRAIN, "--set", "td3.hidden_sizes=[64, 64"],
        "graft train: --set td3.hidden_sizes='[64, 64': not a YAML value (expected ',' or "
        "']', but got '<stream end>')",
    ),
    "unknown env id": (
        [*TRAIN, "--set", "env_id=Pendulum-v9"],
        "graft train: env_id='Pendulum-v9' is not a registered gymnasium environment (did "
        "you mean Pendulum-v1?); give a registered id, package.module:Env-v0 or "
        "package.module:EnvClass",
    ),
    "env module that does not import": (
        [*TRAIN, "--set", "env_id=no_such_package.envs:Reach-v0"],
        "graft train: env_id='no_such_package.envs:Reach-v0' does not resolve: no module "
        "named 'no_such_package' (is its package installed, or its folder on import_path?)",
    ),
    "obs_wrapper that is not an import string": (
        [*TRAIN, "--set", "obs_wrapper=FlattenObservation"],
        "graft train: obs_wrapper='FlattenObservation' is not an import string "
        "'package.module:name'",
    ),
    "obs_wrapper whose module does not import": (
        [*TRAIN, "--set", "obs_wrapper=no_such_package.wrappers:Flat"],
        "graft train: obs_wrapper='no_such_package.wrappers:Flat' does not resolve: no module "
        "named 'no_such_package' (is its package installed, or its folder on import_path?)",
    ),
    "obs_wrapper naming nothing in its module": (
        [*TRAIN, "--set", "obs_wrapper=gymnasium.wrappers:NoSuchWrapper"],
        "graft train: obs_wrapper='gymnasium.wrappers:NoSuchWrapper' does not resolve: "
        "gymnasium.wrappers has no NoSuchWrapper",
    ),
    "hard-coded policy whose module does not import": (
        [
            "train",
            "--preset",
            "pendulum-backbone",
            "--set",
            "hardcoded_policy=no_such_package.trees:make",
        ],
        "graft train: hardcoded_policy='no_such_package.trees:make' does not resolve: no "
        "module named 'no_such_package' (is its package installed, or its folder on "
        "import_path?)",
    ),
    "a space the method refuses": (
        [*TRAIN, "--set", "env_id=CartPole-v1"],
        "graft train: td3 needs continuous actions (a 1-D Box), the environment's action "
        "space is Discrete(2): use algorithm ddqn for discrete actions (dqn.warmup: hardcoded "
        "starts it from your hard-coded policy)",
    ),
    "the options method on discrete actions": (
        [*TRAIN, "--set", "env_id=CartPole-v1", "--set", "algorithm=options"],
        "graft train: options needs continuous actions (a 1-D Box), the environment's action "
        "space is Discrete(2): use algorithm ddqn for discrete actions (dqn.warmup: hardcoded "
        "starts it from your hard-coded policy)",
    ),
    "DQN demonstrations for a TD3 method": (
        [*TRAIN, "--set", "dqn.warmup=hardcoded"],
        "graft train: dqn.warmup=hardcoded is for algorithm ddqn (demonstrations of the "
        "hard-coded policy), not td3: pretrain_td3 is its continuous-action counterpart",
    ),
    "unknown DQN warm-up": (
        [*TRAIN, "--set", "dqn.warmup=expert"],
        "graft train: dqn.warmup='expert' must be one of uniform, hardcoded",
    ),
    "unknown preset name": (
        ["train", "--preset", "pendulum-td4"],
        "graft train: unknown preset 'pendulum-td4' (did you mean pendulum-td3 or "
        f"pendulum-td3bc?); presets: {', '.join(preset_names())} (`graft presets`), or a "
        "path to a YAML file",
    ),
    "missing preset file": (
        ["train", "--preset", "tasks/mine.yaml"],
        "graft train: preset file tasks/mine.yaml does not exist",
    ),
    "a flag and --set for one field": (
        [*TRAIN, "--seed", "1", "--set", "seed=2"],
        "graft train: --seed and --set seed=... both given; give one",
    ),
    "--episodes 0": (
        ["eval", "--episodes", "0"],
        "graft eval: --episodes=0 must be >= 1",
    ),
    "--episodes not a number": (
        ["eval", "--episodes", "ten"],
        "graft eval: argument --episodes: invalid int value: 'ten' (see graft eval --help)",
    ),
    "eval on an unknown env id": (
        ["eval", "--policy", "random", "--env-id", "NoSuchEnv-v0"],
        "graft eval: --env-id: env_id='NoSuchEnv-v0' is not a registered gymnasium "
        "environment; give a registered id, package.module:Env-v0 or package.module:EnvClass",
    ),
    "learner.device misspelt": (
        [*TRAIN, "--set", "learner.device=gpu"],
        "graft train: learner.device='gpu' must be auto, cpu, cuda or cuda:N (N a GPU index)",
    ),
    "learner.compile unknown": (
        [*TRAIN, "--set", "learner.compile=fast"],
        "graft train: learner.compile='fast' must be one of off, auto, compile, cuda_graphs, "
        "captured",
    ),
    "--actors 0": ([*TRAIN, "--actors", "0"], "graft train: --actors=0 must be >= 1"),
    "--env-steps 0": ([*TRAIN, "--env-steps", "0"], "graft train: --env-steps=0 must be >= 1"),
    "--seed -1": ([*TRAIN, "--seed", "-1"], "graft train: --seed=-1 must be >= 0"),
    "seed past numpy's range": (
        [*TRAIN, "--seed", str(2**32)],
        "graft train: seed=4294967296 must lie in [0, 2**32) (numpy's seed range)",
    ),
    "--seeds 0": (
        ["experiment", "fig5", "--seeds", "0"],
        "graft experiment: --seeds=0 must be >= 1",
    ),
    "--parallel 0": (
        ["experiment", "fig5", "--parallel", "0"],
        "graft experiment: --parallel=0 must be >= 1",
    ),
    "learning_starts above the budget in an experiment, naming the variant": (
        ["experiment", "fig4", "--env-steps", "1500"],
        "graft experiment: variant 'TD3 + burn-in' (preset pendulum-td3): learning_starts=2000 "
        "must lie in (0, online env steps=1500)",
    ),
    "unknown variant": (
        ["experiment", "fig5", "--variant", "option"],
        "graft experiment: fig5 has no variant(s) ['option']; its variants: ['options']",
    ),
}


@pytest.mark.parametrize("argv, message", BAD_INPUTS.values(), ids=BAD_INPUTS.keys())
@pytest.mark.service
def test_bad_input_is_one_line(argv, message, capsys) -> None:
    assert _refused(argv, capsys) == message
    assert not Path("runs").exists()  # nothing written


def test_malformed_preset_yaml_names_line_and_column(tmp_path, capsys) -> None:
    preset = tmp_path / "mine.yaml"
    preset.write_text("env_id: Pendulum-v1\ntd3:\n  hidden_sizes: [64, 64\n  gamma: 0.99\n")
    assert _refused(["train", "--preset", str(preset)], capsys) == (
        f"graft train: preset {preset}: malformed YAML at line 4, column 8: expected ',' or "
        "']', but got ':'"
    )


@pytest.mark.service
def test_dqn_demonstrations_need_a_hard_coded_policy(tmp_path, capsys) -> None:
    preset = tmp_path / "cartpole.yaml"
    preset.write_text("env_id: CartPole-v1\nalgorithm: ddqn\ndqn: {warmup: hardcoded}\n")
    assert _refused(["train", "--preset", str(preset)], capsys) == (
        "graft train: ddqn with dqn.warmup=hardcoded improves a hard-coded policy, and the "
        "preset names none: set hardcoded_policy: package.module:factory (a py_trees tree or "
        "a callable)"
    )


def test_unknown_key_in_a_preset_file_names_the_file(tmp_path, capsys) -> None:
    preset = tmp_path / "mine.yaml"
    preset.write_text("env_id: Pendulum-v1\nlearning_start: 100\n")
    assert _refused(["train", "--preset", str(preset)], capsys) == (
        f"graft train: preset {preset}: unknown field learning_start (did you mean "
        "learning_starts?)"
    )


def test_more_actors_than_local_ray_can_place(capsys) -> None:
    have = local_cpus()  # 0.25 CPU per actor and for the evaluator
    fit = int((have - 0.25) // 0.25)
    assert _refused([*TRAIN, "--actors", "100", "--address", "local"], capsys) == (
        f"graft train: actors: 100 × (0.25 CPU) do not fit the local Ray instance ({have:g} "
        f"CPU on 1 eligible node(s)); only {fit} fit. Use --actors {fit}, lower "
        "actors.num_cpus (--set actors.num_cpus=...), or add nodes"
    )


def test_more_parallel_runs_than_local_ray_can_place(capsys) -> None:
    have = local_cpus()  # a fig5 run: its task, 2 actors and the evaluator, 0.25 CPU each
    assert _refused(["experiment", "fig5", "--parallel", "9", "--seeds", "9"], capsys) == (
        "graft experiment: parallel=9 does not fit the local Ray instance: a run of variant "
        f"'options' takes 1 CPUs (its task, actors and evaluator), 9 at a time 9, it has "
        f"{have:g}; at most {int(have)} at a time"
    )


def test_a_head_address_that_does_not_answer_is_refused_in_one_line(tmp_path, capsys) -> None:
    with socket.socket() as closed:  # a port nothing listens on once it is closed
        closed.bind(("127.0.0.1", 0))
        port = closed.getsockname()[1]
    run_dir = tmp_path / "run"
    argv = [*TRAIN, "--address", f"127.0.0.1:{port}", "--run-dir", str(run_dir)]
    assert _refused(argv, capsys) == (
        f"graft train: --address 127.0.0.1:{port}: no Ray head answers there (connection "
        "refused); start one there (deploy/ray-node.sh head, or `ray start --head`) or give "
        "its address"
    )
    assert not run_dir.exists()
    assert _refused([*TRAIN, "--address", "head-without-port"], capsys) == (
        "graft train: --address head-without-port: expected HOST:PORT (the head's, e.g. "
        "10.0.0.1:6379), 'auto', 'local' or ray://HOST:10001"
    )


def test_token_auth_without_a_token_is_refused_in_one_line(monkeypatch, tmp_path, capsys):
    missing = tmp_path / "no-token"
    monkeypatch.setenv("RAY_AUTH_MODE", "token")  # as the image sets it
    monkeypatch.setenv("RAY_AUTH_TOKEN_PATH", str(missing))
    monkeypatch.delenv("RAY_AUTH_TOKEN", raising=False)
    argv = [*TRAIN, "--address", "10.0.0.1:6379", "--run-dir", str(tmp_path / "run")]
    assert _refused(argv, capsys) == (
        "graft train: --address 10.0.0.1:6379: token auth is on (RAY_AUTH_MODE=token) but "
        f"this machine has no Ray token: put the cluster's token in {missing} "
        "(deploy/ray-node.sh copy-token USER@THIS_MACHINE), or name its file with "
        "RAY_AUTH_TOKEN_PATH"
    )


def test_ray_address_in_the_environment_is_said(monkeypatch, tmp_path, capsys) -> None:
    monkeypatch.setenv("RAY_ADDRESS", "127.0.0.1:6379")  # refused before it is joined
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "config.yaml").write_text("preset: pendulum-td3\n")
    with pytest.raises(SystemExit):
        main([*TRAIN, "--run-dir", str(tmp_path / "run")])  # refused: it exists
    note = capsys.readouterr().err.splitlines()[0]
    assert note == (
        "graft train: joining the Ray cluster at RAY_ADDRESS=127.0.0.1:6379; --address "
        "local starts a new local Ray instead"
    )
    with pytest.raises(SystemExit):
        main([*TRAIN, "--address", "local", "--run-dir", str(tmp_path / "run")])
    assert "RAY_ADDRESS" not in capsys.readouterr().err  # given: nothing to say


def test_presets_lists_every_preset_with_its_description(capsys) -> None:
    main(["presets"])
    lines = capsys.readouterr().out.splitlines()
    descriptions = preset_descriptions()
    assert [line.split()[0] for line in lines] == preset_names()
    for line, (name, text) in zip(lines, descriptions.items(), strict=True):
        assert text and line.split(None, 1)[1] == text, name
    with pytest.raises(SystemExit):
        main(["train", "--help"])
    help_text = capsys.readouterr().out
    assert all(line in help_text for line in lines)


def test_every_shipped_preset_starts_with_a_one_line_description() -> None:
    for name in preset_names():
        first = (PRESETS / f"{name}.yaml").read_text().splitlines()[0]
        assert first.startswith("# ") and len(first) <= 100, name
        assert first.rstrip().endswith("."), f"{name}: a sentence, not a cut line"


def test_preset_by_path_matches_preset_by_name(tmp_path) -> None:
    mine = tmp_path / "task" / "mine.yaml"
    mine.parent.mkdir()
    mine.write_text((PRESETS / "pendulum-td3.yaml").read_text())
    by_path, by_name = load_preset(str(mine), seed=3), load_preset("pendulum-td3", seed=3)
    assert by_path.preset == "mine"
    # A preset file's folder comes first on the import path, before the working directory.
    assert by_path.import_path == [str(mine.parent.resolve()), *by_name.import_path]
    same = {"preset": "pendulum-td3", "import_path": by_name.import_path}
    assert {**by_path.to_dict(), **same} == by_name.to_dict()


@pytest.mark.parametrize(
    ("field", "old", "new"),
    [
        ("env_id", "actors.minecraft.agent.travel_env:MinecraftTravel-v0",
         "minecraft.agent.travel_env:MinecraftTravel-v0"),
        ("hardcoded_policy", "actors.minecraft.agent.travel_env:TravelBackbone",
         "minecraft.agent.travel_env:TravelBackbone"),
        ("obs_wrapper", "service.run.recipe:nothing", "graft.recipe:nothing"),
    ],
)  # fmt: skip
def test_an_import_string_with_a_moved_module_works_with_a_warning(field, old, new) -> None:
    # A user's preset (or an old run folder's config.yaml) written before the move.
    with pytest.warns(DeprecationWarning, match=f"write '{new}'"):
        config = load_preset("minecraft-backbone", **{field: old})
    assert getattr(config, field) == new


def test_numbers_written_as_yaml_strings_are_read_as_numbers() -> None:
    # YAML 1.1 reads 1e-3 as a string; a float field takes it as the number it means.
    config = load_preset("pendulum-td3", **{"td3.actor_lr": "1e-3", "env_steps": 2.0e4})
    assert config.td3.actor_lr == 1e-3 and config.env_steps == 20_000


@pytest.mark.skipif(torch.cuda.is_available(), reason="the refusal is for a machine without CUDA")
def test_cuda_without_cuda_is_refused_before_ray_starts(capsys) -> None:
    line = _refused([*TRAIN, "--set", "learner.device=cuda"], capsys)
    assert line.startswith("graft train: learner.device=cuda: this process sees 0 CUDA device(s)")
    assert not Path("runs").exists()


def test_gymnasium_id_whose_extra_is_missing_says_what_to_install(
    monkeypatch, tmp_path, capsys
) -> None:
    """LunarLander-v3 where Box2D does not import (hidden from this process here, whether
    installed or not): the one line says which gymnasium extra installs it."""
    import sys

    loaded = ("Box2D", "gymnasium.envs.box2d")
    for name in [m for m in sys.modules if m.split(".")[0] == "Box2D" or m.startswith(loaded)]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "Box2D", None)  # `import Box2D` raises ImportError
    preset = tmp_path / "lander.yaml"
    preset.write_text("env_id: LunarLander-v3\nalgorithm: td3\n")
    line = _refused(["train", "--preset", str(preset)], capsys)
    assert line.startswith(
        "graft train: preset lander: env_id='LunarLander-v3' needs a dependency that is not "
        'installed: pip install "gymnasium[box2d]" ('
    ), line
    assert "is not a gymnasium id" not in line


def test_tree_written_for_another_task_names_its_leaf_and_the_observation_shape(
    tmp_path, capsys
) -> None:
    preset = tmp_path / "swing.yaml"
    preset.write_text(
        "env_id: Pendulum-v1\nhardcoded_policy: mountaincar_example.trees:energy_pumping\n"
        "algorithm: backbone_td3\n"
    )
    message = (
        "hardcoded_policy='mountaincar_example.trees:energy_pumping' fails on the task's "
        "observations: leaf 'Moving left?' (MovingLeft) raised ValueError: too many values to "
        "unpack (expected 2) on an observation of shape (3,)"
    )
    assert _refused(["train", "--preset", str(preset)], capsys) == f"graft train: {message}"
    assert not Path("runs").exists()
    refused = ["eval", "--policy", "hardcoded", "--preset", str(preset)]
    assert _refused(refused, capsys) == f"graft eval: {message}"


REFUSED_WITHOUT_TORCH = """
import sys
from graft.cli import main
from graft.config import load_preset
load_preset("pendulum-td3", **{"td3.batch_size": 64})
for argv in (
    ["train", "--preset", "pendulum-td3", "--set", "td3.gamma=2"],
    ["eval", "--policy", "no-such-run"],
    ["eval", "--preset", "no-such-preset"],
    ["tune", "--preset", "pendulum-td3", "--grid", "actors=0"],
):
    try:
        main(argv)
    except SystemExit as stop:
        assert stop.code == 2, (argv, stop.code)
print(sorted(m for m in ("torch", "ray") if m in sys.modules))
"""


@pytest.mark.service  # a fresh interpreter: this one has imported torch long since
def test_presets_load_and_bad_input_is_refused_without_importing_torch_or_ray() -> None:
    """`graft train`'s, `graft eval`'s and `graft tune`'s checks answer in a fraction of a
    second: torch and Ray (seconds to import) load only once the input is good."""
    done = subprocess.run(
        [sys.executable, "-c", REFUSED_WITHOUT_TORCH],
        cwd=Path(__file__).resolve().parents[2],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    for line in (
        "graft train: td3.gamma=2",
        "graft eval: no-such-run is neither a run folder nor a checkpoint",
        "graft eval: unknown preset 'no-such-preset'",
        "graft tune: ",
    ):
        assert line in done.stderr, done.stderr
    assert done.stdout.strip() == "[]", done.stdout
