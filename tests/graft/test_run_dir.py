"""A run folder is never silently reused: `graft train` refuses an existing --run-dir unless
--resume, and a resume that cannot continue the folder's run, before writing anything."""

from __future__ import annotations

import pytest
import yaml

from graft.cli import main
from graft.config import load_preset
from graft.registry import make_builder
from learner.checkpoint import save_checkpoint

SMALL = {"td3.hidden_sizes": [16, 16]}


@pytest.fixture(autouse=True)
def _no_ray_address(monkeypatch) -> None:
    monkeypatch.delenv("RAY_ADDRESS", raising=False)


def _run_folder(folder, *, checkpoint: bool = True, preset: str = "pendulum-td3"):
    """A run folder as `graft train` leaves it: config.yaml and (optionally) a checkpoint."""
    config = load_preset(preset, **SMALL)
    folder.mkdir()
    (folder / "config.yaml").write_text(yaml.safe_dump(config.to_dict(), sort_keys=False))
    (folder / "metrics.csv").write_text("env_steps,updates,key,value\n")
    if checkpoint:
        learner = make_builder(config).make_learner()
        loop = {"updates": 500, "env_steps": 600, "version": 25}
        save_checkpoint(
            folder / "checkpoints",
            {"algorithm": learner.state_dict(), "loop": loop},
            updates=500,
        )
    return folder


def _snapshot(folder) -> dict[str, tuple[bytes, int]]:
    """Every file under `folder` with its bytes and modification time."""
    return {
        str(p.relative_to(folder)): (p.read_bytes(), p.stat().st_mtime_ns)
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def _refused(argv: list[str], capsys) -> str:
    with pytest.raises(SystemExit) as exit:
        main(argv)
    assert exit.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    return err.rstrip("\n")


def _train(run_dir, *extra: str) -> list[str]:
    return ["train", "--no-progress", "--run-dir", str(run_dir), *extra]


@pytest.mark.parametrize("checkpoint", [True, False], ids=["a run", "no checkpoint"])
def test_existing_run_dir_is_refused_without_resume(checkpoint, tmp_path, capsys) -> None:
    run = _run_folder(tmp_path / "run", checkpoint=checkpoint)
    before = _snapshot(run)
    message = _refused(_train(run, "--set", "td3.hidden_sizes=[16,16]"), capsys)
    assert message == (
        f"graft train: --run-dir {run} already holds a run; give --resume to continue it, or "
        "a new folder"
        if checkpoint
        else f"graft train: --run-dir {run} already exists and holds no checkpoint to resume; "
        "remove it or give a new folder"
    )
    assert _snapshot(run) == before


def test_an_empty_run_dir_is_taken(tmp_path) -> None:
    from graft.orchestration.preflight import check_run_dir

    (tmp_path / "run").mkdir()
    config = load_preset("pendulum-td3")
    assert check_run_dir(config, tmp_path / "run", resume=False) == (tmp_path / "run", None)


def test_resume_without_a_checkpoint_is_refused(tmp_path, capsys) -> None:
    run = _run_folder(tmp_path / "run", checkpoint=False)
    before = _snapshot(run)
    assert _refused(_train(run, "--resume", "--env-steps", "2000"), capsys) == (
        f"graft train: --resume: {run} has no checkpoint to continue from "
        f"({run / 'checkpoints'}/ckpt-*.pt)"
    )
    assert _snapshot(run) == before


def test_resume_without_a_run_dir_is_refused(tmp_path, capsys, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert _refused(["train", "--resume"], capsys) == (
        "graft train: --resume needs --run-dir, the folder of the run to continue"
    )
    assert list(tmp_path.iterdir()) == []


def test_resume_with_another_preset_is_refused(tmp_path, capsys) -> None:
    run = _run_folder(tmp_path / "run")
    before = _snapshot(run)
    argv = _train(run, "--resume", "--preset", "pendulum-options", "--env-steps", "2000")
    assert _refused(argv, capsys) == (
        f"graft train: --resume: {run} was trained with preset 'pendulum-td3', not "
        "'pendulum-options'; resume it with its own preset"
    )
    assert _snapshot(run) == before


@pytest.mark.service
def test_resume_with_networks_that_do_not_fit_the_checkpoint_is_refused(tmp_path, capsys):
    run = _run_folder(tmp_path / "run")
    before = _snapshot(run)
    argv = _train(run, "--resume", "--env-steps", "2000", "--set", "td3.hidden_sizes=[8]")
    message = _refused(argv, capsys)
    checkpoint = run / "checkpoints" / "ckpt-000000500.pt"
    assert message.startswith(
        f"graft train: --resume: {checkpoint} does not fit this config (td3, Pendulum-v1): "
        "Error(s) in loading state_dict"
    ), message
    assert _snapshot(run) == before


@pytest.mark.service
def test_resume_with_nothing_left_to_train_is_refused(tmp_path, capsys) -> None:
    run = _run_folder(tmp_path / "run")
    before = _snapshot(run)
    argv = _train(run, "--resume", "--env-steps", "1500", "--set", "td3.hidden_sizes=[16,16]")
    assert _refused(argv, capsys) == (
        "graft train: --resume: nothing left to train: the checkpoint is at 600 env steps, "
        "the budget is 1500 and refilling replay takes 1000; raise --env-steps"
    )
    assert _snapshot(run) == before


@pytest.mark.service
def test_resume_without_preset_takes_the_recorded_config_and_its_preset(tmp_path, capsys):
    # A run trained from a YAML file that is gone since: its folder's config.yaml is enough.
    mine = tmp_path / "mine.yaml"
    mine.write_text("env_id: Pendulum-v1\ntd3:\n  hidden_sizes: [16, 16]\n")
    config = load_preset(str(mine))
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yaml").write_text(yaml.safe_dump(config.to_dict(), sort_keys=False))
    learner = make_builder(config).make_learner()
    loop = {"updates": 500, "env_steps": 600, "version": 25}
    state = {"algorithm": learner.state_dict(), "loop": loop}
    save_checkpoint(run / "checkpoints", state, updates=500)
    mine.unlink()
    before = _snapshot(run)
    # The recorded config passes the preset check and fits the checkpoint; only the budget
    # is refused.
    assert _refused(_train(run, "--resume", "--env-steps", "1500"), capsys) == (
        "graft train: --resume: nothing left to train: the checkpoint is at 600 env steps, "
        "the budget is 1500 and refilling replay takes 1000; raise --env-steps"
    )
    argv = _train(run, "--resume", "--preset", "pendulum-td3", "--env-steps", "2000")
    assert _refused(argv, capsys) == (
        f"graft train: --resume: {run} was trained with preset 'mine', not 'pendulum-td3'; "
        "resume it with its own preset"
    )
    assert _snapshot(run) == before
