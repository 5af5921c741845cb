"""The drops decision as a gymnasium environment: the whole obtain-diamond tree runs in a
seeded world over MalmoEnv, and pauses each time a wanted item first lies within reach
of its "Pick up drops" branch; the action chases it (0, what the tree does) or leaves it
(1). ``gym.make("minecraft.agent.drop_env:MinecraftDrops-v0")`` imports this
module (so Ray workers register it themselves).

Per step::

    decide(item, a)                       (tree_episode.TreeEpisode.decide)
    run the tree until the next new item in reach, or the mission's end
    r = -(game ticks that took) / tick_scale
    s' = drop_observation(p', item')      (corrections.drop_observation)

So the return is minus the game time to the diamond (or to ``max_ticks``): leaving an
item saves the walk to it, and costs the time to get another one if the quest needed
it. The episode terminates on the diamond (the mission quits) or death, and is truncated
at ``max_ticks``. Given an ``address`` it plays the Minecraft there; without one it starts
its own simulated world server (``world_server``, an import string) in-process.
"""

from __future__ import annotations

import random
from typing import Any, Optional

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from minecraft.agent.corrections import DROP_ACTIONS, DROP_OBS_DIM
from minecraft.agent.diamond_tree import build_tree
from minecraft.agent.leaves.context import forget_namespace
from minecraft.agent.leaves.percept import ItemSeen
from minecraft.agent.travel_env import SIM_WORLD_SERVER, WorldLink
from minecraft.agent.tree_episode import TreeEpisode
from minecraft.malmo.mission_xml import obtain_diamond

ENV_ID = "minecraft.agent.drop_env:MinecraftDrops-v0"
TRAIN_WORLDS = tuple(range(2000, 2064))
"""Worlds training draws from; bench/diamond.py evaluates on others (disjoint)."""
MAX_TICKS = 3000


class ChaseEveryDrop:
    """μ(s) of the drops decision: the tree chases every wanted item (action 0)."""

    batched = True

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros(np.asarray(obs).shape[:-1], np.int64)


class MinecraftDropsEnv(gym.Env):
    """Chase or leave each wanted item the tree comes upon, on the way to a diamond.

    Args:
        address: ``host:port`` of a running Minecraft or world server; None starts
            ``world_server`` in-process.
        world_seeds: worlds to draw episodes from.
        max_ticks: game ticks before the episode is truncated.
        ticks_per_step: ticks each of the tree's decisions is held (a slow client).
        tick_scale: game ticks per unit of reward.
        world_server: import string of the server started when ``address`` is None.
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(
        self,
        *,
        address: Optional[str] = None,
        world_seeds: tuple[int, ...] = TRAIN_WORLDS,
        max_ticks: int = MAX_TICKS,
        ticks_per_step: int = 1,
        tick_scale: float = 100.0,
        world_server: str = SIM_WORLD_SERVER,
    ) -> None:
        if max_ticks < 1 or ticks_per_step < 1 or tick_scale <= 0:
            raise ValueError(
                f"max_ticks={max_ticks}, ticks_per_step={ticks_per_step} must be >= 1 and "
                f"tick_scale={tick_scale} > 0"
            )
        if not world_seeds:
            raise ValueError("world_seeds is empty: nothing to play")
        self.observation_space = spaces.Box(-np.inf, np.inf, (DROP_OBS_DIM,), np.float32)
        self.action_space = spaces.Discrete(len(DROP_ACTIONS))
        self.address, self.world_seeds = address, tuple(world_seeds)
        self.max_ticks, self.k, self.tick_scale = max_ticks, ticks_per_step, tick_scale
        self._world = WorldLink(address, world_server, synchronous=True)
        self._rng = random.Random(0)
        self.episode: Optional[TreeEpisode] = None
        self._item: Optional[ItemSeen] = None
        self._alive = False

    def _forget_tree(self) -> None:
        """Takes the last episode's tree off the blackboard (it ticks no more)."""
        if self.episode is not None:
            forget_namespace(self.episode.ctx.namespace)

    def _advance(self) -> None:
        """Run the tree until a new item is in reach or the episode ends."""
        ep = self.episode
        assert ep is not None
        self._item = None
        while self._alive:
            self._item = ep.pending_drop()
            if self._item is not None:
                return
            ep.act()
            self._alive = ep.observe()

    def _obs(self) -> np.ndarray:
        assert self.episode is not None
        if self._item is None:
            return np.zeros(DROP_OBS_DIM, np.float32)
        return self.episode.drop_state(self._item)

    def reset(
        self, *, seed: Optional[int] = None, options: Optional[dict[str, Any]] = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        if seed is not None:
            self._rng = random.Random(seed)
        client = self._world.connect()
        while True:  # a world whose first item comes only after the end is replayed
            world = self._rng.choice(self.world_seeds)
            client.init(obtain_diamond(seed=world, pixels=False))
            self._forget_tree()
            root, ctx = build_tree(seed=world)
            self.episode = TreeEpisode(
                client, root, ctx, seed=world, max_ticks=self.max_ticks,
                ticks_per_step=self.k, gate_drops=True,
            )  # fmt: skip
            self._alive = self.episode.start()
            self._advance()
            if self._item is not None:
                return self._obs(), {"world": world, "tick": self.episode.ticks}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        ep = self.episode
        assert ep is not None and self._item is not None
        before = ep.ticks
        ep.decide(self._item, int(np.asarray(action)))
        self._advance()
        reward = -(ep.ticks - before) / self.tick_scale
        info: dict[str, Any] = {"tick": ep.ticks}
        terminated = truncated = False
        if not self._alive:
            result = ep.result()
            info.update(diamond=result.diamond, died=bool(result.deaths), ticks=result.ticks)
            terminated = result.diamond or bool(result.deaths) or result.end == "done"
            truncated = not terminated
        return self._obs(), float(reward), terminated, truncated, info

    def close(self) -> None:
        self._forget_tree()
        self._world.close()


gym.register(id="MinecraftDrops-v0", entry_point=f"{__name__}:MinecraftDropsEnv")
