"""Runs a preset over seeds through the CLI (`graft train`, then `graft eval`) and summarises.

Each seed is the documented pair of commands, each in its own process with its own local
Ray instance, so up to `parallel` seeds run side by side. A seed whose `eval.json` exists
is read back, not re-run, so an interrupted benchmark continues where it stopped; a seed
whose training ended (its summary.json, not interrupted) but was never evaluated, or was on
other episodes, is only evaluated; any other seed folder is started afresh. A folder trained
with other settings (preset, seed, `--set`s, env steps: its `.request.json` beside it) is
refused before any process starts, so give each benchmark process its own `--out`.
A seed whose run fails is reported with its log and left out; the others go on.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from graft.cli.flags import parse_settings
from graft.config import load_preset
from graft.experiments.stats import summarize

GRAFT = [sys.executable, "-m", "graft.cli"]
REPO = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class SeedResult:
    """One seed's final policy, evaluated over `episodes` episodes."""

    seed: int
    mean: float
    std: float
    run_dir: Path
    wall_s: float


def format_ci(values: Sequence[float]) -> str:
    """'mean M [low, high], IQM …, N seeds (95 % bootstrap CI)', as
    `graft.experiments.stats` prints."""
    return summarize(values).line()


def run_seed(
    preset: str,
    seed: int,
    run_dir: Path,
    *,
    overrides: Sequence[str] = (),
    env_steps: int | None = None,
    episodes: int = 100,
    eval_seed: int = 1000,
) -> SeedResult:
    """`graft train --preset P --seed S [--set ...]`, then `graft eval` of its final policy."""
    done = run_dir / "eval.json"
    if done.exists():
        saved = json.loads(done.read_text())
        if (saved["episodes"], saved.get("seed", eval_seed)) == (episodes, eval_seed):
            return SeedResult(seed, saved["mean"], saved["std"], run_dir, saved.get("wall_s", 0.0))
    trained = trained_wall_s(run_dir)
    if trained is not None:  # trained, then stopped before its evaluation (or another one)
        wall_s = trained
    else:
        if run_dir.exists():  # an interrupted run: start it again from an empty folder
            subprocess.run(["rm", "-rf", str(run_dir)], check=True)
        run_dir.parent.mkdir(parents=True, exist_ok=True)
        request = asked(preset, seed, overrides=overrides, env_steps=env_steps)
        _request_file(run_dir).write_text(json.dumps(request))
        train = [*GRAFT, "train", "--preset", preset, "--seed", str(seed)]
        train += ["--run-dir", str(run_dir), "--no-progress"]
        train += [a for o in overrides for a in ("--set", o)]
        if env_steps is not None:
            train += ["--env-steps", str(env_steps)]
        start = time.perf_counter()
        with open(run_dir.parent / f"{run_dir.name}.log", "w") as log:
            subprocess.run(train, check=True, stdout=log, stderr=subprocess.STDOUT)
        wall_s = time.perf_counter() - start
    saved = evaluate_run(run_dir, episodes=episodes, eval_seed=eval_seed, wall_s=wall_s)
    return SeedResult(seed, saved["mean"], saved["std"], run_dir, wall_s)


def evaluate_run(run_dir: Path, *, episodes: int, eval_seed: int, wall_s: float) -> dict[str, Any]:
    """`graft eval --json` of a run's final policy on `episodes` episodes from `eval_seed`,
    written to RUN/eval.json with the run's training wall time; returns what it wrote."""
    evaluate = [*GRAFT, "eval", "--policy", str(run_dir), "--episodes", str(episodes)]
    evaluate += ["--seed", str(eval_seed), "--json"]
    out = subprocess.run(evaluate, check=True, capture_output=True, text=True).stdout
    saved: dict[str, Any] = json.loads(out.strip().splitlines()[-1])
    saved["seed"], saved["wall_s"] = eval_seed, wall_s
    (run_dir / "eval.json").write_text(json.dumps(saved))
    return saved


def asked(
    preset: str, seed: int, *, overrides: Sequence[str], env_steps: int | None
) -> dict[str, Any]:
    """What a seed folder is trained with, as its `.request.json` records it (a preset
    inside the repository by its path from the repository's root, so that another checkout
    resumes it)."""
    path = Path(preset).resolve()
    name = str(path.relative_to(REPO)) if path.is_relative_to(REPO) else preset
    sets = parse_settings(list(overrides))  # in any order, a later one winning
    return {"preset": name, "seed": seed, "env_steps": env_steps, "sets": sets}


def _budget(request: dict[str, Any]) -> dict[str, Any]:
    """`request` with the preset's own budget where it names none (a record from before:
    None), so that asking for that budget by number is the same run."""
    if request["env_steps"] is not None:
        return request
    path = REPO / request["preset"]  # an absolute path stays itself
    preset = path if path.exists() else request["preset"]  # else a preset's name
    return {**request, "env_steps": load_preset(preset).env_steps}


def _request_file(run_dir: Path) -> Path:
    return run_dir.parent / f"{run_dir.name}.request.json"


def refuse_other_settings(
    requests: Mapping[Path, dict[str, Any]], *, ignoring: tuple[str, ...] = ()
) -> None:
    """Stops, in one line naming what differs, at the first seed folder that holds a run
    trained with other settings than its request (`asked`), `--set`s starting with one of
    `ignoring` aside; a folder from before the record is taken as it is. The benchmarks
    call it for all their seeds before the first starts."""

    def flat(request: dict[str, Any]) -> dict[str, Any]:
        request = _budget(request)
        sets = {f"--set {k}": v for k, v in request["sets"].items() if not k.startswith(ignoring)}
        return {**{k: v for k, v in request.items() if k != "sets"}, **sets}

    for run_dir, request in requests.items():
        recorded = _request_file(run_dir)
        if not (run_dir.exists() and recorded.exists()):
            continue
        before, now = flat(json.loads(recorded.read_text())), flat(request)
        keys = dict.fromkeys([*before, *now])
        if differ := [f"{k} {before.get(k, 'unset')} there, {now.get(k, 'unset')} now"
                      for k in keys if before.get(k) != now.get(k)]:  # fmt: skip
            raise SystemExit(f"{run_dir} holds a run of other settings ({'; '.join(differ)}): "
                             "give this benchmark a fresh --out")  # fmt: skip


def trained_wall_s(run_dir: Path) -> float | None:
    """The training wall time of a run that ended (summary.json, not interrupted), or None."""
    summary = run_dir / "summary.json"
    if not summary.exists():
        return None
    recorded = json.loads(summary.read_text())
    return None if recorded.get("interrupted") else float(recorded["wall_s"])


def run_seeds(
    preset: str,
    seeds: Sequence[int],
    out: Path,
    *,
    overrides: Sequence[str] = (),
    env_steps: int | None = None,
    parallel: int = 1,
    episodes: int = 100,
) -> list[SeedResult]:
    """Runs every seed into `out/s<seed>`, `parallel` at a time, printing each as it ends."""
    refuse_other_settings({out / f"s{s}": asked(preset, s, overrides=overrides, env_steps=env_steps)
                           for s in seeds})  # fmt: skip
    start = time.perf_counter()

    def one(seed: int) -> SeedResult | None:
        try:
            r = run_seed(
                preset,
                seed,
                out / f"s{seed}",
                overrides=overrides,
                env_steps=env_steps,
                episodes=episodes,
            )
        except subprocess.CalledProcessError:
            print(f"  seed {seed}: FAILED, see {out / f's{seed}.log'}", flush=True)
            return None
        print(
            f"  seed {seed}: {r.mean:.1f} ± {r.std:.1f} over {episodes} episodes "
            f"(train {r.wall_s:.0f} s; {time.perf_counter() - start:.0f} s elapsed)",
            flush=True,
        )
        return r

    with ThreadPoolExecutor(max_workers=parallel) as pool:
        done = [r for r in pool.map(one, seeds) if r is not None]
    return sorted(done, key=lambda r: r.seed)
