"""Record an episode of the obtain-diamond tree as an animated GIF: the agent's frames
with the running leaf (its sub-tree and activity) written under each."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from actors.minecraft.agent.diamond_tree import EpisodeResult, run_episode
from actors.minecraft.agent.tree_profile import LeafKey, TimeProfile
from actors.minecraft.malmo.client import MalmoClient, StepResult


class _RecordingClient(MalmoClient):
    """A client that keeps every ``every``-th frame with the leaf that chose its action."""

    def __init__(self, port: int, *, seed: int, every: int, profile: TimeProfile) -> None:
        super().__init__("127.0.0.1", port, synchronous=True, seed=seed)
        self.every = every
        self.profile = profile
        self.frames: list[tuple[np.ndarray, LeafKey, int]] = []
        self._steps = 0

    def step(self, commands: str | Sequence[str] = "", *, with_info: bool = True) -> StepResult:
        """Step, and keep the frame now and then."""
        r = super().step(commands, with_info=with_info)
        self._steps += 1
        if self._steps % self.every == 0 and r.frame.size:
            tick = int(r.info.get("TotalTime", 0)) if r.info else 0
            self.frames.append((r.frame[..., :3].copy(), self.profile.current, tick))
        return r


def _caption(frame: np.ndarray, key: LeafKey, tick: int, scale: int) -> Image.Image:
    img = Image.fromarray(frame).resize((frame.shape[1] * scale, frame.shape[0] * scale))
    out = Image.new("RGB", (img.width, img.height + 28), (0, 0, 0))
    out.paste(img, (0, 0))
    draw = ImageDraw.Draw(out)
    s = tick // 20
    draw.text((3, img.height + 2), f"{s // 60}:{s % 60:02d}  {key.activity}", fill=(255, 255, 0))
    draw.text((3, img.height + 15), f"{key.leaf} [{key.subtree}]", fill=(255, 255, 255))
    return out


def record_gif(
    port: int,
    mission: str,
    path: Path,
    *,
    seed: int,
    max_ticks: int,
    every: int = 10,
    scale: int = 3,
) -> tuple[EpisodeResult, int]:
    """Run the tree in the mission on a server at ``port`` and write the GIF.

    Returns:
        The episode's result and the number of frames written.
    """
    profile = TimeProfile()
    client = _RecordingClient(port, seed=seed, every=every, profile=profile)
    client.init(mission)
    try:
        result = run_episode(client, seed=seed, max_ticks=max_ticks, profile=profile)
    finally:
        client.close()
    images = [_caption(f, k, t, scale) for f, k, t in client.frames]
    if not images:
        raise RuntimeError("the episode produced no frames")
    images[0].save(path, save_all=True, append_images=images[1:], duration=100, loop=0)
    return result, len(images)
