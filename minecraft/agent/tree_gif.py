"""Record an episode of the obtain-diamond tree as an animated GIF: the agent's frames
with the running leaf (its sub-tree and activity) written under each, and, with learned
corrections in place, what they did (``TreeEpisode.correction_note``)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Optional

import numpy as np
from PIL import Image, ImageDraw

from minecraft.agent.corrections import Corrections
from minecraft.agent.diamond_tree import build_tree
from minecraft.agent.tree_episode import EpisodeResult, TreeEpisode
from minecraft.agent.tree_profile import LeafKey, TimeProfile
from minecraft.malmo.client import MalmoClient, StepResult


class _RecordingClient(MalmoClient):
    """A client that keeps every ``every``-th frame with the leaf that chose its action."""

    def __init__(self, port: int, *, seed: int, every: int, profile: TimeProfile) -> None:
        super().__init__("127.0.0.1", port, synchronous=True, seed=seed)
        self.every = every
        self.profile = profile
        self.frames: list[tuple[np.ndarray, LeafKey, int, str]] = []
        self.note: Callable[[], str] = lambda: ""
        self._steps = 0

    def step(self, commands: str | Sequence[str] = "", *, with_info: bool = True) -> StepResult:
        """Step, and keep the frame now and then."""
        r = super().step(commands, with_info=with_info)
        self._steps += 1
        if self._steps % self.every == 0 and r.frame.size:
            tick = int(r.info.get("TotalTime", 0)) if r.info else 0
            frame = r.frame[..., :3].copy()
            self.frames.append((frame, self.profile.current, tick, self.note()))
        return r


def _caption(
    frame: np.ndarray, key: LeafKey, tick: int, note: str, scale: int, lines: int
) -> Image.Image:
    img = Image.fromarray(frame).resize((frame.shape[1] * scale, frame.shape[0] * scale))
    out = Image.new("RGB", (img.width, img.height + 2 + 13 * lines), (0, 0, 0))
    out.paste(img, (0, 0))
    draw = ImageDraw.Draw(out)
    s = tick // 20
    draw.text((3, img.height + 2), f"{s // 60}:{s % 60:02d}  {key.activity}", fill=(255, 255, 0))
    draw.text((3, img.height + 15), f"{key.leaf} [{key.subtree}]", fill=(255, 255, 255))
    if note:
        draw.text((3, img.height + 28), note, fill=(0, 255, 255))
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
    ticks_per_step: int = 1,
    corrections: Optional[Corrections] = None,
) -> tuple[EpisodeResult, int]:
    """Run the tree (with ``corrections``, one decision every ``ticks_per_step`` ticks)
    in the mission on a server at ``port`` and write the GIF.

    Returns:
        The episode's result and the number of frames written.
    """
    profile = TimeProfile()
    client = _RecordingClient(port, seed=seed, every=every, profile=profile)
    client.init(mission)
    root, ctx = build_tree(seed=seed)
    episode = TreeEpisode(
        client, root, ctx, seed=seed, max_ticks=max_ticks, profile=profile,
        ticks_per_step=ticks_per_step, corrections=corrections,
    )  # fmt: skip
    client.note = episode.correction_note
    try:
        result = episode.run()
    finally:
        client.close()
    lines = 3 if corrections else 2
    images = [_caption(f, k, t, n, scale, lines) for f, k, t, n in client.frames]
    if not images:
        raise RuntimeError("the episode produced no frames")
    images[0].save(path, save_all=True, append_images=images[1:], duration=100, loop=0)
    return result, len(images)
